"""One table of metrics over the scenario library, with the harness's targets checked.

Targets, for scenarios whose speed noise is <= 0.05 m/s: est.mass within 1 % of the
truth at every stop, and the filter's speed and distance RMSE at most 0.6x the raw sensor's.
A span scenario (the ATO drives, harness/run/span_scenario.py) also gets a table of its own, and the
ATO's targets (Meleshin 2011, Sidorenko 1997), at any noise: on every span arrival within +-2.5 s of the
schedule, the stop within +-0.3 m of the mark, never over the speed limit, no safety intervention.

Which engine runs each scenario (``python -m harness report --engine``, ``choose_engines``): ``fmu``
(the default: the report validates the FMUs users load, so it runs them), ``batch`` (whole runs in the
C core, harness.run.batch: no FMU, bit-identical results, the same table in seconds) or ``auto``
(batch where the C core covers the scenario, else the FMU). Each row records its engine
(``Row.engine``), and library.md names the engine of every scenario (``engine_line``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harness.metrics.ato import ARRIVAL_BOUND_S, STOP_BOUND_M   # the ATO's targets: one copy
from harness.metrics.estimation import RunSummary
from harness.textio import InputError

MASS_BOUND_PCT = 1.0
RMSE_RATIO_BOUND = 0.6
NOISE_LIMIT = 0.05     # [m/s] the targets apply up to this speed noise

ENGINE_FMU, ENGINE_BATCH, ENGINE_REFERENCE = "fmu", "batch", "reference"
"""A row's engine: an FMU (Row.fmu says which), the C batch engine (harness.run.batch.run_batch in
C), or run_on_chain, the Python reference run_batch falls back to (a span run whose log outgrew
the C side's)."""
ENGINES = ("auto", ENGINE_BATCH, ENGINE_FMU)
"""The values of ``--engine``."""
DEFAULT_ENGINE = ENGINE_FMU
"""The report validates what users load, the FMUs; the batch engine is asked for (or auto)."""


@dataclass
class Row:
    name: str
    speed_std: float            # [m/s] the largest speed noise sd (speed_std + rel x top speed)
    summary: RunSummary | None
    error: str = ""
    fmu: str = ""               # which FMU ran: "native" or "python" (harness.run.fmus); "" none
    ato: list | None = None     # a span scenario's harness.metrics.ato.SpanMetrics, else None
    engine: str = ENGINE_FMU    # what ran it: ENGINE_FMU, ENGINE_BATCH or ENGINE_REFERENCE

    @property
    def engine_label(self) -> str:
        """What ran the scenario, for people: 'native FMU', 'C batch engine', ..."""
        if self.engine == ENGINE_FMU:
            return f"{self.fmu or '?'} FMU"
        return {ENGINE_BATCH: "C batch engine", ENGINE_REFERENCE: "Python reference (run_on_chain)"}.get(
            self.engine, self.engine or "?")

    @property
    def targets_apply(self) -> bool:
        return self.speed_std <= NOISE_LIMIT + 1e-12

    @property
    def checks(self) -> dict[str, bool]:
        s = self.summary
        if s is None:
            return {"run": False}
        return {
            "mass": all(abs(e) <= MASS_BOUND_PCT for e in s.mass_errors_at_stops_pct),
            "speed": s.speed_rmse_filter <= RMSE_RATIO_BOUND * s.speed_rmse_sensor,
            "distance": s.position_rmse_filter <= RMSE_RATIO_BOUND * s.position_rmse_sensor,
        }

    @property
    def ato_checks(self) -> dict[str, bool]:
        """The ATO's targets over every span (empty for a scripted scenario)."""
        if not self.ato:
            return {}
        m = self.ato
        return {"arrived": all(x.arrived for x in m),
                "arrival": all(abs(x.arrival_error_s) <= ARRIVAL_BOUND_S for x in m),
                "stop": all(abs(x.stop_error_m) <= STOP_BOUND_M for x in m),
                "limit": all(x.margin_mps > 0.0 for x in m),
                "safety": all(x.interventions == 0 for x in m)}

    @property
    def ok(self) -> bool:
        return (self.summary is not None and (not self.targets_apply or all(self.checks.values()))
                and all(self.ato_checks.values()))


def library_rows(results, engines: dict[str, str] | None = None) -> list[Row]:
    """(scenario, RunResult or exception) pairs -> rows, each run's metrics computed once
    (harness.metrics.run.run_metrics; a span scenario's ATO table from the calls the run
    recorded). ``engines``: what ran each scenario, by name (default ENGINE_FMU)."""
    from harness.metrics.run import run_metrics
    engines = engines or {}
    rows = []
    for s, r in results:
        engine = engines.get(s.name, ENGINE_FMU)
        std = s.parameter("sensor.speed_std")     # [m/s]; a relative part counts at top speed
        if not isinstance(r, Exception) and s.parameter("sensor.speed_std_rel"):
            std += s.parameter("sensor.speed_std_rel") * float(np.max(np.abs(r["car.speed"])))
        if isinstance(r, Exception):
            rows.append(Row(s.name, std, None, str(r).splitlines()[0], getattr(r, "fmu", ""), engine=engine))
            continue
        m = run_metrics(r)
        rows.append(Row(s.name, std, m.summary, fmu=r.fmu, ato=m.ato, engine=engine))
    return rows


# ------------------------------------------------------------------------------ which engine runs

@dataclass(frozen=True)
class EngineChoice:
    engine: str          # ENGINE_BATCH or ENGINE_FMU: what will run the scenario
    why: str             # printed and recorded: the --engine asked and the reason


def engine_usage_error(engine: str, fmu_asked: str | None) -> str | None:
    """What is wrong with ``--engine`` ``engine`` given with ``--fmu`` ``fmu_asked`` (None: no
    --fmu), None if nothing: --fmu picks an FMU, and the batch engine runs none."""
    if engine not in ENGINES:
        return f"--engine {engine}: expected one of {', '.join(ENGINES)}"
    if engine == ENGINE_BATCH and fmu_asked is not None:
        return (f"--fmu {fmu_asked} picks the FMU of --engine fmu; --engine batch runs no FMU (whole runs in "
                f"the C core): give one of the two")
    return None


def choose_engines(scenarios, asked: str, fmu_asked: str | None = None) -> dict[str, EngineChoice]:
    """The engine of each scenario, by name, for ``--engine`` ``asked`` and ``--fmu`` ``fmu_asked``
    (None: not given). ``fmu``: every scenario on the FMU. ``batch``: every scenario in the C
    batch engine; InputError naming each scenario it does not cover
    (harness.run.batch.not_covered) and why. ``auto``: the batch engine for each scenario it
    covers, the FMU for the others; with --fmu given, the FMU for all (as ``harness sweep``
    --engine auto: a --fmu asks for the FMU)."""
    problem = engine_usage_error(asked, fmu_asked)
    if problem:
        raise InputError(problem)
    if asked == ENGINE_FMU:
        return {s.name: EngineChoice(ENGINE_FMU, "--engine fmu") for s in scenarios}
    if asked == "auto" and fmu_asked is not None:
        return {s.name: EngineChoice(ENGINE_FMU, f"--engine auto: --fmu {fmu_asked} asks for an FMU")
                for s in scenarios}
    from harness.run.batch import not_covered
    gaps = {s.name: why for s in scenarios if (why := not_covered(s)) is not None}
    if asked == ENGINE_BATCH:
        if gaps:
            where = {s.name: str(s.path or s.name) for s in scenarios}
            raise InputError("--engine batch: the C batch engine does not cover "
                             + "; ".join(f"{where[name]}: {why}" for name, why in gaps.items())
                             + " (--engine auto runs such a scenario on the FMU, the rest in the C core)")
        return {s.name: EngineChoice(ENGINE_BATCH, "--engine batch") for s in scenarios}
    return {s.name: (EngineChoice(ENGINE_FMU, f"--engine auto: the C batch engine does not cover it: {gaps[s.name]}")
                     if s.name in gaps else EngineChoice(ENGINE_BATCH, "--engine auto: the C core covers it"))
            for s in scenarios}


def engine_choice_lines(choices: dict[str, EngineChoice]) -> list[str]:
    """What the report prints before it runs: one line per engine and reason,
    'engine: batch for all 19 scenarios (--engine batch)' or 'engine: fmu for a, b (why)'."""
    groups: dict[tuple[str, str], list[str]] = {}
    for name, c in choices.items():
        groups.setdefault((c.engine, c.why), []).append(name)
    lines = []
    for (engine, why), names in groups.items():
        which = (f"all {len(names)} scenarios" if len(names) == len(choices) and len(names) > 1
                 else ", ".join(names))
        lines.append(f"engine: {engine} for {which} ({why})")
    return lines


def _fmt(x, spec):
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


HEADER = ("scenario", "V noise [m/s]", "stops", "max abs mass err at stops [%]", "mass within 1 % after [s]",
          "w0 RMS err [%]", "coast time err [s]", "speed RMSE sensor/filter/oracle [m/s]", "filter/sensor",
          "dist. RMSE sensor/filter/oracle [m]", "filter/sensor", "NEES v/x", "targets")


def table_rows(rows: list[Row]) -> list[tuple[str, ...]]:
    out = []
    for r in rows:
        s = r.summary
        if s is None:
            out.append((r.name, _fmt(r.speed_std, ".3g"), "–", "–", "–", "–", "–", "–", "–", "–", "–", "–",
                        f"FAILED: {r.error}"))
            continue
        errs = s.mass_errors_at_stops_pct
        target = ("ok" if all(r.checks.values()) else
                  "MISSED " + ",".join(k for k, v in r.checks.items() if not v)) if r.targets_apply else "n/a (noisy)"
        if r.ato_checks:
            missed = [k for k, v in r.ato_checks.items() if not v]
            target += "; ATO " + ("ok" if not missed else "MISSED " + ",".join(missed))
        out.append((
            r.name, _fmt(r.speed_std, ".3g"), str(s.stops),
            _fmt(max((abs(e) for e in errs), default=float("nan")), ".3f"),
            ", ".join(_fmt(x, ".0f") for x in s.mass_time_within_1pct_s) or "n/a",
            _fmt(100 * s.w0_rel_rms_error, ".1f"),
            ", ".join(f"{e:+.2f}" for e in s.coast_time_errors_s) or "n/a",
            f"{s.speed_rmse_sensor:.4f}/{s.speed_rmse_filter:.4f}/{_fmt(s.speed_rmse_oracle, '.4f')}",
            f"{s.speed_rmse_filter / s.speed_rmse_sensor:.2f}",
            f"{s.position_rmse_sensor:.2f}/{s.position_rmse_filter:.2f}/{_fmt(s.position_rmse_oracle, '.2f')}",
            f"{s.position_rmse_filter / s.position_rmse_sensor:.2f}",
            f"{s.speed_nees:.2f}/{s.position_nees:.2f}", target))
    return out


ATO_HEADER = ("scenario", "span", "schedule [s]", "arrival err [s]", "stop err [m]", "energy [kWh]",
              "V_lim margin [m/s]", "interventions [steps]", "arrived")


def ato_table_rows(rows: list[Row]) -> list[tuple[str, ...]]:
    from harness.metrics.ato import rows_text
    return [(r.name, *cells) for r in rows if r.ato for cells in rows_text(r.ato)]


def _fixed(header, body) -> str:
    widths = [max(len(h), *(len(b[j]) for b in body)) for j, h in enumerate(header)]
    line = "  ".join(h.ljust(w) for h, w in zip(header, widths))
    return "\n".join([line, "  ".join("-" * w for w in widths)] +
                     ["  ".join(c.ljust(w) for c, w in zip(b, widths)) for b in body])


def format_table(rows: list[Row]) -> str:
    text = _fixed(HEADER, table_rows(rows))
    ato = ato_table_rows(rows)
    return text + ("\n\nATO, per span:\n" + _fixed(ATO_HEADER, ato) if ato else "")


def fmu_line(rows: list[Row]) -> str:
    """Which FMU ran which scenarios: 'native for all 12 scenarios' or 'native: a, b; python: c'."""
    kinds: dict[str, list[str]] = {}
    for r in rows:
        kinds.setdefault(r.fmu or "?", []).append(r.name)
    if len(kinds) == 1 and len(rows) > 1:
        return f"{next(iter(kinds))} for all {len(rows)} scenarios"
    return "; ".join(f"{k}: {', '.join(names)}" for k, names in kinds.items())


def engine_line(rows: list[Row]) -> str:
    """Which engine ran which scenarios: 'C batch engine for all 19 scenarios' or
    'C batch engine: a, b; native FMU: c' (Row.engine_label)."""
    kinds: dict[str, list[str]] = {}
    for r in rows:
        kinds.setdefault(r.engine_label, []).append(r.name)
    if len(kinds) == 1 and len(rows) > 1:
        return f"{next(iter(kinds))} for all {len(rows)} scenarios"
    return "; ".join(f"{k}: {', '.join(names)}" for k, names in kinds.items())


def ran_on_line(rows: list[Row]) -> str:
    """library.md's line naming what ran each scenario: the FMU line when only FMUs ran (fmu_line),
    else the engine line (engine_line)."""
    if all(r.engine == ENGINE_FMU for r in rows):
        return f"FMU (python -m harness report --fmu): {fmu_line(rows)}."
    return f"Engine (python -m harness report --engine): {engine_line(rows)}."


def write_table(rows: list[Row], out: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Scenario library: truth vs estimates", "",
             f"Targets for speed noise <= {NOISE_LIMIT} m/s: |mass error| <= {MASS_BOUND_PCT} % at every stop, "
             f"filter RMSE <= {RMSE_RATIO_BOUND} x sensor RMSE (speed and distance).", "",
             ran_on_line(rows), "",
             "| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(b) + " |" for b in table_rows(rows)]
    ato = ato_table_rows(rows)
    if ato:
        lines += ["", f"ATO targets, every span (any noise): |arrival error| <= {ARRIVAL_BOUND_S} s, "
                      f"|stop error| <= {STOP_BOUND_M} m, margin to V_lim > 0, no safety intervention.", "",
                  "| " + " | ".join(ATO_HEADER) + " |", "|" + "---|" * len(ATO_HEADER)]
        lines += ["| " + " | ".join(b) + " |" for b in ato]
    path = out / "library.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path

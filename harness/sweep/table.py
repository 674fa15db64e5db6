"""The results table of a sweep: its columns, how one run's result becomes a row, cells as text,
and the summary over the rows. Pure computing: the files are read and written by
harness/sweep/results.py.

A row holds the run id, status ("ok" or "failed") and error message, the wall time, the swept
values (and the seed), the flattened ``RunSummary`` of harness.metrics.estimation, the calibration counts,
for a sweep of a span scenario the ATO's metrics over the run's spans (``ATO_SWEEP_COLUMNS``:
arrival and stop errors, energy, margin to the limit, interventions; the summary gives the share
of spans within +-2.5 s and +-0.3 m and the worst) and, last, ``engine`` (what ran it: ``fmu``, ``c``
the batch engine, ``python`` its fallback run_on_chain; '' for a run refused before it started)
and ``fmu``: which FMU kind ran it ('' when none did). List-valued metrics of ``RunSummary`` become two
columns: ``NAME.max_abs`` (largest absolute value; nan when the list is empty or holds a nan)
and ``NAME.list`` (the values, ';'-joined reprs). Tuples of A coefficients become ``A0_true`` ...
In the CSV, floats are written by repr (they read back bit for bit) and units stand in the
header cells, ``name [unit]``.
"""
from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field, fields

import numpy as np

from harness.sweep.spec import Sweep, name_kind, name_unit, unit_from_suffix

TEXT_STATUS_OK, TEXT_STATUS_FAILED = "ok", "failed"


@dataclass(frozen=True)
class Column:
    key: str
    unit: str          # '' for text and ids; '-' for dimensionless numbers
    kind: str          # 'int', 'float' or 'str'

    @property
    def header(self) -> str:
        return f"{self.key} [{self.unit}]" if self.unit else self.key


_METRIC_UNITS = {"duration_s": "s", "stops": "-", "mass_true_t": "t", "mass_est_t": "t", "mass_std_t": "t",
                 "mass_error_pct": "%", "mass_errors_at_stops_pct": "%", "mass_time_within_1pct_s": "s",
                 "w0_rel_rms_error": "-", "coast_time_errors_s": "s", "speed_nees": "-",
                 "position_nees": "-"}
_A_UNITS = ("N/kN", "N/kN/(m/s)", "N/kN/(m/s)2")
CALIBRATION_COLUMNS = (
    Column("mass_stops_covered", "-", "int"),          # arrivals with |est.mass - truth| <= 2 est.mass_std
    Column("mass_z_at_stops.max_abs", "-", "float"),   # (est.mass - truth) / est.mass_std at each arrival
    Column("mass_z_at_stops.list", "-", "str"),
    Column("moving_samples", "-", "int"),              # rows with car.speed > 0
    Column("speed_within_2sigma", "-", "int"),         # ... of them with |filter.speed - car.speed| <= 2 std
    Column("position_within_2sigma", "-", "int"),
    Column("speed_within_2sigma_pct", "%", "float"),
    Column("position_within_2sigma_pct", "%", "float"),
)
ENGINE_COLUMN = Column("engine", "", "str")    # what ran the row: fmu, c (batch engine), python (run_on_chain)
FMU_COLUMN = Column("fmu", "", "str")          # which FMU ran the row: native, python ('' none ran)
ATO_SWEEP_COLUMNS = (      # a span scenario's run (harness.metrics.ato.SpanMetrics over its spans)
    Column("ato_spans", "-", "int"),                   # spans the ATO drove
    Column("ato_arrived", "-", "int"),                 # ... of them the car stands at the mark
    Column("ato_on_target", "-", "int"),               # ... arrived within +-2.5 s and +-0.3 m
    Column("ato_arrival_error_s.max_abs", "s", "float"),
    Column("ato_arrival_error_s.list", "s", "str"),    # per span: true arrival - departure - schedule
    Column("ato_stop_error_m.max_abs", "m", "float"),
    Column("ato_stop_error_m.list", "m", "str"),       # per span: true position at rest - stop mark
    Column("ato_energy_kwh", "kWh", "float"),          # over the spans, from the network
    Column("ato_margin_mps", "m/s", "float"),          # min over the spans of V_lim(s) - V (> 0: under it)
    Column("ato_interventions", "-", "int"),           # safe brake or supervisor's brake, steps
)


def _metric_unit(name: str) -> str:
    if name in _METRIC_UNITS:
        return _METRIC_UNITS[name]
    if name.startswith("speed_"):
        return "m/s"
    if name.startswith("position_"):
        return "m"
    return unit_from_suffix(name) or "-"


def metric_columns() -> list[Column]:
    """Columns of a flattened RunSummary (derived from its fields and their annotations)."""
    from harness.metrics.estimation import RunSummary
    cols = []
    for f in fields(RunSummary):
        ann = str(f.type)
        if f.name == "scenario":
            continue
        if f.name in ("A_true", "A_est"):
            suffix = f.name[2:]
            cols += [Column(f"A{i}_{suffix}", _A_UNITS[i], "float") for i in range(3)]
        elif ann.startswith(("list", "tuple")):
            unit = _metric_unit(f.name)
            cols += [Column(f"{f.name}.max_abs", unit, "float"), Column(f"{f.name}.list", unit, "str")]
        elif ann == "int" or f.name == "stops":
            cols.append(Column(f.name, _metric_unit(f.name), "int"))
        elif ann == "str":
            cols.append(Column(f.name, "", "str"))
        else:
            cols.append(Column(f.name, _metric_unit(f.name), "float"))
    return cols


def is_span_sweep(sweep: Sweep) -> bool:
    """The base scenario is a span scenario: the ATO drives every run."""
    return sweep.span


def sweep_columns(sweep: Sweep) -> list[Column]:
    """The run id, status, error, wall time, the swept values and the seed, the metrics, the
    calibration, for a span scenario's sweep the ATO's (ATO_SWEEP_COLUMNS), ``engine`` and ``fmu``."""
    cols = [Column("run_id", "", "int"), Column("status", "", "str"), Column("error", "", "str"),
            Column("wall_time", "s", "float")]
    cols += [Column(n, name_unit(n) or ("-" if name_kind(n) != "str" else ""), name_kind(n)) for n in sweep.axes]
    if "seed" not in sweep.axes:
        cols.append(Column("seed", "-", "int"))
    ato = list(ATO_SWEEP_COLUMNS) if is_span_sweep(sweep) else []
    return cols + metric_columns() + list(CALIBRATION_COLUMNS) + ato + [ENGINE_COLUMN, FMU_COLUMN]


def ato_row(spans) -> dict:
    """A run's ATO metrics (harness.metrics.ato.SpanMetrics, one per span driven) as the
    ATO_SWEEP_COLUMNS: counts and sums over the spans, the worst |error|, each span's errors."""
    arrival = [m.arrival_error_s for m in spans]
    stop = [m.stop_error_m for m in spans]
    return {"ato_spans": len(spans), "ato_arrived": sum(m.arrived for m in spans),
            "ato_on_target": sum(m.on_target for m in spans),
            "ato_arrival_error_s.max_abs": _max_abs(arrival), "ato_arrival_error_s.list": _joined(arrival),
            "ato_stop_error_m.max_abs": _max_abs(stop), "ato_stop_error_m.list": _joined(stop),
            "ato_energy_kwh": float(sum(m.energy_kwh for m in spans)),
            "ato_margin_mps": min((m.margin_mps for m in spans), default=float("nan")),
            "ato_interventions": int(sum(m.interventions for m in spans))}


def run_ato_row(result) -> dict:
    """``ato_row`` of a span scenario's run (its RunResult with the ATO's calls); {} otherwise."""
    if result.driver_steps is None or result.scenario.ato is None:
        return {}
    from harness.metrics.ato import ato_metrics
    return ato_row(ato_metrics(result.scenario, result, result.driver_steps))


def _max_abs(xs) -> float:
    if not xs:
        return float("nan")
    a = [abs(float(x)) for x in xs]
    return float("nan") if any(math.isnan(x) for x in a) else max(a)


def _joined(xs) -> str:
    return ";".join(repr(float(x)) for x in xs)


def flatten_summary(summary) -> dict:
    """RunSummary -> scalars (see the module docstring: lists -> .max_abs and .list)."""
    out = {}
    for f in fields(summary):
        v = getattr(summary, f.name)
        if f.name == "scenario":
            continue
        if f.name in ("A_true", "A_est"):
            for i, x in enumerate(v):
                out[f"A{i}_{f.name[2:]}"] = float(x)
        elif isinstance(v, (list, tuple)):
            out[f"{f.name}.max_abs"] = _max_abs(v)
            out[f"{f.name}.list"] = _joined(v)
        elif isinstance(v, (bool, str)):
            out[f.name] = v
        elif isinstance(v, (int, np.integer)):
            out[f.name] = int(v)
        else:
            out[f.name] = float(v)
    return out


def calibration(result) -> dict:
    """Is the truth inside the estimator's and the filter's +-2 sigma? Counts for one run.

    Mass: at the arrival at each stop (harness.metrics.estimation.stop_indices, before passengers board),
    |est.mass - car.total_mass| <= 2 est.mass_std. Filter: over the moving rows (car.speed > 0),
    |filter.speed - car.speed| <= 2 filter.speed_std, and the same for the distance.
    """
    from harness.metrics.estimation import stop_indices
    v = result["car.speed"]
    stops = stop_indices(v)
    err = result["est.mass"] - result["car.total_mass"]
    std = result["est.mass_std"]
    z = [float(err[k] / std[k]) if std[k] > 0 else (0.0 if err[k] == 0 else math.copysign(math.inf, err[k]))
         for k in stops]
    moving = v > 0.0
    n = int(moving.sum())
    sv = np.abs(result["filter.speed"] - v) <= 2.0 * result["filter.speed_std"]
    sx = np.abs(result["filter.position"] - result["car.position"]) <= 2.0 * result["filter.position_std"]
    nv, nx = int((sv & moving).sum()), int((sx & moving).sum())
    return {"mass_stops_covered": int(sum(abs(err[k]) <= 2.0 * std[k] for k in stops)),
            "mass_z_at_stops.max_abs": _max_abs(z), "mass_z_at_stops.list": _joined(z),
            "moving_samples": n, "speed_within_2sigma": nv, "position_within_2sigma": nx,
            "speed_within_2sigma_pct": 100.0 * nv / n if n else float("nan"),
            "position_within_2sigma_pct": 100.0 * nx / n if n else float("nan")}


def cell_text(value) -> str:
    """A value as a CSV cell: floats by repr (read back bit for bit), None as ''."""
    if type(value) is float:           # most cells: the checks below give the same text, slower
        return repr(value)
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def parse_cell(text: str, kind: str):
    """A CSV cell back to a value of the column's kind; ValueError if it is not one."""
    if text == "":
        return None if kind != "str" else ""
    if kind == "int":
        return int(text)
    if kind == "float":
        return float(text)
    return text


@dataclass
class Table:
    """Rows of a sweep's results (dicts keyed by column key), typed by the columns."""
    columns: list[Column]
    rows: list[dict] = field(default_factory=list)

    def column(self, key: str) -> list:
        return [r.get(key) for r in self.rows]

    def comparable(self, exclude=("wall_time",)) -> list[tuple]:
        """Rows as tuples of exact cell texts (floats by repr), for bit-for-bit comparisons."""
        keys = [c.key for c in self.columns if c.key not in exclude]
        return [tuple(cell_text(r.get(k)) for k in keys) for r in self.rows]

    def ok_rows(self) -> list[dict]:
        return [r for r in self.rows if r.get("status") == TEXT_STATUS_OK]


class SweepStats:
    """What the summary says about a sweep's rows, accumulated one row at a time (``add``), in any
    order, so that the end of a sweep of any size streams its CSV once instead of holding the table:
    counts, the pooled calibration, the failures by message (count and the five smallest run ids),
    the ATO's shares and worsts, and each SUMMARY_METRICS value and each run's ATO energy (8 bytes a
    value, for the exact median). ``coverage`` and ``ato_outcome`` of a Table are computed here too."""

    def __init__(self):
        self.rows = self.ok = self.failed = 0
        self.values = {m: array("d") for m in SUMMARY_METRICS}
        self.stops = self.covered = self.moving = self.speed_in = self.position_in = 0
        self.failures: dict[str, list] = {}      # message -> [count, up to 5 smallest run ids]
        self.ato_runs = self.spans = self.arrival_within = self.stop_within = 0
        self.on_target = self.arrived = self.interventions = 0
        self.worst = {"arrival": None, "stop": None}    # max (|x|, run id) over the finite errors
        self.nan_run = {"arrival": None, "stop": None}  # least run id with a nan error (never came to rest)
        self.min_margin = math.inf
        self.energy = array("d")

    @classmethod
    def of(cls, rows) -> "SweepStats":
        stats = cls()
        for r in rows:
            stats.add(r)
        return stats

    def add(self, r: dict) -> None:
        self.rows += 1
        if r.get("status") != TEXT_STATUS_OK:
            self.failed += 1
            entry = self.failures.setdefault(r.get("error") or "?", [0, []])
            entry[0] += 1
            entry[1] = sorted(entry[1] + [r["run_id"]])[:5]
            return
        self.ok += 1
        for m, xs in self.values.items():
            xs.extend(finite_values([r.get(m)]))
        self.stops += r.get("stops") or 0
        self.covered += r.get("mass_stops_covered") or 0
        self.moving += r.get("moving_samples") or 0
        self.speed_in += r.get("speed_within_2sigma") or 0
        self.position_in += r.get("position_within_2sigma") or 0
        if r.get("ato_spans") is not None:
            self._add_ato(r)

    def _add_ato(self, r: dict) -> None:
        from harness.metrics.ato import ARRIVAL_BOUND_S, STOP_BOUND_M
        self.ato_runs += 1
        self.spans += r["ato_spans"]
        for what, key, bound in (("arrival", "ato_arrival_error_s.list", ARRIVAL_BOUND_S),
                                 ("stop", "ato_stop_error_m.list", STOP_BOUND_M)):
            for x in _split_list(r.get(key)):
                if what == "arrival":
                    self.arrival_within += abs(x) <= bound
                else:
                    self.stop_within += abs(x) <= bound
                if math.isnan(x):
                    run = self.nan_run[what]
                    self.nan_run[what] = r["run_id"] if run is None else min(run, r["run_id"])
                else:
                    pair = (abs(x), r["run_id"])
                    self.worst[what] = pair if self.worst[what] is None else max(self.worst[what], pair)
        self.on_target += r.get("ato_on_target") or 0
        self.arrived += r.get("ato_arrived") or 0
        self.min_margin = min([self.min_margin] + finite_values([r.get("ato_margin_mps")]))
        self.interventions += r.get("ato_interventions") or 0
        self.energy.extend(finite_values([r.get("ato_energy_kwh")]))

    def coverage(self) -> dict:
        """Pooled calibration over the ok rows: percentage of stops / moving samples inside +-2 sigma."""
        nan = float("nan")
        return {"runs": self.ok, "stops": self.stops, "moving_samples": self.moving,
                "mass_pct": 100.0 * self.covered / self.stops if self.stops else nan,
                "speed_pct": 100.0 * self.speed_in / self.moving if self.moving else nan,
                "position_pct": 100.0 * self.position_in / self.moving if self.moving else nan}

    def ato_outcome(self) -> dict | None:
        """See ``ato_outcome``."""
        if not self.ato_runs:
            return None
        nan = float("nan")

        def worst(what):          # a car that never came to rest: its run is the worst
            if self.nan_run[what] is not None:
                return nan, self.nan_run[what]
            return self.worst[what] if self.worst[what] is not None else (nan, None)
        return {"runs": self.ato_runs, "spans": self.spans, "arrival_within": self.arrival_within,
                "stop_within": self.stop_within, "on_target": self.on_target, "arrived": self.arrived,
                "worst_arrival": worst("arrival"), "worst_stop": worst("stop"),
                "min_margin": nan if math.isinf(self.min_margin) else self.min_margin,
                "interventions": self.interventions, "energy": list(self.energy)}

    def top_failures(self, n: int = 5) -> list[tuple[str, int, list]]:
        """(message, count, up to 5 smallest run ids) of the ``n`` commonest failure messages; ties
        in the order of their smallest run id (as Counter.most_common over the rows by run id)."""
        ranked = sorted(self.failures.items(), key=lambda kv: (-kv[1][0], kv[1][1][0]))
        return [(msg, count, ids) for msg, (count, ids) in ranked[:n]]


class SweepOutcome:
    """What run_sweep did: ``stats`` (SweepStats over every row in DIR), the counts of this call, the
    files; ``table`` (every row, sorted by run id) is read from DIR only when asked for, so a sweep of
    any size ends in flat memory."""

    def __init__(self, stats: SweepStats, ran: int, resumed: int, missing: list, wall_s: float, workers: int,
                 files: list | None = None, fmu: str = "", engine: str = "", read_table=None,
                 table: Table | None = None):
        self.stats = stats
        self.ran = ran                   # runs executed by this call
        self.resumed = resumed           # rows kept from an earlier call (--resume)
        self.missing = missing           # run ids with no row (interrupted, --limit)
        self.wall_s = wall_s
        self.workers = workers
        self.files = files if files is not None else []
        self.fmu = fmu                   # which FMU ran and why (harness.run.fmus.FmuChoice.describe)
        self.engine = engine             # which engine ran and why (--engine), '' for the FMU
        self._read_table = read_table    # () -> Table: every row in DIR (results.read_results)
        self._table = table

    @property
    def table(self) -> Table:
        """Every row in DIR, sorted by run id (read on first use: O(rows) memory)."""
        if self._table is None:
            self._table = self._read_table()
        return self._table


def finite_values(xs) -> list[float]:
    """The finite numbers among ``xs`` (None, text, nan and inf left out)."""
    return [float(x) for x in xs if x is not None and not isinstance(x, str) and math.isfinite(x)]


def coverage(table: Table) -> dict:
    """Pooled calibration over the ok rows: percentage of stops / moving samples inside +-2 sigma."""
    return SweepStats.of(table.rows).coverage()


SUMMARY_METRICS = ("mass_error_pct", "mass_errors_at_stops_pct.max_abs", "mass_time_within_1pct_s.max_abs",
                   "mass_std_t", "w0_rel_rms_error", "coast_time_errors_s.max_abs", "speed_rmse_sensor",
                   "speed_rmse_filter", "position_rmse_sensor", "position_rmse_filter", "speed_nees",
                   "position_nees")


def format_sweep_summary(sweep: Sweep, o: SweepOutcome, columns: list[Column] | None = None) -> str:
    """The summary of a sweep's rows (``o.stats``) and of this call; ``columns`` (default the sweep's)
    give the units."""
    st = o.stats
    units = {c.key: c.unit for c in (columns or sweep_columns(sweep))}
    lines = [f"sweep '{sweep.name}' on {sweep.base_path.name}: {len(sweep.runs)} runs over "
             f"{', '.join(sweep.axes)}",
             f"  rows {st.rows}: {st.ok} ok, {st.failed} failed; this call ran {o.ran} in {o.wall_s:.1f} s"
             + (f" ({o.ran / o.wall_s:.2f} runs/s on {o.workers} workers)" if o.ran and o.wall_s > 0 and o.workers else "")
             + (f"; {o.resumed} rows kept from before (--resume)" if o.resumed else "")]
    if o.fmu:
        lines.append(f"  fmu: {o.fmu}")
    if o.engine:
        lines.append(f"  engine: {o.engine}")
    if o.missing:
        lines.append(f"  not run yet: {len(o.missing)} runs (first ids {', '.join(map(str, o.missing[:5]))}); "
                     f"--resume continues")
    if st.ok:
        lines.append("")
        w = max(len(m) for m in SUMMARY_METRICS) + 6
        lines.append(f"  {'metric (over the ok runs)':<{w}} {'min':>10} {'median':>10} {'max':>10}")
        for m in SUMMARY_METRICS:
            xs = st.values[m]
            label = f"{m} [{units.get(m, '-')}]"
            if xs:
                lines.append(f"  {label:<{w}} {min(xs):>10.4g} {float(np.median(xs)):>10.4g} {max(xs):>10.4g}")
            else:
                lines.append(f"  {label:<{w}} {'n/a':>10}")
        c = st.coverage()
        lines += ["", "  calibration: truth inside the estimate +- 2 sigma (95.4 % for honest Gaussian errors)",
                  f"    mass at the arrival at each stop    {_pct(c['mass_pct'])} of {c['stops']} stops",
                  f"    filter speed (moving samples)       {_pct(c['speed_pct'])} of {c['moving_samples']} samples",
                  f"    filter distance (moving samples)    {_pct(c['position_pct'])} of {c['moving_samples']} samples"]
        ato = st.ato_outcome()
        if ato is not None:
            lines += format_ato_outcome(ato)
    if st.failed:
        lines += ["", "  failures (by message):"]
        for msg, n, ids in st.top_failures(5):
            lines.append(f"    {n} x (runs {', '.join(map(str, ids))}{', ...' if n > 5 else ''}): {msg[:300]}")
    return "\n".join(lines)


def _split_list(text) -> list[float]:
    """A ``.list`` cell back to its numbers ('' -> [])."""
    return [float(x) for x in text.split(";")] if isinstance(text, str) and text else []


def ato_outcome(table: Table) -> dict | None:
    """The ATO over every span of the ok runs of a span sweep (None if no row has ATO columns):
    spans, the share arrived within +-ARRIVAL_BOUND_S / +-STOP_BOUND_M / both (and arrived), the
    worst |arrival error| and |stop error| and their runs, the smallest margin to V_lim, the
    interventions and the spans not arrived."""
    return SweepStats.of(table.rows).ato_outcome()


def format_ato_outcome(a: dict) -> list[str]:
    """The summary's ATO lines (``ato_outcome``)."""
    from harness.metrics.ato import ARRIVAL_BOUND_S, STOP_BOUND_M
    n = a["spans"]

    def share(k: int) -> str:
        return f"{k} of {n} spans ({100.0 * k / n:.1f} %)" if n else "n/a"

    def worst(pair, unit: str) -> str:
        x, run = pair
        return "n/a" if run is None else (f"never came to rest (run {run})" if math.isnan(x)
                                          else f"{x:.3g} {unit} (run {run})")
    e = a["energy"]
    lines = ["", f"  ATO over the spans of the {a['runs']} ok runs (targets: |arrival error| <= {ARRIVAL_BOUND_S} s, "
                 f"|stop error| <= {STOP_BOUND_M} m)",
             f"    arrival within +-{ARRIVAL_BOUND_S} s     {share(a['arrival_within'])}",
             f"    stop within +-{STOP_BOUND_M} m        {share(a['stop_within'])}",
             f"    arrived, both within       {share(a['on_target'])}",
             f"    worst |arrival error|      {worst(a['worst_arrival'], 's')}",
             f"    worst |stop error|         {worst(a['worst_stop'], 'm')}",
             f"    least margin to V_lim      " + ("n/a" if math.isnan(a["min_margin"]) else f"{a['min_margin']:.3g} m/s"),
             f"    safety interventions       {a['interventions']} steps",
             f"    not arrived                {n - a['arrived']} spans"]
    if e:
        lines.append(f"    energy per run             min {min(e):.4g}, median {float(np.median(e)):.4g}, "
                     f"max {max(e):.4g} kWh")
    return lines


def _pct(x: float) -> str:
    return "  n/a " if math.isnan(x) else f"{x:5.1f} %"

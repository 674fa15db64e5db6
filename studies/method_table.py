"""Which identification method to ship: paper LS vs each est.method vs the oracle, per metric
(a study, not a test).

    python studies/method_table.py [NAME ...] [--methods K ...] [--with NAME=VALUE ...]

The FMU parameter est.method selects how the estimator identifies the mass and the resistance
coefficients (models.estimation.identification.IdentifierConfig):

  0  paper LS          the paper's recursive least squares
  1  LS + FE refit     LS, plus a filter-error refit of each run at the next station stop
  2  LS + poly diff    LS fed by Sidorenko's (1997) least-squares polynomial differentiation of speed
  3  LS + coast EKF    Meleshin's (2011) coasting EKF for A0, A1, A2; LS for the mass

This runs every library scenario (scenarios/library/*.toml; NAME restricts them) with each
method (--methods restricts them, default 0 1 2 3; each --with NAME=VALUE adds every method
again with that FMU parameter set, e.g. --with est.physical=1 --with est.sigma2_method=1) on the
models chain (no FMI), as
studies/filter_gap.py does, and summarises each run with harness.metrics.estimation.summarise. A method the
configuration rejects (ValueError when the chain is built) is a row "n/a (rejected: ...)".
Per row:

  mass       max |est - true| at the stops [%] (arrival rows, before boarding), whether every
             stop is within 1 %, and the share of stops with |est - true| <= 2 est.mass_std
  w0         summarise's w0 relative RMS error over the travelled speed range [%]
  coast      summarise's coast run-time errors [s], predicted with the identified A's - actual
  speed      RMSE sensor / filter / oracle [m/s]; filter/oracle (issue 5: <= 1.10) and
             filter/sensor (<= 0.6)
  distance   RMSE filter / oracle [m] and their ratio
  coverage   the filter's +-2 sigma coverage of speed and distance over the moving rows
             (car.speed > 0) [%]; an honest filter is at 90-98 %

and one "oracle" row per scenario: harness.metrics.estimation.oracle_filter (the same filter fed the true
mass, A's and process noise), so mass and w0 errors 0; its coast errors are the coast-time
prediction with the true A's (the floor of that metric: the plant's process noise). The oracle
replays the recorded measurements and demands, which do not depend on est.method (the driver
steers by the true state); the table says so if they ever did.

Then a summary per method over the scenarios with speed noise <= 0.05 m/s (all but
etcs_noisy_sensors). Prints both tables and writes them as markdown to out/methods/methods.md.
A note lists the rows equal in every metric to paper LS (method 1 on every scenario with a
single stop: its refit acts on the runs after a stop). Seeded (each scenario's own seed): the
numbers repeat. The scripted runs of est.method 0 and 2 go whole in C (harness.run.batch); est.method
1 and 3, and the span scenarios (until the batch engine covers the ATO), run on run_on_chain. Runtime
on 2 cores (Pool(2), a loaded machine): ~10 s for the library with --methods 0 2, ~20 s with all
four; serially 30 of the 33 s of --methods 0 2 are the span scenarios' Python ATO.

Reading the coast column: with the true A's the prediction is still off by up to ~1 s per
coast on these runs (0.00 s with car.process_noise_psd = 0: it is the plant's process noise),
so coast errors under ~1 s do not rank methods. The identified A's are re-run in still air
(they contain the wind they met); the true ones in the scenario's wind as it blows over the
coast (headwind_change: the 12 m/s headwind rises mid-coast; the oracle row is +0.8 s).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from harness.run.batch import run_batch  # noqa: E402
from harness.metrics.estimation import _segments, coast_time_errors, summarise  # noqa: E402
from harness.run.runner import RunResult  # noqa: E402
from harness.run.scenario import RAILCAR_PARAMETERS as PARAMETERS, load_scenario  # noqa: E402
from models.estimation.identification import METHODS as ID_METHODS  # noqa: E402

LIBRARY = ROOT / "scenarios" / "library"
OUT = ROOT / "out" / "methods"
METHODS = (0, 1, 2, 3)
ORACLE = "oracle"
LOW_NOISE = 0.05          # [m/s] the summary's scenarios: sensor.speed_std at most this
RATIO_TARGET = 1.10       # speed RMSE filter / oracle
SENSOR_TARGET = 0.6       # speed RMSE filter / sensor
NAN = float("nan")


@dataclass
class Row:
    """One scenario x method (or the scenario's oracle). Shares in [0, 1], nan where undefined."""
    scenario: str
    method: str                        # "K name", or ORACLE
    speed_noise: float                 # sensor.speed_std [m/s]
    rejected: str | None = None        # the configuration's ValueError message
    stops: int = 0
    mass_err_max_pct: float = NAN      # max |est - true| / true at the stops [%]
    mass_within_1pct: bool | None = None
    mass_coverage: float = NAN         # share of stops with |est - true| <= 2 est.mass_std
    w0_err_pct: float = NAN            # [%]
    coast_errors_s: list = field(default_factory=list)   # [s]
    speed_rmse_sensor: float = NAN     # [m/s]
    speed_rmse_filter: float = NAN     # [m/s] (the oracle's, on the oracle row)
    speed_rmse_oracle: float = NAN     # [m/s]
    dist_rmse_sensor: float = NAN      # [m]
    dist_rmse_filter: float = NAN      # [m]
    dist_rmse_oracle: float = NAN      # [m]
    speed_coverage: float = NAN        # share of moving rows within 2 filter.speed_std
    dist_coverage: float = NAN         # share of moving rows within 2 filter.position_std

    @property
    def speed_ratio(self) -> float:
        return self.speed_rmse_filter / self.speed_rmse_oracle

    @property
    def speed_vs_sensor(self) -> float:
        return self.speed_rmse_filter / self.speed_rmse_sensor

    @property
    def dist_vs_sensor(self) -> float:
        return self.dist_rmse_filter / self.dist_rmse_sensor

    @property
    def dist_ratio(self) -> float:
        return self.dist_rmse_filter / self.dist_rmse_oracle


def method_label(method: int, extra: dict | None = None) -> str:
    return f"{method} {ID_METHODS.get(method, '?')}" + "".join(f" + {k}={v:g}" for k, v in (extra or {}).items())


# ------------------------------------------------------------------------------ computing

def _run(scenario, method: int, extra: dict | None = None):
    """The scenario on the models chain with est.method = method and the ``extra`` parameters,
    demands recorded as inputs: (the run's ChainSetup, its RunResult), the run whole in C where
    the batch engine covers it (harness.run.batch.run_batch: run_on_chain's result bit for bit;
    est.method 1 and 3 run on run_on_chain). Raises ValueError if the configuration rejects them."""
    overrides = {"est.method": method, **(extra or {})}
    setup = scenario.chain_setup(overrides)
    return setup, run_batch([scenario], [overrides], [setup])[0]


def _coverage(estimate, truth, std, mask) -> float:
    """Share of the masked rows with |estimate - truth| <= 2 std."""
    ok = np.abs(np.asarray(estimate) - np.asarray(truth)) <= 2.0 * np.asarray(std)
    return float(np.mean(ok[mask])) if mask.any() else NAN


def _true_coast_errors(result: RunResult, setup) -> list[float]:
    """summarise's coast run-time errors [s] with the true still-air A's (and the wind then
    blowing) in place of the identified ones; ``setup``: the run's ChainSetup."""
    car = setup.config.vehicle
    A = (car.A0, car.A1, car.A2)
    return coast_time_errors(result, lambda last: A, still_air=True, setup=setup)


def run_job(job: tuple[Path, int, bool] | tuple[Path, int, bool, bool]) -> list[Row]:
    """The row of (scenario, method[, extra parameters]), and the scenario's oracle row if asked
    (from this run, or from a method-0 run if the method is rejected)."""
    path, method, with_oracle, extra = (tuple(job) + (None,))[:4]
    scenario = load_scenario(path)
    noise = float(scenario.parameter("sensor.speed_std"))
    try:
        setup, result = _run(scenario, method, extra)
    except ValueError as e:
        rows = [Row(scenario.name, method_label(method, extra), noise, rejected=str(e))]
        if with_oracle:
            rows += [r for r in run_job((path, 0, True)) if r.method == ORACLE]
        return rows
    s = summarise(result, setup=setup)
    v = result["car.speed"]
    moving = v > 0.0
    arrivals = [k for _, k in _segments(v)]
    errs = [abs(e) for e in s.mass_errors_at_stops_pct]
    mass_ok = [abs(result["est.mass"][k] - result["car.total_mass"][k]) <= 2.0 * result["est.mass_std"][k]
               for k in arrivals]
    row = Row(
        scenario.name, method_label(method, extra), noise, stops=len(arrivals),
        mass_err_max_pct=max(errs) if errs else NAN,
        mass_within_1pct=all(e <= 1.0 for e in errs) if errs else None,
        mass_coverage=float(np.mean(mass_ok)) if mass_ok else NAN,
        w0_err_pct=100.0 * s.w0_rel_rms_error,
        coast_errors_s=list(s.coast_time_errors_s),
        speed_rmse_sensor=s.speed_rmse_sensor, speed_rmse_filter=s.speed_rmse_filter,
        speed_rmse_oracle=s.speed_rmse_oracle,
        dist_rmse_sensor=s.position_rmse_sensor,
        dist_rmse_filter=s.position_rmse_filter, dist_rmse_oracle=s.position_rmse_oracle,
        speed_coverage=_coverage(result["filter.speed"], v, result["filter.speed_std"], moving),
        dist_coverage=_coverage(result["filter.position"], result["car.position"],
                                result["filter.position_std"], moving),
    )
    rows = [row]
    if with_oracle:
        rows.append(Row(
            scenario.name, ORACLE, noise, stops=len(arrivals),
            mass_err_max_pct=0.0 if arrivals else NAN, mass_within_1pct=True if arrivals else None,
            w0_err_pct=0.0, coast_errors_s=_true_coast_errors(result, setup),
            speed_rmse_sensor=s.speed_rmse_sensor, speed_rmse_filter=s.speed_rmse_oracle,
            speed_rmse_oracle=s.speed_rmse_oracle,
            dist_rmse_filter=s.position_rmse_oracle, dist_rmse_oracle=s.position_rmse_oracle))
    return rows


def compute_rows(names: list[str] | None = None, methods=METHODS, processes: int = 2,
                 extras: tuple[dict, ...] = ({},)) -> list[Row]:
    """Rows grouped by scenario (library order), methods in the order given (each with every
    parameter set of ``extras``, {} = as the scenario says), then the oracle."""
    paths = [LIBRARY / f"{n}.toml" for n in names] if names else sorted(LIBRARY.glob("*.toml"))
    variants = [(int(m), dict(x)) for m in methods for x in extras]
    jobs = [(p, m, i == 0, ph) for p in paths for i, (m, ph) in enumerate(variants)]
    cost = {p: (lambda s: s.duration_s / s.step_s)(load_scenario(p)) for p in paths}
    order = sorted(range(len(jobs)), key=lambda i: -cost[jobs[i][0]])      # longest first
    if processes > 1 and len(jobs) > 1:
        with Pool(processes) as pool:
            done = pool.map(run_job, [jobs[i] for i in order], chunksize=1)
    else:
        done = [run_job(jobs[i]) for i in order]
    by_job = dict(zip(order, done))
    rows = []
    for p in paths:
        idx = [i for i, j in enumerate(jobs) if j[0] == p]
        rows += [r for i in idx for r in by_job[i] if r.method != ORACLE]
        rows += [r for i in idx for r in by_job[i] if r.method == ORACLE]
    return rows


def same_as_paper_ls(rows: list[Row]) -> list[str]:
    """"scenario: method" of the accepted rows equal in every metric to the scenario's method-0
    row (a method that never acts there, e.g. the refit with a single stop, or one accepted by
    the configuration but not implemented)."""
    def key(r: Row) -> tuple:
        return (r.mass_err_max_pct, r.mass_coverage, r.w0_err_pct, tuple(r.coast_errors_s),
                r.speed_rmse_filter, r.dist_rmse_filter, r.speed_coverage, r.dist_coverage)

    first = {r.scenario: r for r in rows if r.method == method_label(0) and not r.rejected}
    return [f"{r.scenario}: {r.method}" for r in rows
            if r.scenario in first and r.method not in (ORACLE, method_label(0)) and not r.rejected
            and str(key(r)) == str(key(first[r.scenario]))]


def oracle_mismatches(rows: list[Row]) -> list[str]:
    """Scenarios whose oracle RMSE differs between methods (it should not: same measurements)."""
    out = []
    for name in dict.fromkeys(r.scenario for r in rows):
        vals = {r.speed_rmse_oracle for r in rows
                if r.scenario == name and r.method != ORACLE and not r.rejected}
        if len(vals) > 1 and max(vals) - min(vals) > 1e-12:
            out.append(name)
    return out


# ------------------------------------------------------------------------------ printing

def _f(x, fmt: str) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)


def _pct(share: float) -> str:
    return _f(100.0 * share if share == share else share, "{:.1f}")


def _yes(b: bool | None) -> str:
    return "n/a" if b is None else ("yes" if b else "NO")


MAIN_HEADER = ("scenario", "method", "stops", "max mass err at stops [%]", "all stops <= 1 %",
               "mass 2σ cover [%]", "w0 err [%]", "coast time err [s]",
               "speed RMSE sensor / filter / oracle [m/s]", "speed filter/oracle [-] (<= 1.10)",
               "speed filter/sensor [-] (<= 0.6)", "distance RMSE filter / oracle [m]",
               "distance filter/oracle [-]", "speed 2σ cover [%]", "distance 2σ cover [%]")


def main_table(rows: list[Row]) -> tuple[tuple, list[list[str]]]:
    """Header and cells of the table of every row (the scenario named on its first row)."""
    cells, last = [], None
    for r in rows:
        name = r.scenario if r.scenario != last else ""
        last = r.scenario
        if r.rejected:
            cells.append([name, r.method, f"n/a (rejected: {r.rejected})"])
            continue
        ratio = r.speed_ratio
        cells.append([
            name, r.method, str(r.stops), _f(r.mass_err_max_pct, "{:.3f}"), _yes(r.mass_within_1pct),
            _pct(r.mass_coverage), _f(r.w0_err_pct, "{:.1f}"),
            ", ".join(f"{e:+.2f}" for e in r.coast_errors_s) or "n/a",
            f"{r.speed_rmse_sensor:.4f} / {r.speed_rmse_filter:.4f} / {_f(r.speed_rmse_oracle, '{:.4f}')}",
            _f(ratio, "{:.3f}") + (" !" if ratio > RATIO_TARGET else ""),
            _f(r.speed_vs_sensor, "{:.3f}") + (" !" if r.speed_vs_sensor > SENSOR_TARGET else ""),
            f"{r.dist_rmse_filter:.3f} / {_f(r.dist_rmse_oracle, '{:.3f}')}",
            _f(r.dist_ratio, "{:.3f}"), _pct(r.speed_coverage), _pct(r.dist_coverage)])
    return MAIN_HEADER, cells


SUMMARY_HEADER = ("method", "scenarios", "mean speed filter/oracle [-]", "worst speed filter/oracle [-]",
                  "mean speed filter/sensor [-]", "mean w0 err [%]", "worst mass err at stops [%]",
                  "mean mass 2σ cover [%]", "mean speed 2σ cover [%]", "mean distance 2σ cover [%]")


def summary_table(rows: list[Row], noise_max: float = LOW_NOISE) -> tuple[tuple, list[list[str]]]:
    """Per method (and the oracle) over the scenarios with sensor.speed_std <= noise_max:
    means and worsts, nan-valued entries (no stops) left out."""
    def mean(xs):
        xs = [x for x in xs if x == x]
        return float(np.mean(xs)) if xs else NAN

    def worst(xs):
        xs = [x for x in xs if x == x]
        return max(xs) if xs else NAN

    cells = []
    for method in dict.fromkeys(r.method for r in rows):
        sel = [r for r in rows if r.method == method and r.speed_noise <= noise_max + 1e-12]
        ok = [r for r in sel if not r.rejected]
        if not ok:
            cells.append([method, f"{len(sel)}", "n/a (rejected)"])
            continue
        cells.append([
            method, f"{len(ok)}" + (f" (+{len(sel) - len(ok)} rejected)" if len(sel) > len(ok) else ""),
            _f(mean([r.speed_ratio for r in ok]), "{:.3f}"), _f(worst([r.speed_ratio for r in ok]), "{:.3f}"),
            _f(mean([r.speed_vs_sensor for r in ok]), "{:.3f}"),
            _f(mean([r.w0_err_pct for r in ok]), "{:.1f}"),
            _f(worst([r.mass_err_max_pct for r in ok]), "{:.3f}"), _pct(mean([r.mass_coverage for r in ok])),
            _pct(mean([r.speed_coverage for r in ok])), _pct(mean([r.dist_coverage for r in ok]))])
    return SUMMARY_HEADER, cells


def markdown(header: tuple, cells: list[list[str]]) -> str:
    """A markdown table, columns padded to the widest full row (rejected rows overflow)."""
    full = [c for c in cells if len(c) == len(header)]
    w = [max([len(h)] + [len(c[i]) for c in full]) for i, h in enumerate(header)]
    lines = ["| " + " | ".join(h.ljust(w[i]) for i, h in enumerate(header)) + " |",
             "|" + "|".join("-" * (n + 2) for n in w) + "|"]
    for c in cells:
        c = c + [""] * (len(header) - len(c))
        lines.append("| " + " | ".join(x.ljust(w[i]) for i, x in enumerate(c)) + " |")
    return "\n".join(lines)


def report(rows: list[Row], seconds: float | None = None) -> str:
    """Both tables with their titles and notes, as markdown."""
    n_low = len({r.scenario for r in rows if r.speed_noise <= LOW_NOISE + 1e-12})
    parts = ["# Identification methods on the library scenarios", "",
             "Models chain (no FMI), each scenario's own seed. '!' marks a speed ratio over its "
             f"target (filter/oracle <= {RATIO_TARGET}, filter/sensor <= {SENSOR_TARGET}). "
             "Coverages are of +-2 sigma: mass over the stops, speed and distance over the moving rows.",
             "", markdown(*main_table(rows)), "",
             f"## Per method over the {n_low} scenarios with speed noise <= {LOW_NOISE} m/s", "",
             markdown(*summary_table(rows))]
    bad = oracle_mismatches(rows)
    if bad:
        parts += ["", "Note: the oracle's RMSE differs between methods on " + ", ".join(bad)
                  + " (the oracle row is from the first method's run)."]
    same = same_as_paper_ls(rows)
    if same:
        parts += ["", "Equal in every metric to 0 paper LS: " + "; ".join(same) + "."]
    if seconds is not None:
        parts += ["", f"Computed in {seconds:.0f} s."]
    return "\n".join(parts) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", metavar="NAME", help="library scenarios (default: all)")
    ap.add_argument("--methods", nargs="+", type=int, default=list(METHODS), metavar="K",
                    help="est.method values (default: 0 1 2 3)")
    ap.add_argument("--with", dest="extra", action="append", default=[], metavar="NAME=VALUE",
                    help="each method again with this FMU parameter set (repeatable)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    extras = [{}]
    for item in args.extra:
        name, _, value = item.partition("=")
        if name not in PARAMETERS or not value:
            ap.error(f"--with {item!r}: expected NAME=VALUE with a RailCar parameter NAME")
        extras.append({name: float(value)})
    rows = compute_rows(args.names, args.methods, extras=tuple(extras))
    text = report(rows, time.perf_counter() - t0)
    print(text)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "methods.md").write_text(text, encoding="utf-8")
    print(f"written {OUT / 'methods.md'}")


if __name__ == "__main__":
    main()

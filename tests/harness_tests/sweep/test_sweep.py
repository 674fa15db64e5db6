"""Parameter sweeps (harness/sweep/main.py and its parts in harness/sweep/): sweep files, Latin
hypercube, instance reuse, and whole sweeps through the CLI (its default: the C batch engine,
chunks of runs a task) on an embedded local cluster and on a real dask scheduler with two worker
processes (one of them killed mid-sweep), plus an interrupted sweep resumed.

Short runs (60 s of simulated time) keep the whole module well under two minutes.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any FMU is loaded in this process)

import csv
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from harness.run.scenario import load_scenario
from harness.sweep.execute import ReusableRunner, execute_run
from harness.sweep.plots import PLOT_GROUPS
from harness.sweep.results import ResultsWriter, read_results
from harness.sweep.spec import SweepError, latin_hypercube, load_sweep
from harness.sweep.table import CALIBRATION_COLUMNS, calibration, flatten_summary, metric_columns, sweep_columns

ROOT = Path(__file__).resolve().parents[3]
LEVEL = ROOT / "scenarios" / "library" / "level_run.toml"
N_RUNS = 18
SWEEP = f"""
name = "t_sweep"
scenario = "{LEVEL.as_posix()}"
seeds = 3

[fixed]
duration_s = 60.0

[grid]
"car.mass" = [-5.0, 30.0, 38.0]                  # -5 t: refused before the FMU runs (a failed row)
"driver[0].until_speed_kmh" = [40.0, 60.0]
"""


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# ------------------------------------------------------------------------- sweep files

BASE = f'scenario = "{LEVEL.as_posix()}"\n'


@pytest.mark.parametrize("text,needle", [
    ("seeds = 2\ncolour = 1\n", "unknown key 'colour'"),
    ("seeds = 2\n", "scenario: give the base scenario"),
    ('scenario = "nope.toml"\nseeds = 2\n', "scenario: cannot read"),
    (BASE, "nothing to sweep"),
    (BASE + '[grid]\n"car.mas" = [1.0]\n', 'grid."car.mas": not a RailCar parameter (docs/variables.md lists them)'),
    (BASE + '[grid]\n"car.mas" = [1.0]\n', "wind[i].speed_mps); did you mean 'car.mass'?"),
    (BASE + '[fixed]\nduration = 30.0\n[grid]\n"car.mass" = [1.0]\n', "did you mean 'duration_s'?"),
    (BASE + '[grid]\n"driver[0].until_speed_km" = [40.0]\n', "did you mean 'until_speed_kmh'?"),
    (BASE + '[grid]\n"car.mass" = ["heavy"]\n', 'grid."car.mass": expected a finite number'),
    (BASE + '[grid]\n"seed" = [1.5]\n', 'grid."seed": expected an integer'),
    (BASE + '[grid]\n"car.mass" = []\n', 'grid."car.mass": empty list'),
    (BASE + '[grid]\n"car.mass" = {start = 1.0, stop = 2.0}\n', "a range needs exactly start, stop and num"),
    (BASE + '[grid]\n"track.grade_profile" = ["missing.csv"]\n', "file not found"),
    (BASE + '[grid]\n"driver[9].force_N" = [1.0]\n', 'grid."driver[9].force_N": the base scenario has 4'),
    (BASE + '[grid]\n"driver[0].speed" = [1.0]\n', "is not a driver phase key"),
    (BASE + '[grid]\n"name" = ["x"]\n', "nor a sweepable scenario field"),
    (BASE + '[zip]\n"car.mass" = [30.0, 31.0]\n"car.A0" = [1.0]\n', "zipped lists must have equal lengths"),
    (BASE + 'seeds = 0\n', "seeds: expected a count >= 1"),
    (BASE + 'seeds = [1, 1]\n', "repeated seeds"),
    (BASE + 'seeds = 3\n[grid]\n"seed" = [1, 2]\n', "give seeds or a seed, not both"),
    (BASE + '[fixed]\n"car.mass" = 30.0\n[grid]\n"car.mass" = [31.0]\n', "already set in [fixed]"),
    (BASE + '[lhs]\nsamples = 0\n[lhs.bounds]\n"car.mass" = [1.0, 2.0]\n', "lhs.samples: expected an integer >= 1"),
    (BASE + '[lhs]\nsamples = 5\n[lhs.bounds]\n"car.mass" = [2.0, 1.0]\n', "low must be < high"),
    (BASE + '[lhs]\nsamples = 5\n[lhs.bounds]\n"est.batch_size" = [10, 50]\n', "samples real values"),
    (BASE + '[lhs]\nsamples = 5\n[lhs.bounds]\n"car.mass" = [1.0]\n', "expected [low, high]"),
    (BASE + '[lhs]\nsamples = 5\nsead = 1\n[lhs.bounds]\n"car.mass" = [1.0, 2.0]\n', "lhs: unknown key 'sead'"),
    ("name = \n", "not valid TOML"),
])
def test_invalid_sweep_files_name_file_key_and_reason(tmp_path, text, needle):
    p = write(tmp_path, text, "my_sweep.toml")
    with pytest.raises(SweepError) as e:
        load_sweep(p)
    assert "my_sweep.toml" in str(e.value) and needle in str(e.value), str(e.value)


def test_a_name_close_to_none_gets_no_guess(tmp_path):
    p = write(tmp_path, BASE + '[grid]\n"colour" = [1.0]\n', "my_sweep.toml")
    with pytest.raises(SweepError) as e:
        load_sweep(p)
    assert "not a RailCar parameter" in str(e.value) and "did you mean" not in str(e.value)


def test_runs_are_the_product_of_the_blocks_seeds_fastest(tmp_path):
    (tmp_path / "g.csv").write_text("distance_m,grade_permille\n0,0\n")
    p = write(tmp_path, BASE + """seeds = [7, 9]
[fixed]
duration_s = 30
[grid]
"car.mass" = {start = 30.0, stop = 40.0, num = 3}
"track.grade_profile" = ["g.csv"]
[zip]
step_s = [0.1, 0.0]
"est.mass_initial" = [28, 29]
""")
    s = load_sweep(p)
    assert s.axes == ("car.mass", "track.grade_profile", "step_s", "est.mass_initial", "seed")
    assert len(s.runs) == 3 * 1 * 2 * 2 and [r.run_id for r in s.runs] == list(range(12))
    assert [dict(r.values)["seed"] for r in s.runs[:4]] == [7, 9, 7, 9]
    assert [dict(r.values)["car.mass"] for r in s.runs[::4]] == [30.0, 35.0, 40.0]
    first = s.runs[0]
    assert first.scenario.parameter("car.mass") == 30.0 and first.scenario.parameter("seed") == 7
    assert first.scenario.parameter("est.mass_initial") == 28.0            # typed as the FMU's Real
    assert first.scenario.parameter("track.grade_profile") == str((tmp_path / "g.csv").resolve())
    assert first.scenario.duration_s == 30.0 and first.scenario.parameter("car.A0") == 0.89
    bad = s.runs[2]                                                          # step_s = 0: a failed row
    assert bad.scenario is None and "step_s must be > 0" in bad.error
    assert load_sweep(p).fingerprint == s.fingerprint


def test_driver_and_wind_fields_can_be_swept(tmp_path):
    s = load_sweep(write(tmp_path, BASE + '[grid]\n"driver[0].until_speed_kmh" = [40.0, 50.0]\n'
                                          '"stop_after_last_phase" = [false]\n'))
    assert [r.scenario.phases[0].until_speed_mps for r in s.runs] == pytest.approx([40 / 3.6, 50 / 3.6])
    assert s.runs[0].scenario.stop_after_last_phase is False
    assert load_scenario(LEVEL).phases[0].until_speed_mps == pytest.approx(60 / 3.6)   # base untouched


def test_latin_hypercube_is_seeded_stratified_and_within_bounds():
    bounds = {"car.mass": (25.0, 45.0), "car.A0": (0.5, 1.5), "sensor.speed_std": (0.01, 0.15)}
    a = latin_hypercube(bounds, 50, seed=3)
    assert a == latin_hypercube(bounds, 50, seed=3)
    assert a != latin_hypercube(bounds, 50, seed=4)
    for name, (lo, hi) in bounds.items():
        x = np.array([p[name] for p in a])
        assert np.all((x >= lo) & (x <= hi))
        strata = np.floor((x - lo) / (hi - lo) * 50).astype(int)
        assert sorted(strata) == list(range(50))          # one sample in each of the 50 strata


def test_example_sweep_is_a_200_run_hypercube():
    s = load_sweep(ROOT / "scenarios" / "sweeps" / "lhs_mass_A0_noise.toml")
    assert len(s.runs) == 200 and s.axes == ("car.mass", "car.A0", "sensor.speed_std")
    assert all(r.error is None and 25.0 <= dict(r.values)["car.mass"] <= 45.0 for r in s.runs)


# ------------------------------------------------------------------------- one worker process

def test_reset_instance_gives_the_fresh_instance_results_bit_for_bit(built_fmus):
    """The worker's reuse (fmi2Reset between runs, fresh instance after a Fatal) changes nothing."""
    from harness.run.runner import FmuRunner, RunError
    base = dataclasses.replace(load_scenario(LEVEL), duration_s=60.0)
    a = dataclasses.replace(base, parameters={**base.parameters, "seed": 3})
    b = dataclasses.replace(base, parameters={**base.parameters, "seed": 4, "car.mass": 40.0,
                                              "sensor.speed_std": 0.1})
    bad = dataclasses.replace(base, parameters={**base.parameters, "car.mass": -1.0})
    with FmuRunner(built_fmus["RailCar"]) as fresh:
        ref = fresh.run(a)
    r = ReusableRunner(built_fmus["RailCar"])
    try:
        r.run(b)
        again = r.run(a)                                     # on the reset instance
        with pytest.raises(RunError, match="car.mass must be > 0"):
            r.run(bad)                                       # reset, then Fatal: leaked
        after_fatal = r.run(a)                               # a fresh instance
        assert dict(r.counts) == {"instantiate": 2, "reset": 2, "leaked": 1}
    finally:
        r.close()
    for res in (again, after_fatal):
        assert res.signals.keys() == ref.signals.keys()
        for name in ref.signals:
            assert np.array_equal(res.signals[name], ref.signals[name]), name
        assert np.array_equal(res.time, ref.time)
    from harness.metrics.estimation import summarise
    flat = flatten_summary(summarise(ref))
    assert set(flat) == {c.key for c in metric_columns()}
    assert set(calibration(ref)) == {c.key for c in CALIBRATION_COLUMNS}


def test_a_failed_run_is_a_row(built_fmus, tmp_path):
    s = load_sweep(write(tmp_path, SWEEP))
    row = execute_run(str(built_fmus["RailCar"]), None, s.runs[0])
    assert row["status"] == "failed" and "car.mass must be > 0" in row["error"] and "\n" not in row["error"]
    assert row["car.mass"] == -5.0 and row["seed"] == 1 and row["wall_time"] >= 0


# ------------------------------------------------------------------------- whole sweeps

ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT)] + ([os.environ["PYTHONPATH"]]
                                                                  if os.environ.get("PYTHONPATH") else [])),
           PYTHONDONTWRITEBYTECODE="1")


def sweep_cmd(sweep: Path, out: Path, dist: Path, *extra) -> list[str]:
    return [sys.executable, "-m", "harness", "sweep", str(sweep), "--out", str(out), "--dist", str(dist), *extra]


def run_cli(*args, timeout=180) -> subprocess.CompletedProcess:
    return subprocess.run(sweep_cmd(*args), cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout)


def csv_run_ids(out: Path) -> list[int]:
    """Run ids of results.csv in the order written (duplicates included)."""
    with open(out / "results.csv", newline="", encoding="utf-8") as f:
        return [int(r[0]) for r in list(csv.reader(f))[1:]]


@pytest.fixture(scope="module")
def sweep_file(tmp_path_factory) -> Path:
    return write(tmp_path_factory.mktemp("sweep"), SWEEP, "t_sweep.toml")


@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return Path(built_fmus["RailCar"]).parent


@pytest.fixture(scope="module")
def embedded(sweep_file, dist, tmp_path_factory):
    """The reference: the sweep on the embedded local cluster (2 worker processes), with plots."""
    out = tmp_path_factory.mktemp("embedded")
    p = run_cli(sweep_file, out, dist, "--workers", "2")
    assert p.returncode == 1, p.stdout + p.stderr           # 1: some runs failed (car.mass = -5)
    assert "local cluster of 2 worker processes" in p.stdout
    return out, read_results(out), p.stdout


def _kill_group(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=15)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(timeout=15)


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """A real `dask scheduler` and two `dask worker` processes (one thread each) on 127.0.0.1."""
    from distributed import Client
    tmp = tmp_path_factory.mktemp("dask")
    sched_file = tmp / "scheduler.json"
    procs = []

    def start(args, log):
        p = subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=ROOT, env=ENV, start_new_session=True,
                             stdout=open(tmp / log, "w"), stderr=subprocess.STDOUT)
        procs.append(p)
        return p

    try:
        start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
               "--scheduler-file", str(sched_file)], "scheduler.log")
        deadline = time.monotonic() + 60
        while not sched_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert sched_file.is_file(), (tmp / "scheduler.log").read_text()
        time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        workers = [start(["worker", address, "--nthreads", "1", "--nworkers", "1", "--no-dashboard",
                          "--host", "127.0.0.1", "--death-timeout", "60"], f"worker{i}.log") for i in range(2)]
        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for p in reversed(procs):
            _kill_group(p)


def test_embedded_sweep_writes_rows_summary_and_plots(embedded):
    out, table, stdout = embedded
    assert [r["run_id"] for r in table.rows] == list(range(N_RUNS))
    assert sorted(csv_run_ids(out)) == list(range(N_RUNS))
    failed = [r for r in table.rows if r["status"] == "failed"]
    assert [r["car.mass"] for r in failed] == [-5.0] * 6
    assert all("car.mass must be > 0" in r["error"] for r in failed)
    ok = [r for r in table.rows if r["status"] == "ok"]
    assert all(r["speed_rmse_filter"] < r["speed_rmse_sensor"] and r["moving_samples"] > 0 for r in ok)
    assert {(r["engine"], r["fmu"]) for r in ok} == {("c", "")}          # the default: the C batch engine
    assert "engine: batch (--engine auto: the C core covers every run)" in stdout
    assert [r["seed"] for r in table.rows[:3]] == [1, 2, 3]
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert header[:7] == ["run_id", "status", "error", "wall_time [s]", "car.mass [t]",
                          "driver[0].until_speed_kmh [km/h]", "seed [-]"]
    assert "speed_rmse_filter [m/s]" in header and "mass_errors_at_stops_pct.max_abs [%]" in header
    assert "calibration: truth inside" in stdout and "6 x (runs 0, 1, 2, 3, 4, ...)" in stdout
    assert (out / "summary.md").is_file()
    plots = {p.name for p in (out / "plots").glob("*.png")}
    kinds = ("heatmap_car.mass__driver_0_.until_speed_kmh", "histograms", "vs_car.mass",
             "vs_driver_0_.until_speed_kmh")
    groups = {g for g, _, _ in PLOT_GROUPS if f"{g}_histograms.png" in plots}
    assert {"mass", "filter_accuracy"} <= groups                  # each group: one figure of each kind
    assert plots == {f"{g}_{k}.png" for g in groups for k in kinds}


def test_parquet_holds_the_csv_rows(embedded):
    pq = pytest.importorskip("pyarrow.parquet")
    out, table, _ = embedded
    t = pq.read_table(out / "results.parquet")
    assert t.schema.field("car.mass").metadata == {b"unit": b"t"}
    rows = sorted(t.to_pylist(), key=lambda r: r["run_id"])
    for a, b in zip(rows, table.rows):
        assert {k: v for k, v in a.items() if k != "wall_time"} == pytest.approx(
            {k: v for k, v in b.items() if k != "wall_time"}, nan_ok=True)


def test_scheduler_gives_the_embedded_rows_bit_for_bit(embedded, dask_cluster, sweep_file, dist, tmp_path):
    address, _ = dask_cluster
    p = run_cli(sweep_file, tmp_path, dist, "--scheduler", address, "--no-plots")
    assert p.returncode == 1, p.stdout + p.stderr
    assert f"on {address}" in p.stdout and "on 2 workers" in p.stdout
    assert "engine: batch (--engine auto: the C core covers every run)" in p.stdout    # the external
    table = read_results(tmp_path)                                   # scheduler's workers ran the batch engine
    assert {r["engine"] for r in table.rows if r["status"] == "ok"} == {"c"}
    assert table.comparable() == embedded[1].comparable()
    def summary(out):            # but the line of this call's time
        return [x for x in (out / "summary.md").read_text().splitlines() if not x.startswith("  rows ")]
    assert summary(tmp_path) == summary(embedded[0])


def test_a_worker_killed_mid_sweep_loses_no_run_and_counts_none_twice(embedded, dask_cluster, sweep_file, dist,
                                                                      tmp_path):
    import psutil
    from distributed import Client
    address, workers = dask_cluster
    proc = subprocess.Popen(sweep_cmd(sweep_file, tmp_path, dist, "--scheduler", address, "--no-plots"),
                            cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        rows_at_kill = 0
        while time.monotonic() < deadline and proc.poll() is None:
            if (tmp_path / "results.csv").is_file():
                rows_at_kill = len((tmp_path / "results.csv").read_text().splitlines()) - 1
                if rows_at_kill >= 1:
                    break
            time.sleep(0.02)
        # the worker process under the first `dask worker` (its nanny): as if it segfaulted
        victims = [c for c in psutil.Process(workers[0].pid).children(recursive=True)
                   if "spawn_main" in " ".join(c.cmdline())]
        assert len(victims) == 1, [c.cmdline() for c in psutil.Process(workers[0].pid).children(recursive=True)]
        victims[0].send_signal(signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=150)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert 1 <= rows_at_kill < N_RUNS, "the worker was not killed mid-sweep"
    assert proc.returncode == 1, stdout + stderr
    ids = csv_run_ids(tmp_path)
    assert sorted(ids) == list(range(N_RUNS)), ids                   # each run exactly once
    assert read_results(tmp_path).comparable() == embedded[1].comparable()
    with Client(address, timeout="30s") as c:                        # the nanny replaced the worker
        c.wait_for_workers(2, timeout=60)


def test_resume_after_an_interruption_gives_the_uninterrupted_table(embedded, dask_cluster, sweep_file, dist,
                                                                    tmp_path):
    address, _ = dask_cluster
    p = run_cli(sweep_file, tmp_path, dist, "--scheduler", address, "--no-plots", "--limit", "8")
    assert "not run yet: 10 runs" in p.stdout, p.stdout + p.stderr
    assert sorted(csv_run_ids(tmp_path)) == list(range(8))
    with open(tmp_path / "results.csv", "a", encoding="utf-8") as f:   # killed while writing a row
        f.write("9,ok,,0.25,30.0")
    p = run_cli(sweep_file, tmp_path, dist, "--scheduler", address, "--no-plots", "--resume")
    assert p.returncode == 1, p.stdout + p.stderr
    assert "this call ran 10" in p.stdout and "8 rows kept from before" in p.stdout
    assert sorted(csv_run_ids(tmp_path)) == list(range(N_RUNS))
    assert read_results(tmp_path).comparable() == embedded[1].comparable()
    # the same folder with another sweep: refused, nothing run
    other = write(tmp_path, SWEEP.replace("duration_s = 60.0", "duration_s = 50.0"), "other.toml")
    p = run_cli(other, tmp_path, dist, "--scheduler", address, "--resume")
    assert p.returncode == 2 and "results there are of another sweep" in p.stderr
    assert sorted(csv_run_ids(tmp_path)) == list(range(N_RUNS))


def test_sweep_columns_match_the_rows(tmp_path):
    s = load_sweep(write(tmp_path, SWEEP))
    keys = [c.key for c in sweep_columns(s)]
    assert len(keys) == len(set(keys)) and keys[:7] == ["run_id", "status", "error", "wall_time", "car.mass",
                                                        "driver[0].until_speed_kmh", "seed"]


def test_two_sweeps_cannot_write_one_folder(tmp_path):
    s = load_sweep(write(tmp_path, SWEEP))
    first = ResultsWriter(tmp_path / "out", s, "guid", resume=False)
    try:
        with pytest.raises(SweepError, match="another sweep is writing there"):
            ResultsWriter(tmp_path / "out", s, "guid", resume=True)
    finally:
        first.close()
    ResultsWriter(tmp_path / "out", s, "guid", resume=True).close()      # free again once closed


def test_reading_and_plotting_a_sweep_loads_no_dask_and_no_fmu_library():
    """Computing apart from execution: the sweep file, the table, the results folder and the
    plots import neither dask nor an FMU library; harness.sweep.execute does (the control)."""
    code = ("import sys\n"
            "import harness.sweep.spec, harness.sweep.table, harness.sweep.results, harness.sweep.plots\n"
            "heavy = ('distributed', 'dask', 'fmpy', 'pythonfmu')\n"
            "print(sorted(m for m in heavy if m in sys.modules))\n"
            "import harness.sweep.execute\n"
            "print(sorted(m for m in heavy if m in sys.modules))\n")
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    parts, with_exec = p.stdout.splitlines()
    assert parts == "[]"
    assert "'fmpy'" in with_exec and "'pythonfmu'" in with_exec

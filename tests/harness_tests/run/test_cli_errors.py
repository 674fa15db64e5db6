"""Invalid input to the harness's command line: exit code 2 and one line naming the file and the key
or line, never a traceback (README "The validation harness"); seeds in the FMU's 32-bit range; a
sweep that would discard results; the embedded dask cluster's temporary files.

Every bad input of the parametrised test is caught before an FMU is built or run: each gets an
unused ``--dist`` folder, which must still not exist afterwards. The tests that run FMUs use the
session build (tests/conftest.py).
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
LEVEL = (ROOT / "scenarios" / "library" / "level_run.toml").as_posix()
BOM = b"\xef\xbb\xbf"
BINARY = bytes(range(256)) * 4          # NUL first, invalid UTF-8 at 0x80
LOG_HEADER = "time [s],traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]\n"
GOOD_LOG = LOG_HEADER + "0,0,0,0,0\n0.1,100,0,0.01,0\n0.2,100,0,0.02,0.001\n"
DRIVE = '[[driver]]\naction = "coast"\nuntil_time_s = 1.0\n'
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT)] + ([os.environ["PYTHONPATH"]]
                                                                  if os.environ.get("PYTHONPATH") else [])),
           PYTHONDONTWRITEBYTECODE="1")


def harness(*args, env=None, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "harness", *map(str, args)], cwd=ROOT, env=env or ENV,
                          capture_output=True, text=True, timeout=timeout)


def put(path: Path, content: str | bytes) -> Path:
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
    return path


def scenario(tmp: Path, params: str = "", extra: str = DRIVE, name: str = "s.toml") -> Path:
    return put(tmp / name, f'name = "t"\nduration_s = 5.0\n{extra}[parameters]\n{params}\n')


def sweep_file(tmp: Path, body: str, name: str = "sw.toml") -> Path:
    return put(tmp / name, f'scenario = "{LEVEL}"\n{body}\n')


def table_scenario(tmp: Path, demands: bytes) -> Path:
    put(tmp / "d.csv", demands)
    return put(tmp / "s.toml", 'name = "t"\n[driver_table]\nfile = "d.csv"\n')


def grade_scenario(tmp: Path, grade: bytes) -> Path:
    put(tmp / "g.csv", grade)
    return scenario(tmp, '"track.grade_profile" = "g.csv"')


def binary_base_sweep(tmp: Path) -> Path:
    put(tmp / "base.toml", BINARY)
    return put(tmp / "sw.toml", 'scenario = "base.toml"\nseeds = 2\n')


def rerun_case(tmp: Path):
    p, out = prepared_results(tmp)
    return ["sweep", p, "--out", out], [f"{out} already holds 1 results of sweep 'sw'", "--resume", "--overwrite"]


def binary_results_case(tmp: Path):
    p, out = prepared_results(tmp)
    put(out / "results.csv", BINARY)
    return ["sweep", p, "--out", out, "--resume"], ["results.csv", "not UTF-8 text"]


def prepared_results(tmp: Path) -> tuple[Path, Path]:
    """A sweep file and a folder holding one row of its results (written as a sweep writes them)."""
    from harness.sweep.main import ResultsWriter, load_sweep
    p = sweep_file(tmp, "seeds = 2\n[fixed]\nduration_s = 10.0")
    w = ResultsWriter(tmp / "out", load_sweep(p), "guid", resume=False)
    w.write({"run_id": 0, "status": "ok", "error": ""})
    w.close()
    return p, tmp / "out"


# Each case: tmp folder -> (arguments after `python -m harness`, strings stderr must contain).
CASES = {
    # ---- run
    "run: binary TOML": lambda t: (["run", put(t / "bin.toml", BINARY)],
                                   ["bin.toml", "not UTF-8 text (byte offset 0)"]),
    "run: non-UTF-8 TOML": lambda t: (["run", put(t / "l1.toml", 'name = "caf\xe9"\n'.encode("latin-1"))],
                                      ["l1.toml", "not UTF-8 text (byte offset 11)"]),
    "run: UTF-16 TOML": lambda t: (["run", put(t / "u16.toml", 'name = "t"\n'.encode("utf-16"))],
                                   ["u16.toml", "not UTF-8 text (byte offset 0)", "UTF-16"]),
    "run: TOML syntax": lambda t: (["run", put(t / "s.toml", 'name = "t"\nstep_s = \n')], ["s.toml", "line 2"]),
    "run: missing file": lambda t: (["run", t / "nope.toml"], ["nope.toml", "cannot read"]),
    "run: parameters = 5": lambda t: (["run", put(t / "s.toml", f'name = "t"\nparameters = 5\n{DRIVE}')],
                                      ["s.toml", "parameters"]),
    "run: wind = [1, 2]": lambda t: (["run", put(t / "s.toml", f'name = "t"\nwind = [1, 2]\n{DRIVE}')],
                                     ["s.toml", "wind[0]"]),
    "run: driver = 5": lambda t: (["run", put(t / "s.toml", 'name = "t"\ndriver = 5\n')], ["s.toml", "driver"]),
    "run: driver_table = 5": lambda t: (["run", put(t / "s.toml", 'name = "t"\ndriver_table = 5\n')],
                                        ["s.toml", "driver_table"]),
    "run: driver_table text": lambda t: (["run", put(t / "s.toml", 'name = "t"\n[driver_table]\ntime_s = ["a"]\n')],
                                         ["s.toml", "driver_table.time_s[0]"]),
    "run: driver_table file binary": lambda t: (["run", table_scenario(t, BINARY)],
                                                ["s.toml", "driver_table.file", "d.csv", "not UTF-8"]),
    "run: car.mass = 0": lambda t: (["run", scenario(t, '"car.mass" = 0.0')],
                                    ["s.toml", 'parameters."car.mass"', "must be > 0"]),
    "run: seed = -3": lambda t: (["run", scenario(t, "seed = -3")], ["s.toml", 'parameters."seed"', "0..2147483647"]),
    "run: seed = 2**32 + 1": lambda t: (["run", scenario(t, "seed = 4294967297")],
                                        ["s.toml", 'parameters."seed"', "0..2147483647"]),
    "run: est.batch_size = 2": lambda t: (["run", scenario(t, '"est.batch_size" = 2')],
                                          ["s.toml", 'parameters."est.batch_size"', ">= 4"]),
    "run: filter.kind 1 without a speed profile": lambda t: (["run", scenario(t, '"filter.kind" = 1')],
                                                             ["s.toml", 'parameters."filter.kind"']),
    "run: grade profile missing": lambda t: (["run", scenario(t, '"track.grade_profile" = "g.csv"')],
                                             ["s.toml", '"track.grade_profile"', "g.csv", "file not found"]),
    "run: grade profile bad line": lambda t: (["run", grade_scenario(t, b"distance_m,grade_permille\n0,0\n10,x\n")],
                                              ["s.toml", '"track.grade_profile"', "g.csv", "line 3"]),
    "run: --out is a file": lambda t: (["run", scenario(t), "--out", put(t / "o.txt", "x")], ["--out", "o.txt"]),
    "run: --log is a folder": lambda t: (["run", scenario(t), "--log", t], ["--log", str(t)]),
    "run: --dist is a file": lambda t: (["run", scenario(t), "--dist", put(t / "d.txt", "x")], ["--dist", "d.txt"]),
    # ---- replay
    "replay: binary log": lambda t: (["replay", put(t / "log.csv", BINARY)], ["log.csv", "not UTF-8 text"]),
    "replay: missing log": lambda t: (["replay", t / "nope.csv"], ["nope.csv", "cannot read"]),
    "replay: negative force": lambda t: (
        ["replay", put(t / "log.csv", LOG_HEADER + "0,0,0,0,0\n0.1,-5,0,0,0\n0.2,0,0,0,0\n")],
        ["log.csv", "line 3", "traction_force", ">= 0"]),
    "replay: column twice": lambda t: (["replay", put(t / "log.csv", GOOD_LOG.replace("sensor.position", "time", 1))],
                                       ["log.csv", "line 1", "'time' appears twice"]),
    "replay: --param batch_size=0": lambda t: (["replay", put(t / "log.csv", GOOD_LOG), "--param", "batch_size=0"],
                                               ["--param batch_size", "not a RailCarEstimator parameter"]),
    "replay: --param est.batch_size=0": lambda t: (
        ["replay", put(t / "log.csv", GOOD_LOG), "--param", "est.batch_size=0"], ["--param est.batch_size", ">= 4"]),
    "replay: --param seed=": lambda t: (["replay", put(t / "log.csv", GOOD_LOG), "--param", "seed=4294967297"],
                                        ["--param seed"]),
    "replay: --param without =": lambda t: (["replay", put(t / "log.csv", GOOD_LOG), "--param", "est.A0"],
                                            ["--param", "NAME=VALUE"]),
    "replay: missing grade file": lambda t: (
        ["replay", put(t / "log.csv", GOOD_LOG), "--param", f"track.grade_profile={t / 'grade.csv'}"],
        ["--param track.grade_profile", "grade.csv", "file not found"]),
    # ---- regress, report
    "regress: unknown scenario": lambda t: (["regress", "no_such_scenario"], ["no_such_scenario"]),
    "regress: --dist is a file": lambda t: (["regress", "level_run", "--dist", put(t / "d.txt", "x")],
                                            ["--dist", "d.txt"]),
    "report: unknown scenario": lambda t: (["report", "no_such_scenario"], ["no_such_scenario"]),
    "report: --out is a file": lambda t: (["report", "level_run", "--out", put(t / "o.txt", "x")], ["--out", "o.txt"]),
    # ---- sweep
    "sweep: binary file": lambda t: (["sweep", put(t / "sw.toml", BINARY)], ["sw.toml", "not UTF-8 text"]),
    "sweep: base scenario binary": lambda t: (["sweep", binary_base_sweep(t)],
                                              ["sw.toml", "scenario", "base.toml", "not UTF-8 text"]),
    "sweep: seeds wrap": lambda t: (["sweep", sweep_file(t, "seeds = [4294967297, 1]")],
                                    ["sw.toml", "seeds[0]", "0..2147483647"]),
    "sweep: seeds negative": lambda t: (["sweep", sweep_file(t, "seeds = [1, -1]")],
                                        ["sw.toml", "seeds[1]", "0..2147483647"]),
    "sweep: seeds count too large": lambda t: (["sweep", sweep_file(t, "seeds = 2147483648")],
                                               ["sw.toml", "seeds", "2147483647"]),
    "sweep: seed in a grid": lambda t: (["sweep", sweep_file(t, '[grid]\n"seed" = [2147483648]')],
                                        ["sw.toml", 'grid."seed"', "0..2147483647"]),
    "sweep: fixed = 5": lambda t: (["sweep", sweep_file(t, "fixed = 5\nseeds = 2")], ["sw.toml", "fixed"]),
    "sweep: --out is a file": lambda t: (["sweep", sweep_file(t, "seeds = 2"), "--out", put(t / "o.txt", "x")],
                                         ["--out", "o.txt"]),
    "sweep: rerun without --resume": lambda t: rerun_case(t),
    "sweep: --resume with a binary results.csv": lambda t: binary_results_case(t),
    "sweep: --resume and --overwrite": lambda t: (
        ["sweep", sweep_file(t, "seeds = 2"), "--out", t / "o", "--resume", "--overwrite"],
        ["--resume", "--overwrite"]),
}


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory) -> dict:
    """Every case's command, run concurrently (each is a fresh interpreter: ~0.4 s of start-up)."""
    def one(case, tmp):
        args, needles = CASES[case](tmp)
        dist = tmp / "dist_unused"
        if "--dist" not in args:
            args += ["--dist", dist]
        return harness(*args), needles, dist

    folders = {case: tmp_path_factory.mktemp("case") for case in CASES}
    with ThreadPoolExecutor(max_workers=2 * (os.cpu_count() or 1)) as pool:
        futures = {case: pool.submit(one, case, folders[case]) for case in CASES}
        return {case: f.result() for case, f in futures.items()}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_exits_2_with_one_line_naming_the_file_and_key(case, outcomes):
    p, needles, dist = outcomes[case]
    assert p.returncode == 2, f"{case}: exit {p.returncode}\n{p.stdout}\n{p.stderr}"
    assert "Traceback" not in p.stderr, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), p.stderr
    for needle in needles:
        assert needle in lines[0], f"{case}: {needle!r} not in {lines[0]!r}"
    assert not dist.exists(), "an FMU was built: the input should have been refused before"


# ------------------------------------------------------------------------------ BOM, seeds

def test_a_bom_is_skipped_in_logs_toml_files_profiles_and_driver_tables(tmp_path):
    from harness.run.replay import read_log
    from harness.run.scenario import load_scenario
    log = read_log(put(tmp_path / "log.csv", BOM + GOOD_LOG.encode()))
    assert list(log.columns)[:2] == ["time", "traction_force"] and log.time[-1] == 0.2
    s = load_scenario(put(tmp_path / "s.toml", BOM + f'name = "t"\n{DRIVE}'.encode()))
    assert s.name == "t"
    s = load_scenario(grade_scenario(tmp_path, BOM + b"distance_m,grade_permille\n0,2\n"))
    assert s.parameter("track.grade_profile").endswith("g.csv")
    s = load_scenario(table_scenario(tmp_path, BOM + b"time_s,traction_N,brake_N\n0,5,0\n"))
    assert s.time_table.traction_N[0] == 5.0


def test_seeds_are_refused_outside_the_fmus_32_bit_range(tmp_path):
    """0 and 2**31 - 1 are seeds; -1 and 2**31 are not (no wrap: 2**32 + 1 used to run as seed 1)."""
    from harness.run.runner import _int32
    from harness.run.scenario import ScenarioError, scenario_from_dict
    from harness.sweep.main import SweepError, load_sweep

    def with_seed(seed):
        return scenario_from_dict({"name": "t", "parameters": {"seed": seed},
                                   "driver": [{"action": "coast", "until_time_s": 1.0}]}, "s.toml", tmp_path)

    assert with_seed(0).parameter("seed") == 0
    assert with_seed(2 ** 31 - 1).parameter("seed") == 2 ** 31 - 1
    for bad in (-1, 2 ** 31, 2 ** 32 + 1):
        with pytest.raises(ScenarioError, match=r'parameters."seed": must be in 0..2147483647'):
            with_seed(bad)
    s = load_sweep(sweep_file(tmp_path, "seeds = [2147483647, 0]"))
    assert [dict(r.values)["seed"] for r in s.runs] == [2 ** 31 - 1, 0]
    for body in ("seeds = [4294967297, 1]", '[grid]\n"seed" = [-1]', '[fixed]\nseed = 2147483648\n[grid]\n'
                 '"car.mass" = [30.0]'):
        with pytest.raises(SweepError, match="0..2147483647"):
            load_sweep(sweep_file(tmp_path, body))
    assert _int32("seed", 2 ** 31 - 1) == 2 ** 31 - 1          # the runner's last line of defence
    for name, bad in (("seed", 2 ** 32 + 1), ("seed", -1), ("est.batch_size", 2 ** 31)):
        with pytest.raises(ValueError, match="32-bit"):
            _int32(name, bad)


def test_an_unreadable_reference_is_invalid_input_naming_the_file(tmp_path):
    from harness.run.regress import ReferenceFileError, read_reference
    put(tmp_path / "x_ref.csv", BINARY)
    put(tmp_path / "x_ref.opt", "StartTime, 0.0\nStopTime, 1.0\nStepSize, 0.1\nRelTol, 1e-06\n")
    with pytest.raises(ReferenceFileError, match=r"x_ref.csv: not UTF-8 text \(byte offset 0\)"):
        read_reference("x", tmp_path)
    put(tmp_path / "x_ref.csv", '"time","car.speed"\n0.0,0.0\n1.0,1.0\n')
    ref, opts = read_reference("x", tmp_path)
    assert ref["car.speed"][-1] == 1.0 and opts["StopTime"] == 1.0


# ------------------------------------------------------------------------------ with FMUs

def test_an_fmu_that_refuses_to_initialise_is_invalid_input(built_fmus, tmp_path, monkeypatch, capsys):
    """Should the harness's checks miss a parameter the FMU refuses, the refusal is still exit 2,
    naming the scenario file (with the checks skipped here to make the FMU see car.mass = 0)."""
    import models.compiled
    from harness.__main__ import main
    # the checks at loading (harness.run.scenario.resolve_setup) validate with this
    monkeypatch.setattr(models.compiled, "validate", lambda cfg, *a, **k: cfg)
    p = scenario(tmp_path, '"car.mass" = 0.0')
    assert main(["run", str(p), "--out", str(tmp_path / "o"), "--dist", str(built_fmus["RailCar"].parent)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "s.toml: parameters: the FMU refused to initialise" in err[0], err
    assert "car.mass must be > 0" in err[0], err


SWEEP_BODY = "seeds = 2\n[fixed]\nduration_s = 20.0"


def private_tmp(tmp_path: Path) -> tuple[Path, dict]:
    tmp = tmp_path / "tmpdir"
    tmp.mkdir()
    return tmp, dict(ENV, TMPDIR=str(tmp))


def test_sweep_rerun_needs_resume_or_overwrite_and_leaves_no_temporary_files(built_fmus, tmp_path):
    """A rerun into a folder with results is refused (its rows intact); --overwrite starts afresh,
    --resume runs nothing more. The embedded cluster leaves nothing in the temporary folder (its
    workers' FMU extractions and dask's scratch space are removed with it)."""
    dist = built_fmus["RailCar"].parent
    tmp, env = private_tmp(tmp_path)
    p, out = sweep_file(tmp_path, SWEEP_BODY), tmp_path / "out"
    first = harness("sweep", p, "--out", out, "--dist", dist, "--workers", "1", "--no-plots", env=env)
    assert first.returncode == 0, first.stdout + first.stderr
    assert list(tmp.iterdir()) == []
    rows = (out / "results.csv").read_text()
    again = harness("sweep", p, "--out", out, "--dist", dist, "--workers", "1", "--no-plots", env=env)
    assert again.returncode == 2 and "Traceback" not in again.stderr
    assert f"{out} already holds 2 results of sweep 'sw': use --resume to continue or --overwrite to start " \
           f"again" in again.stderr
    assert (out / "results.csv").read_text() == rows                      # untouched
    other = sweep_file(tmp_path, SWEEP_BODY.replace("20.0", "10.0"), "other.toml")
    p2 = harness("sweep", other, "--out", out, "--dist", dist, env=env)
    assert p2.returncode == 2 and "another sweep" in p2.stderr and "--overwrite" in p2.stderr
    fresh = harness("sweep", p, "--out", out, "--dist", dist, "--workers", "1", "--no-plots", "--overwrite",
                    env=env)
    assert fresh.returncode == 0 and "this call ran 2" in fresh.stdout, fresh.stdout + fresh.stderr
    assert len((out / "results.csv").read_text().splitlines()) == 3         # header + 2 rows, not 4
    resumed = harness("sweep", p, "--out", out, "--dist", dist, "--no-plots", "--resume", env=env)
    assert resumed.returncode == 0 and "this call ran 0" in resumed.stdout, resumed.stdout + resumed.stderr
    assert list(tmp.iterdir()) == []


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_an_interrupted_sweep_removes_its_workers_temporary_files(built_fmus, tmp_path, how):
    """Ctrl-C on the terminal (SIGINT to the whole process group) or SIGTERM to the sweep's process
    mid-sweep: exit 1, the finished rows kept, no KeyboardInterrupt traceback (the workers ignore
    SIGINT; the sweep closes them), nothing left in the temporary folder."""
    tmp, env = private_tmp(tmp_path)
    p, out = sweep_file(tmp_path, "seeds = 40\n[fixed]\nduration_s = 100.0"), tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "harness", "sweep", str(p), "--out", str(out), "--dist",
                             str(built_fmus["RailCar"].parent), "--workers", "2", "--no-plots"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            # a pytest started in the background (nohup ... &) hands its children
                            # SIGINT ignored, and Python then never raises KeyboardInterrupt: the
                            # sweep gets the terminal's default, as a user's would
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:
            f = out / "results.csv"
            if f.is_file() and len(f.read_text().splitlines()) >= 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep ended before it could be interrupted"
        assert [d.name[:14] for d in tmp.iterdir()] == ["railcar-sweep-"]     # the cluster's scratch folder
        if how == "ctrl-c":
            os.killpg(proc.pid, signal.SIGINT)
        else:
            os.kill(proc.pid, signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 1, stdout + stderr
    # the sweep's own process ends with its message, no traceback of its own (under heavy load a worker
    # closing after the scheduler may log a heartbeat error: dask's, not the harness's)
    assert stderr.strip().splitlines()[-1].startswith("interrupted: the finished runs are in"), stderr
    assert "KeyboardInterrupt" not in stderr, stderr
    assert 1 <= len((out / "results.csv").read_text().splitlines()) - 1 < 40
    assert list(tmp.iterdir()) == [], [str(x) for x in tmp.rglob("*")][:10]
    shutil.rmtree(tmp, ignore_errors=True)

"""``--fmu auto|native|python`` (harness/run/fmus.py) for every harness command that runs an FMU.

- run, regress, report, filters, replay and sweep each run with each kind; the choice is printed
  ("fmu: native|python PATH ...") and recorded (summary.md, library.md, the replay's text, the
  sweep's ``fmu`` column and summary);
- ``auto`` picks the native FMU when it covers the parameters (est.method 2 and est.physical 1
  included) and the pythonfmu FMU for ``est.method`` 3 (run, replay, a sweep with one such run)
  or 1 (a library scenario);
- the outputs of both kinds are bit-identical on a covered scenario (result CSV, replay
  estimates, sweep rows, library and filter tables); a one-ulp change is seen by the comparison;
- ``native`` with ``est.method`` 3 fails initialisation with a message naming est.method;
- ensure_built rebuilds a stale native FMU (and not for ``--fmu python``); without a native FMU
  that cannot be built, auto falls back to the pythonfmu FMU and ``native`` says why;
- a sweep worker loads a native FMU rebuilt at the same path (the pythonfmu one refuses).

Every FMU comes from the session build (tests/conftest.py, built_fmus); short scenarios (a 60 s
level run) keep the module at about 45 s, 20 s of them the one real rebuild.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any FMU is loaded in this process)

import contextlib
import csv
import dataclasses
import io
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from harness.__main__ import main
from harness.run.fmus import NATIVE_NAMES, fmu_guid, native_path

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ROOT / "scenarios" / "library"
KINDS = ("auto", "native", "python")


# ------------------------------------------------------------------------------ helpers

def float_bits(path: Path) -> np.ndarray:
    """A CSV of numbers (one header line) as the float64 bit patterns of its cells."""
    rows = list(csv.reader(io.StringIO(path.read_text(encoding="utf-8"))))[1:]
    return np.array([[float(x) for x in r] for r in rows], dtype=np.float64).view(np.uint64)


def assert_same_bits(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape, (a.shape, b.shape)
    diff = np.argwhere(a != b)
    assert diff.size == 0, f"{len(diff)} cells differ, first at {tuple(int(i) for i in diff[0])}"


def short_scenario(folder: Path, extra: str = "", name: str = "short.toml") -> Path:
    """level_run cut to 60 s (600 steps, traction then coasting), with ``extra`` parameters."""
    text = (LIBRARY / "level_run.toml").read_text(encoding="utf-8").replace("duration_s = 400.0",
                                                                            "duration_s = 60.0")
    text = text.replace("[parameters]\n", f"[parameters]\n{extra}")
    p = folder / name
    p.write_text(text, encoding="utf-8")
    return p


def fmu_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("fmu: ")]


@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return Path(built_fmus["RailCar"]).parent


@pytest.fixture(scope="module")
def paths(dist) -> dict:
    return {"python": dist / "RailCar.fmu", "native": native_path("RailCar", dist),
            "est_python": dist / "RailCarEstimator.fmu", "est_native": native_path("RailCarEstimator", dist)}


# ------------------------------------------------------------------------------ run (+ a log for replay)

@pytest.fixture(scope="module")
def runs(dist, tmp_path_factory):
    """``run`` of the short level run with each kind (and a replay log): {kind: (out, stdout)}."""
    tmp = tmp_path_factory.mktemp("run")
    scenario = short_scenario(tmp)
    out = {}
    for kind in KINDS:
        cap = io.StringIO()
        with contextlib.redirect_stdout(cap):
            code = main(["run", str(scenario), "--out", str(tmp / kind), "--dist", str(dist), "--fmu", kind,
                         "--log", str(tmp / kind / "log.csv")])
        assert code == 0, cap.getvalue()
        out[kind] = (tmp / kind, cap.getvalue())
    return out


def test_run_says_which_fmu_ran_and_both_kinds_are_bit_identical(runs, paths):
    for kind, want in (("auto", "native"), ("native", "native"), ("python", "python")):
        folder, stdout = runs[kind]
        assert fmu_lines(stdout) == [fmu_lines(stdout)[0]] and fmu_lines(stdout)[0].startswith(
            f"fmu: {want} {paths[want]} (--fmu {kind}: "), stdout
        summary = (folder / "summary.md").read_text(encoding="utf-8")
        # the report names the FMU's file, not this machine's folders (outside the repository)
        assert f"FMU: {want} {paths[want].name} (--fmu {kind}: " in summary
        assert str(paths[want].parent) not in summary
    native, python, auto = (float_bits(runs[k][0] / "level_run_result.csv") for k in ("native", "python", "auto"))
    assert native.shape[0] == 601 and native.shape[1] >= 20, native.shape   # 60 s at 0.1 s, and t = 0
    values = native.view(np.float64)[:, 1:]
    assert np.count_nonzero(values) > 0.5 * values.size                     # not a table of zeros
    assert_same_bits(native, python)
    assert_same_bits(auto, native)
    logs = [(runs[k][0] / "log.csv").read_bytes() for k in KINDS]
    assert logs[0] == logs[1] == logs[2]


def test_the_bit_comparison_sees_one_ulp(runs):
    """The comparison above can fail: one output one ulp off, in one row, is caught."""
    a = float_bits(runs["python"][0] / "level_run_result.csv")
    b = a.view(np.float64).copy()
    b[300, 5] = np.nextafter(b[300, 5], np.inf)
    with pytest.raises(AssertionError, match=r"1 cells differ, first at \(300, 5\)"):
        assert_same_bits(a, b.view(np.uint64))


def test_run_auto_takes_python_for_est_method_3_and_native_refuses_it_by_name(dist, paths, tmp_path, capsys):
    scenario = short_scenario(tmp_path, '"est.method" = 3\n')
    assert main(["run", str(scenario), "--out", str(tmp_path / "auto"), "--dist", str(dist)]) == 0   # default: auto
    out = capsys.readouterr().out
    assert fmu_lines(out) == [f"fmu: python {paths['python']} (--fmu auto: {scenario} sets est.method = 3, "
                              f"which the native FMU does not cover)"], out
    assert f"FMU: python {paths['python'].name} (--fmu auto: " in (tmp_path / "auto" / "summary.md").read_text(encoding="utf-8")
    assert main(["run", str(scenario), "--out", str(tmp_path / "native"), "--dist", str(dist), "--fmu", "native"]) == 2
    cap = capsys.readouterr()
    assert fmu_lines(cap.out)[0].startswith(f"fmu: native {paths['native']} (--fmu native: as asked; it refuses "
                                            f"est.method = 3")
    err = cap.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {scenario}: parameters: the FMU refused to initialise: "
                                               f"est.method = 3 is not in the native RailCar FMU"), err
    assert err[0].endswith("(--fmu auto or --fmu python runs it on the pythonfmu FMU)"), err


@pytest.mark.parametrize("model", ["RailCar", "RailCarEstimator"])
def test_auto_takes_native_for_slope_ls_and_names_only_what_it_lacks(dist, paths, model):
    """est.method 2 (any est.slope_window), est.physical 1 and est.sigma2_method 1 run on the native FMU; a refusal
    names the options the native FMU lacks, not est.physical beside them."""
    from harness.run.fmus import choose, uncovered
    native = paths["native" if model == "RailCar" else "est_native"]
    for params in ({"est.method": 2}, {"est.method": 2, "est.slope_window": 6, "est.physical": 1},
                   {"est.sigma2_method": 1}, {"est.method": 2, "est.sigma2_method": 1}):
        assert uncovered(model, params) is None
        choice = choose("auto", model, dist, [("s", params)])
        assert (choice.kind, choice.path) == ("native", native), choice
    assert uncovered(model, {"est.method": 3, "est.physical": 1}) == "est.method = 3"
    assert uncovered(model, {"est.method": 1, "est.sigma2_method": 1}) == "est.method = 1"
    choice = choose("auto", model, dist, [("a", {"est.method": 2}), ("b", {"est.method": 1})])
    assert choice.kind == "python" and choice.why == "b sets est.method = 1, which the native FMU does not cover"


# ------------------------------------------------------------------------------ replay

def test_replay_with_each_kind(runs, dist, paths, tmp_path, capsys):
    log = runs["python"][0] / "log.csv"
    for kind, want in (("auto", "est_native"), ("native", "est_native"), ("python", "est_python")):
        assert main(["replay", str(log), "--out", str(tmp_path / kind), "--dist", str(dist), "--fmu", kind]) == 0
        out = capsys.readouterr().out
        name = want.split("_")[1]
        assert fmu_lines(out)[0].startswith(f"fmu: {name} {paths[want]} (--fmu {kind}: "), out
        assert f"ran on the FMU {name} ({paths[want].name})" in out
    est = {k: float_bits(tmp_path / k / "estimates.csv") for k in KINDS}
    assert est["python"].shape[0] == 601
    assert_same_bits(est["native"], est["python"])
    assert_same_bits(est["auto"], est["native"])
    # est.method 3: auto runs the pythonfmu RailCarEstimator, native refuses it by name
    assert main(["replay", str(log), "--out", str(tmp_path / "m2"), "--dist", str(dist), "--param", "est.method=3"]) == 0
    out = capsys.readouterr().out
    assert fmu_lines(out) == [f"fmu: python {paths['est_python']} (--fmu auto: --param sets est.method = 3, which the "
                              f"native FMU does not cover)"]
    assert main(["replay", str(log), "--out", str(tmp_path / "n2"), "--dist", str(dist), "--param", "est.method=3",
                 "--fmu", "native"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error: --param: the FMU refused to initialise: est.method = 3 is not in the native " \
                             "RailCarEstimator FMU" in err[0], err


# ------------------------------------------------------------------------------ library commands

def test_regress_report_and_filters_with_each_kind(dist, paths, tmp_path, capsys):
    tables, filters = {}, {}
    for kind, want in (("auto", "native"), ("native", "native"), ("python", "python")):
        assert main(["regress", "level_run", "--dist", str(dist), "--fmu", kind]) == 0
        out = capsys.readouterr().out
        assert fmu_lines(out)[0].startswith(f"fmu: {want} {paths[want]} for level_run (--fmu {kind}: "), out
        assert "ok   level_run" in out                                  # the same references, either kind
        assert main(["report", "level_run", "--dist", str(dist), "--fmu", kind, "--out", str(tmp_path / kind)]) == 0
        out = capsys.readouterr().out
        assert fmu_lines(out)[0].startswith(f"fmu: {want} {paths[want]} for level_run"), out
        md = (tmp_path / kind / "library.md").read_text(encoding="utf-8").splitlines()
        assert f"FMU (python -m harness report --fmu): {want}: level_run." in md
        tables[kind] = [line for line in md if not line.startswith("FMU")]
        assert main(["filters", "level_run", "--dist", str(dist), "--fmu", kind]) == 0
        out = capsys.readouterr().out
        assert fmu_lines(out)[0].startswith(f"fmu: {want} {paths[want]} (--fmu {kind}: "), out
        filters[kind] = [line for line in out.splitlines() if line.startswith("level_run")]
    assert len(filters["python"]) == 4 and len([r for r in tables["python"] if r.startswith("| level_run")]) == 1
    assert tables["native"] == tables["python"] == tables["auto"]
    assert filters["native"] == filters["python"] == filters["auto"]


def test_auto_decides_per_library_scenario(dist, paths, capsys):
    """regress and report choose per scenario: a scenario with est.method 1 runs on pythonfmu, the
    others on the native FMU, and the lines say which ran which."""
    from harness.__main__ import _choose_each
    from harness.run.scenario import load_scenario
    level = load_scenario(LIBRARY / "level_run.toml")
    steep = load_scenario(LIBRARY / "steep_grades.toml")
    m1 = dataclasses.replace(steep, name="steep_m1", parameters={**steep.parameters, "est.method": 1})
    choices = _choose_each([level, m1, steep], "auto", dist, False)
    assert {n: c.kind for n, c in choices.items()} == {"level_run": "native", "steep_m1": "python",
                                                       "steep_grades": "native"}
    lines = fmu_lines(capsys.readouterr().out)
    assert lines[0].startswith(f"fmu: native {paths['native']} for level_run, steep_grades (--fmu auto: ")
    assert lines[1] == (f"fmu: python {paths['python']} for steep_m1 (--fmu auto: {steep.path} sets "
                        f"est.method = 1, which the native FMU does not cover)")


# ------------------------------------------------------------------------------ sweeps

@pytest.fixture(scope="module")
def scheduler():
    """One local dask worker process (one thread) shared by the sweeps below (a cluster start-up is
    ~5 s); the sweep runs on it through --scheduler exactly as on an embedded cluster."""
    import logging
    from distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                      host="127.0.0.1", silence_logs=logging.ERROR) as cluster:
        yield cluster.scheduler_address


def sweep_file(folder: Path, body: str, name: str) -> Path:
    p = folder / name
    p.write_text(f'scenario = "{(LIBRARY / "level_run.toml").as_posix()}"\n[fixed]\nduration_s = 30.0\n{body}',
                 encoding="utf-8")
    return p


def test_sweep_with_each_kind(dist, paths, scheduler, tmp_path, capsys):
    from harness.sweep.main import read_results
    sw = sweep_file(tmp_path, "[grid]\n\"car.mass\" = [30.0, -1.0, 38.0]\n", "sw.toml")   # -1 t: never runs
    tables = {}
    for kind, want in (("auto", "native"), ("native", "native"), ("python", "python")):
        out = tmp_path / kind
        code = main(["sweep", str(sw), "--out", str(out), "--dist", str(dist), "--fmu", kind, "--scheduler", scheduler,
                     "--no-plots"])
        stdout = capsys.readouterr().out
        assert code == 1, stdout                                       # the car.mass = -1 row failed
        line = f"fmu: {want} {paths[want]} (--fmu {kind}: "
        assert fmu_lines(stdout)[0].startswith(line), stdout
        assert f"  {line}" in (out / "summary.md").read_text(encoding="utf-8")
        t = tables[kind] = read_results(out)
        assert [(r["run_id"], r["status"], r["fmu"]) for r in t.rows] == [(0, "ok", want), (1, "failed", ""),
                                                                        (2, "ok", want)]
        assert (out / "results.csv").read_text(encoding="utf-8").splitlines()[0].endswith(",fmu")
    keep = ("wall_time", "fmu")
    assert tables["python"].comparable(keep) == tables["native"].comparable(keep) == tables["auto"].comparable(keep)
    assert tables["native"].comparable(("wall_time",)) != tables["python"].comparable(("wall_time",))


def test_sweep_auto_takes_python_when_one_run_needs_it_and_native_fails_those_runs(dist, paths, scheduler, tmp_path,
                                                                                    capsys):
    from harness.sweep.main import read_results
    sw = sweep_file(tmp_path, "[grid]\n\"est.method\" = [0, 3]\n", "m.toml")
    assert main(["sweep", str(sw), "--out", str(tmp_path / "auto"), "--dist", str(dist), "--scheduler", scheduler,
                 "--no-plots"]) == 0
    assert fmu_lines(capsys.readouterr().out) == [f"fmu: python {paths['python']} (--fmu auto: run 1 sets "
                                                  f"est.method = 3, which the native FMU does not cover)"]
    auto = read_results(tmp_path / "auto")
    assert [(r["status"], r["fmu"]) for r in auto.rows] == [("ok", "python")] * 2
    assert main(["sweep", str(sw), "--out", str(tmp_path / "native"), "--dist", str(dist), "--scheduler", scheduler,
                 "--no-plots", "--fmu", "native"]) == 1
    capsys.readouterr()
    rows = read_results(tmp_path / "native").rows
    assert [(r["status"], r["fmu"]) for r in rows] == [("ok", "native"), ("failed", "native")]
    assert "est.method = 3 is not in the native RailCar FMU" in rows[1]["error"]
    keep = ("wall_time", "fmu")
    assert read_results(tmp_path / "native").comparable(keep)[0] == auto.comparable(keep)[0]   # est.method 0
    # --resume on the other kind is refused, naming both
    assert main(["sweep", str(sw), "--out", str(tmp_path / "native"), "--dist", str(dist), "--scheduler", scheduler,
                 "--resume"]) == 2
    err = capsys.readouterr().err
    assert "the results there ran on the native FMU, this call would run the python one; give --fmu native" in err


def test_a_worker_loads_a_native_fmu_rebuilt_at_the_same_path(built_fmus, dist, tmp_path):
    """No Python modules are cached for a native FMU: a rebuild at the same path (another GUID) is
    extracted and run; for the pythonfmu FMU the worker refuses, as before."""
    from harness.run.scenario import load_scenario
    from harness.sweep.main import _WORKER_FMUS, RunSpec, execute_run, worker_runner
    sc = dataclasses.replace(load_scenario(short_scenario(tmp_path)), duration_s=5.0)
    path = tmp_path / "w" / "RailCarNative.fmu"
    path.parent.mkdir()
    shutil.copy(native_path("RailCar", dist), path)
    first = fmu_guid(path)
    try:
        row = execute_run(str(path), first, RunSpec(0, (), sc))
        assert row["status"] == "ok" and row["fmu"] == "native", row
        old = _WORKER_FMUS[str(path)]
        other = "{00000000-0000-5000-8000-000000000001}"
        rewrite_guid(path, other)                          # "rebuilt": the same binary, another GUID
        row2 = execute_run(str(path), other, RunSpec(0, (), sc))
        assert row2["status"] == "ok" and row2["fmu"] == "native", row2
        assert _WORKER_FMUS[str(path)] is not old and _WORKER_FMUS[str(path)].md.guid == other
        assert {k: repr(v) for k, v in row2.items() if k != "wall_time"} == \
            {k: repr(v) for k, v in row.items() if k != "wall_time"}        # repr: exact, and nan == nan
        py = str(built_fmus["RailCar"])
        mine = py not in _WORKER_FMUS
        worker_runner(py, fmu_guid(Path(py)))
        with pytest.raises(RuntimeError, match="caches the FMU's Python modules"):
            worker_runner(py, other)
    finally:
        for key in [str(path)] + ([py] if "mine" in locals() and mine else []):
            runner = _WORKER_FMUS.pop(key, None)
            if runner is not None:
                runner.close()


def rewrite_guid(fmu: Path, guid: str) -> None:
    tmp = fmu.with_suffix(".tmp")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                old = fmu_guid(fmu)
                assert old.encode() in data
                data = data.replace(old.encode(), guid.encode())
            dst.writestr(item, data)
    tmp.replace(fmu)


# ------------------------------------------------------------------------------ building

def test_without_a_native_fmu_auto_falls_back_and_native_says_why(dist, tmp_path, monkeypatch):
    import harness.run.fmus as fmus
    copy = tmp_path / "dist"
    copy.mkdir()
    for name in ("RailCar", "RailCarEstimator"):
        shutil.copy(dist / f"{name}.fmu", copy)
    monkeypatch.setattr(fmus, "native_buildable", lambda: False)     # as without a C compiler
    monkeypatch.setattr(fmus, "run_build", lambda *a, **k: pytest.fail("no build expected"))
    fmus.ensure_built(copy)
    c = fmus.choose("auto", "RailCar", copy, [("s.toml", {})])
    assert (c.kind, c.path) == ("python", copy / "RailCar.fmu")
    assert "no native FMU" in c.why and str(copy / "native" / "RailCarNative.fmu") in c.why
    with pytest.raises(fmus.BuildError, match=r"--fmu native: .*RailCarNative.fmu is missing"):
        fmus.choose("native", "RailCar", copy, [("s.toml", {})])


def test_a_stale_native_fmu_is_rebuilt(dist, tmp_path, capsys, monkeypatch):
    """A native FMU from other sources (another GUID) is rebuilt by ensure_built, but not for
    --fmu python (which does not run it). The build itself is build.py's, which the session's
    build runs: here it puts the session's FMU back (a second full build took 70 s)."""
    import harness.run.fmus as fmus
    copy = tmp_path / "dist"
    shutil.copytree(dist, copy)
    assert not any(fmus.native_is_stale(n, copy) for n in NATIVE_NAMES)
    stale = native_path("RailCar", copy)
    tampered = "{00000000-0000-5000-8000-000000000002}"
    rewrite_guid(stale, tampered)
    assert fmus.native_is_stale("RailCar", copy) and not fmus.native_is_stale("RailCarEstimator", copy)
    before = stale.stat().st_mtime_ns
    builds = []

    def build(folder, native=True):
        builds.append(Path(folder))
        shutil.copy(native_path("RailCar", dist), stale)
        return f"built {stale}"
    monkeypatch.setattr(fmus, "run_build", build)
    with monkeypatch.context() as m:        # the pythonfmu FMUs current, whatever changed in the tree meanwhile
        m.setattr(fmus, "is_stale", lambda *a, **k: False)
        fmus.ensure_built(copy, native=False)                          # --fmu python: not needed
    assert stale.stat().st_mtime_ns == before and "building" not in capsys.readouterr().out
    assert builds == []
    fmus.ensure_built(copy)
    out = capsys.readouterr().out
    assert builds == [copy]
    assert f"building FMUs into {copy}" in out and f"built {stale}" in out
    assert fmu_guid(stale) not in (None, tampered)
    assert not any(fmus.native_is_stale(n, copy) for n in NATIVE_NAMES)     # current: no rebuild next time

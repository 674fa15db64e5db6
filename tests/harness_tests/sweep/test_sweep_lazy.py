"""A sweep's runs built when asked for (harness/sweep/spec.py SweepRuns, RunPlan; issue 31): the
same runs, ids and fingerprint as building them all at load did, a load whose memory does not grow
with the number of runs, and the chunks a sweep is cut into (harness/sweep/execute.py RunStream,
next_chunk); a packed chunk's runs built and run by its worker. No FMU and no dask here."""
from __future__ import annotations

import hashlib
import itertools
import json
import pickle
import tracemalloc
import zlib
from pathlib import Path

import pytest

from harness.run.scenario import PATH_PARAMETERS, ScenarioError, scenario_from_dict
from harness.sweep.execute import (MIN_CHUNK, RunStream, chunk_size, execute_packed_chunk, next_chunk,
                                   pack_chunk)
from harness.sweep.spec import load_sweep

ROOT = Path(__file__).resolve().parents[3]
LEVEL = ROOT / "scenarios" / "library" / "level_run.toml"
BASE = f'scenario = "{LEVEL.as_posix()}"\n'
MIXED = BASE + """seeds = [7, 9, 11]
[fixed]
duration_s = 30
[grid]
"car.mass" = [-5.0, 30.0, 38.0]
"track.grade_profile" = ["g.csv", "h.csv"]
"driver[0].until_speed_kmh" = [40.0, 60.0]
[zip]
"est.mass_initial" = [28, 29]
"car.A0" = [0.8, 0.9]
"""


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    (tmp_path / "g.csv").write_text("distance_m,grade_permille\n0,0\n")
    (tmp_path / "h.csv").write_text("distance_m,grade_permille\n0,1\n500,2\n")
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def eager_runs(sweep) -> list[tuple]:
    """What load_sweep built before runs were lazy: every point of itertools.product over the
    blocks (each grid axis, the zip, the seeds; the last fastest), its scenario from the base
    TOML with the values set, or the reason it is invalid."""
    import tomllib
    base = tomllib.loads(sweep.base_path.read_text(encoding="utf-8"))
    plan = sweep.runs.plan
    out = []
    for run_id, combo in enumerate(itertools.product(*plan.factors)):
        values = {}
        for part in combo:
            values.update(part)
        data = json.loads(json.dumps(base))                       # a deep copy
        for name, value in {**plan.fixed, **values}.items():
            if name.startswith("driver["):
                data["driver"][int(name[7])][name.split(".", 1)[1]] = value
            elif name in ("duration_s", "step_s"):
                data[name] = value
            else:
                data.setdefault("parameters", {})[name] = value
        try:
            sc, error = scenario_from_dict(data, str(sweep.base_path), sweep.base_path.parent), None
        except ScenarioError as e:
            sc, error = None, f"invalid scenario: {e}"
        out.append((run_id, tuple((n, values[n]) for n in sweep.axes), sc, error))
    return out


def test_the_runs_built_when_asked_for_are_those_built_at_load_before(tmp_path):
    sweep = load_sweep(write(tmp_path, MIXED))
    expected = eager_runs(sweep)
    assert len(sweep.runs) == len(expected) == 3 * 2 * 2 * 2 * 3
    assert [(r.run_id, r.values, r.scenario, r.error) for r in sweep.runs] == expected
    assert sum(r.scenario is None for r in sweep.runs) == 2 * 2 * 2 * 3         # car.mass -5 t: invalid
    assert [r.run_id for r in sweep.runs[5:11:2]] == [5, 7, 9] and len(sweep.runs[5:11:2]) == 3
    assert sweep.runs[-1].run_id == len(expected) - 1 and sweep.runs.build(17).values == expected[17][1]
    with pytest.raises(IndexError):
        sweep.runs.build(len(expected))
    # building a run leaves the base data as it was: the second build of a run is the first's
    assert sweep.runs[30] == sweep.runs[30] and sweep.runs[0].scenario is None


def test_the_fingerprint_is_the_one_of_all_runs_built(tmp_path):
    """--resume compares it with sweep.json's: the same digest as when every run was built at load."""
    sweep = load_sweep(write(tmp_path, MIXED))
    runs = eager_runs(sweep)
    files = {sc.parameter(n) for _, _, sc, _ in runs if sc is not None for n in PATH_PARAMETERS
             if sc.parameter(n)}
    assert files == {str((tmp_path / f).resolve()) for f in ("g.csv", "h.csv")}
    digest = {f: hashlib.sha256(Path(f).read_bytes()).hexdigest() for f in sorted(files)}
    text = json.dumps({"base": LEVEL.read_text(encoding="utf-8"), "fixed": sweep.runs.plan.fixed,
                       "files": digest, "runs": [[i, [list(v) for v in values]] for i, values, _, _ in runs]},
                      sort_keys=True, default=repr)
    assert sweep.fingerprint == hashlib.sha256(text.encode()).hexdigest()
    (tmp_path / "h.csv").write_text("distance_m,grade_permille\n0,3\n")          # a profile's contents count
    assert load_sweep(tmp_path / "s.toml").fingerprint != sweep.fingerprint


def test_representatives_are_one_run_per_point_but_the_seed(tmp_path):
    sweep = load_sweep(write(tmp_path, MIXED))
    ids = [r.run_id for r in sweep.runs.representatives()]
    assert ids == list(range(0, len(sweep.runs), 3))
    assert [r.run_id for r in sweep.runs[4:10].representatives()] == [4, 6, 9]
    no_seeds = load_sweep(write(tmp_path, BASE + '[grid]\n"car.mass" = [30.0, 31.0]\n', "n.toml"))
    assert [r.run_id for r in no_seeds.runs.representatives()] == [0, 1]


def loaded_bytes(path: Path) -> tuple[int, int]:
    """(runs, peak bytes Python allocated while loading the sweep file)."""
    tracemalloc.start()
    try:
        sweep = load_sweep(path)
        return len(sweep.runs), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_loading_takes_the_same_memory_for_ten_or_fifty_thousand_runs(tmp_path):
    small = loaded_bytes(write(tmp_path, BASE + "seeds = 10\n", "small.toml"))
    large = loaded_bytes(write(tmp_path, BASE + "seeds = 50000\n", "large.toml"))
    assert (small[0], large[0]) == (10, 50_000)
    # a run built at load took ~1.7 kB (85 MB here); the fingerprint's parts and the plan: < 2 MB more
    assert large[1] - small[1] < 2_000_000, (small, large)


def test_a_stream_hands_out_run_ids_and_a_packed_chunk_builds_its_runs_on_the_worker(tmp_path):
    sweep = load_sweep(write(tmp_path, MIXED))
    stream = RunStream(range(28, 40))
    assert list(stream.take(3)) == [28, 29, 30] and stream.left() == 9
    assert list(stream.take(20)) == list(range(31, 40)) and list(stream.take(1)) == [] and stream.left() == 0
    plan = sweep.runs.plan
    ids = [0, 30, 31, 71]                                       # run 0: car.mass -5 t, invalid
    packed = pack_chunk(plan.recipe(), [(i, plan.point(i)) for i in ids])
    assert len(packed) < 3000                                     # the recipe and four points, compressed
    recipe, points = pickle.loads(zlib.decompress(packed))
    assert recipe.factors == () and [recipe.make(i, p) for i, p in points] == [sweep.runs.build(i) for i in ids]
    rows = execute_packed_chunk(packed)
    assert [r["run_id"] for r in rows] == ids and [r["status"] for r in rows] == ["failed", "ok", "ok", "ok"]
    assert "invalid scenario" in rows[0]["error"] and [r["seed"] for r in rows[1:]] == [7, 9, 11]


def test_chunks_shrink_towards_the_end_of_a_sweep():
    first = chunk_size(1000, 2)
    sizes, left = [], 1000
    while left:
        sizes.append(min(left, next_chunk(first, left, 2)))
        left -= sizes[-1]
    assert sizes[0] == first == 100 and sum(sizes) == 1000
    assert sizes == sorted(sizes, reverse=True) and sizes[-2] == MIN_CHUNK and sizes[-1] <= MIN_CHUNK
    assert next_chunk(1, 5, 2) == 1 and next_chunk(5, 3, 2) == 5                 # never above chunk_size


HEAP_PROBE = """
import resource, numpy as np
from harness.sweep.execute import heap_kept

def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(50):                         # a batch run's output arrays, allocated and freed
        a = np.empty((9001, 34)); a.fill(1.0); del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

faults()
outside = faults()
with heap_kept():
    faults()
    inside = faults()
print(outside, inside, faults())
"""


def test_a_chunk_keeps_freed_memory_in_the_heap_under_dasks_trim_threshold(tmp_path):
    """dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536: every 2.4 MB array was mapped
    again page by page; inside heap_kept it is not; after it, the worker's setting is back."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, MALLOC_TRIM_THRESHOLD_="65536", PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", HEAP_PROBE], env=env, cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    outside, inside, after = (int(x) for x in out.stdout.split())
    assert outside >= 50 * 500                 # ~600 pages a time: mapped afresh every time
    assert inside < outside / 20
    assert after >= 50 * 500                   # dask's setting is back after the chunk

"""The batch engine of ``harness sweep`` (--engine batch, harness/sweep/execute.py execute_chunk):
a sweep of each kind (grid, Latin hypercube, Monte Carlo seeds: the library's sweep files cut
down to a few short runs) gives the FMU path's rows bit for bit but for the engine, fmu and wall
time columns; a run that fails inside a chunk keeps the chunk's other rows; a resumed sweep adds
exactly the missing rows; the CLI's engine choice.

One embedded cluster of two single-threaded worker processes serves the whole module.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any FMU is loaded in this process)

import dataclasses
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from harness.run.batch import not_covered
from harness.sweep.execute import chunk_size, execute_chunk, execute_run
from harness.sweep.main import choose_engine, run_sweep
from harness.sweep.results import read_results
from harness.sweep.spec import SweepError, load_sweep
from harness.sweep.table import cell_text, sweep_columns

ROOT = Path(__file__).resolve().parents[3]
SWEEPS = ROOT / "scenarios" / "sweeps"
NOT_COMPARED = ("wall_time", "engine", "fmu")


def cut_down(tmp_path: Path, name: str, changes: list[tuple[str, str]], fixed: str) -> Path:
    """The library sweep ``name`` with each (pattern, replacement) applied once (each must match),
    its base scenario's path made absolute and a [fixed] block appended."""
    text = (SWEEPS / f"{name}.toml").read_text(encoding="utf-8")
    text = text.replace('scenario = "../library/', f'scenario = "{(ROOT / "scenarios" / "library").as_posix()}/')
    for pattern, replacement in changes:
        text, n = re.subn(pattern, replacement, text, count=1, flags=re.M)
        assert n == 1, f"{name}.toml: no match for {pattern!r}"
    path = tmp_path / f"{name}.toml"
    path.write_text(text + f"\n[fixed]\n{fixed}\n", encoding="utf-8")
    return path


KINDS = {    # sweep file -> (its cut: 4 or 5 runs, 60-150 s simulated)
    "grid_mass_noise": ([(r"^seeds = 3", "seeds = 1"), (r"\[26\.0, 30\.0, 34\.0, 38\.0, 42\.0\]", "[26.0, 42.0]"),
                         (r"num = 4", "num = 2")], "duration_s = 60.0"),
    "lhs_mass_A0_noise": ([(r"^samples = 200", "samples = 4")], "duration_s = 60.0"),
    "mc_station_day": ([(r"^seeds = 100", "seeds = 5")], "duration_s = 150.0"),
}


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster
    import logging
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                           host="127.0.0.1", silence_logs=logging.ERROR)
    c = Client(cluster)
    try:
        yield c
    finally:
        c.close()
        cluster.close()


@pytest.fixture(scope="module")
def native_railcar(native_fmus) -> Path:
    return native_fmus["RailCarNative"]


def comparable(table):
    return table.comparable(exclude=NOT_COMPARED)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_each_kind_of_sweep_gives_the_fmu_rows_bit_for_bit(kind, client, native_railcar, tmp_path):
    sweep = load_sweep(cut_down(tmp_path, kind, *KINDS[kind]))
    assert 4 <= len(sweep.runs) <= 5 and all(not_covered(s.scenario) is None for s in sweep.runs)
    fmu = run_sweep(sweep, tmp_path / "fmu", native_railcar, client=client, plots=False, progress=False,
                    log=lambda *_: None)
    batch = run_sweep(sweep, tmp_path / "batch", client=client, plots=False, progress=False, chunk=2,
                      log=lambda *_: None)
    assert [r["status"] for r in batch.table.rows] == ["ok"] * len(sweep.runs)
    assert comparable(batch.table) == comparable(fmu.table)
    assert {(r["engine"], r["fmu"]) for r in batch.table.rows} == {("c", "")}
    assert {(r["engine"], r["fmu"]) for r in fmu.table.rows} == {("fmu", "native")}
    assert all(r["wall_time"] > 0.0 for r in batch.table.rows)
    assert batch.engine.startswith("batch") and batch.fmu == "" and fmu.engine == ""


def test_a_failing_run_in_a_chunk_keeps_the_others_rows(native_railcar, tmp_path):
    sweep = load_sweep(cut_down(tmp_path, "grid_mass_noise", *KINDS["grid_mass_noise"]))
    specs = list(sweep.runs)
    # past the sweep file's checks: the chain refuses it inside run_batch, which raises for the call
    bad = dataclasses.replace(specs[1].scenario, parameters={**specs[1].scenario.parameters, "car.mass": -5.0})
    specs[1] = dataclasses.replace(specs[1], scenario=bad)
    refused = dataclasses.replace(specs[2], scenario=None, error="refused by the sweep file")
    specs[2] = refused
    rows = execute_chunk(specs, call_runs=len(specs))
    assert [r["run_id"] for r in rows] == [s.run_id for s in specs]
    assert [r["status"] for r in rows] == ["ok", "failed", "failed", "ok"]
    assert "car.mass must be > 0" in rows[1]["error"] and rows[1]["engine"] == ""
    assert rows[0]["engine"] == rows[3]["engine"] == "c"
    assert rows[2]["error"] == "refused by the sweep file" and "engine" not in rows[2]
    keys = [c.key for c in sweep_columns(sweep) if c.key not in NOT_COMPARED]
    for row, spec in zip(rows, specs):
        reference = execute_run(str(native_railcar), None, spec)
        assert reference["status"] == row["status"]
        if row["status"] == "ok":
            assert [cell_text(row.get(k)) for k in keys] == [cell_text(reference.get(k)) for k in keys]


def test_resume_adds_exactly_the_missing_rows(client, native_railcar, tmp_path):
    sweep = load_sweep(cut_down(tmp_path, "lhs_mass_A0_noise", *KINDS["lhs_mass_A0_noise"]))
    out = tmp_path / "out"
    whole = run_sweep(sweep, tmp_path / "whole", client=client, plots=False, progress=False, log=lambda *_: None)
    first = run_sweep(sweep, out, client=client, plots=False, progress=False, limit=2, chunk=1,
                      log=lambda *_: None)
    assert (first.ran, len(first.missing)) == (2, 2)
    with open(out / "results.csv", "a", encoding="utf-8") as f:      # a row cut short by a kill
        f.write(f"{first.missing[0]},ok,,0.25")
    second = run_sweep(sweep, out, client=client, plots=False, progress=False, resume=True, log=lambda *_: None)
    assert (second.ran, second.resumed, second.missing) == (2, 2, [])
    ids = [int(line.split(",")[0]) for line in (out / "results.csv").read_text().splitlines()[1:]]
    assert sorted(ids) == [s.run_id for s in sweep.runs]
    assert comparable(read_results(out)) == comparable(whole.table)
    with pytest.raises(SweepError, match="ran on the batch engine, this call would run the fmu one"):
        run_sweep(sweep, out, native_railcar, client=client, resume=True, engine="fmu")


def test_resume_refuses_rows_of_another_build_of_the_c_core(client, tmp_path):
    """sweep.json records the batch engine's core (core_identity: a hash of the compiled extensions);
    a --resume on another build is refused, naming both, as the FMU path's GUID check does."""
    import json
    from harness.sweep.execute import core_identity
    sweep = load_sweep(cut_down(tmp_path, "lhs_mass_A0_noise", *KINDS["lhs_mass_A0_noise"]))
    out = tmp_path / "out"
    run_sweep(sweep, out, client=client, plots=False, progress=False, limit=1, log=lambda *_: None)
    meta = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    mine = core_identity()
    assert meta["core"] == mine and re.fullmatch(r"c [0-9a-f]{16}", mine)
    meta["core"] = "c 0123456789abcdef"                              # as if the core was rebuilt since
    (out / "sweep.json").write_text(json.dumps(meta), encoding="utf-8")
    with pytest.raises(SweepError, match=re.escape(f"(core 'c 0123456789abcdef', now '{mine}')")):
        run_sweep(sweep, out, client=client, plots=False, progress=False, resume=True, log=lambda *_: None)
    assert len((out / "results.csv").read_text().splitlines()) == 2          # the row kept, none added


def test_the_core_identity_is_the_python_reference_without_the_c_core(monkeypatch):
    from harness.sweep.execute import core_identity
    monkeypatch.setenv("RAILCAR_PURE_PYTHON", "1")
    assert core_identity() == "python reference"


def test_the_engine_choice_and_the_chunk_size(tmp_path):
    sweep = load_sweep(cut_down(tmp_path, "grid_mass_noise", *KINDS["grid_mass_noise"]))
    assert choose_engine("auto", None, sweep)[0] == "batch"
    assert choose_engine("auto", "native", sweep) == ("fmu", "--engine auto: --fmu native asks for an FMU")
    assert choose_engine("auto", "auto", sweep)[0] == "fmu"                   # an explicit --fmu auto too
    assert choose_engine("fmu", None, sweep)[0] == "fmu"
    method1 = cut_down(tmp_path, "grid_mass_noise", KINDS["grid_mass_noise"][0], 'duration_s = 60.0\n"est.method" = 1')
    engine, why = choose_engine("auto", None, load_sweep(method1))
    assert engine == "fmu" and "does not cover run 0" in why
    assert choose_engine("batch", None, load_sweep(method1))[0] == "batch"
    swept = cut_down(tmp_path, "grid_mass_noise", KINDS["grid_mass_noise"][0]
                     + [(r"^\"car.mass\" = \[26\.0, 42\.0\]", '"est.method" = [2, 1]')], "duration_s = 60.0")
    engine, why = choose_engine("auto", None, load_sweep(swept))          # the method swept: run 2 has 1
    assert engine == "fmu" and "does not cover run 2" in why
    assert [chunk_size(n, 2) for n in (1, 8, 9, 200, 1000, 100_000)] == [1, 1, 2, 25, 100, 100]
    from harness.sweep.main import _usage_error
    base = dict(scheduler=None, workers=None, limit=None, resume=False, overwrite=False)
    assert _usage_error(SimpleNamespace(**base, chunk=0, engine="batch")) == "--chunk must be >= 1"
    assert "not with --engine fmu" in _usage_error(SimpleNamespace(**base, chunk=5, engine="fmu"))
    assert "give one of the two" in _usage_error(SimpleNamespace(**base, chunk=None, engine="batch", fmu="native"))
    assert _usage_error(SimpleNamespace(**base, chunk=None, engine="batch", fmu=None)) is None


def test_the_results_writer_keeps_no_rows_in_memory(tmp_path):
    """Memory flat in the number of runs: 4,000 more rows of every column cost the writer no more
    than their run ids (a writer that kept the rows would hold ~40 MB more), and the Parquet file,
    written at the end from the CSV in row groups, holds every row."""
    import tracemalloc
    from harness.sweep.results import ResultsWriter
    sweep = load_sweep(cut_down(tmp_path, "lhs_mass_A0_noise", *KINDS["lhs_mass_A0_noise"]))
    cols = sweep_columns(sweep)
    template = {c.key: {"int": 7, "float": 0.1 + 1e-9, "str": "ok"}[c.kind] for c in cols}
    writer = ResultsWriter(tmp_path / "out", sweep, None, resume=False, engine="batch")
    try:
        tracemalloc.start()
        for i in range(1000):
            writer.write({**template, "run_id": i})
        at_1000 = tracemalloc.get_traced_memory()[0]
        for i in range(1000, 5000):
            writer.write({**template, "run_id": i})
        grown = tracemalloc.get_traced_memory()[0] - at_1000
        tracemalloc.stop()
        assert not writer.write({**template, "run_id": 17})          # a run id already written
    finally:
        writer.close()
    assert grown < 1_000_000, f"the writer grew {grown} bytes for 4,000 rows"
    import pyarrow.parquet as pq
    table = pq.read_table(tmp_path / "out" / "results.parquet")
    assert table.num_rows == 5000 and table.column("run_id").to_pylist() == list(range(5000))
    assert pq.ParquetFile(tmp_path / "out" / "results.parquet").num_row_groups == 1


def test_a_span_run_on_the_batch_engine_gives_the_fmu_rows(native_railcar, tmp_path):
    """The C batch engine drives the ATO too (models/core/span_driver.c): --engine auto picks it
    for a span scenario (engine "c"), and its row, the ATO's cells included, is the FMU's."""
    path = tmp_path / "span.toml"
    path.write_text(f'name = "span"\nscenario = "{(ROOT / "scenarios/library/ato_nominal.toml").as_posix()}"\n'
                    f'seeds = [4]\n', encoding="utf-8")
    sweep = load_sweep(path)
    assert choose_engine("auto", None, sweep)[0] == "batch"
    (row,) = execute_chunk(list(sweep.runs))
    reference = execute_run(str(native_railcar), None, sweep.runs[0])
    assert (row["status"], row["engine"], row["ato_spans"]) == ("ok", "c", 1)
    keys = [c.key for c in sweep_columns(sweep) if c.key not in NOT_COMPARED]
    assert [cell_text(row.get(k)) for k in keys] == [cell_text(reference.get(k)) for k in keys]


def test_a_span_run_the_batch_engine_hands_to_python_is_labelled_python(tmp_path, monkeypatch):
    """A span run whose ATO logs more lines than the C side keeps is run again on the Python loop
    (harness.run.batch.run_batch); its row says "python", from run_batch itself (ato_headwind
    with seed 2 logs one line; with room for none the C run is not kept)."""
    from models import batch as core_batch
    path = tmp_path / "span.toml"
    path.write_text(f'name = "span"\nscenario = "{(ROOT / "scenarios/library/ato_headwind.toml").as_posix()}"\n'
                    f'seeds = [2]\n', encoding="utf-8")
    sweep = load_sweep(path)
    (kept,) = execute_chunk(list(sweep.runs))
    monkeypatch.setattr(core_batch, "LOG_CAP", 0)
    (moved,) = execute_chunk(list(sweep.runs))
    assert (kept["status"], kept["engine"]) == ("ok", "c")
    assert (moved["status"], moved["engine"]) == ("ok", "python")
    keys = [c.key for c in sweep_columns(sweep) if c.key not in NOT_COMPARED]
    assert [cell_text(moved.get(k)) for k in keys] == [cell_text(kept.get(k)) for k in keys]


def test_the_engine_is_decided_from_one_run_when_no_axis_changes_coverage(tmp_path, monkeypatch):
    """A sweep whose axes do not include a parameter coverage depends on (models.compiled.
    COVERAGE_PARAMETERS) builds one run to choose the engine, not one per point (~0.1-1 ms each:
    seconds for a 100,000-point Latin hypercube)."""
    from harness.run import batch as harness_batch
    asked = []
    real = harness_batch.not_covered
    monkeypatch.setattr(harness_batch, "not_covered", lambda sc, setup=None: asked.append(sc) or real(sc, setup))
    sweep = load_sweep(cut_down(tmp_path, "lhs_mass_A0_noise", [(r"^samples = 200", "samples = 50")],
                                "duration_s = 60.0"))
    assert len(sweep.runs) == 50
    assert choose_engine("auto", None, sweep) == ("batch", "--engine auto: the C core covers every run")
    assert len(asked) == 1



def test_the_embedded_cluster_takes_a_free_port_for_its_http_server():
    """With dask's default port 8787 held (a user's own dashboard, a second sweep), the embedded
    cluster starts without "Port 8787 is already in use" and serves on another port."""
    import socket
    import warnings
    from harness.sweep.execute import dask_client
    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))
    except OSError:
        held.close()
        held = None                                     # something else holds it: as good
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with dask_client(workers=1) as (client, _):
                port = client.cluster.scheduler.http_server.port
        assert port != 8787
        assert not [w for w in caught if "already in use" in str(w.message)], [str(w.message) for w in caught]
    finally:
        if held is not None:
            held.close()

"""The end of a sweep streamed (harness/sweep/main.py streamed_end): the summary accumulated a row
at a time (harness.sweep.table.SweepStats) says what the summary over the whole table sorted by run
id says, whatever order the rows come in; the end's memory grows by bytes, not by rows, with the
number of runs; the plots' sample (harness.sweep.plots.PlotSample) is the same rows in any order.
"""
from __future__ import annotations

import math
import random
import tracemalloc
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from harness.sweep.main import streamed_end
from harness.sweep.plots import PlotSample
from harness.sweep.results import ResultsWriter
from harness.sweep.spec import load_sweep
from harness.sweep.table import SUMMARY_METRICS, SweepOutcome, SweepStats, format_sweep_summary, sweep_columns

ROOT = Path(__file__).resolve().parents[3]
NAN = float("nan")


def synthetic_rows(n: int, seed: int) -> list[dict]:
    """``n`` rows sorted by run id: ok rows with random metrics (some nan or missing), ATO cells
    (a nan stop error in two runs, ties in |arrival error|), and failures whose messages tie."""
    rng = random.Random(seed)
    rows = []
    for i in range(n):
        if i % 7 == 3:
            rows.append({"run_id": i, "status": "failed", "error": ["car.mass must be > 0", "dask: killed"][i % 2]})
            continue
        row = {"run_id": i, "status": "ok", "error": ""}
        for m in SUMMARY_METRICS:
            row[m] = NAN if rng.random() < 0.05 else (None if rng.random() < 0.05 else rng.gauss(0.0, 3.0))
        row.update(stops=rng.randint(0, 5), mass_stops_covered=rng.randint(0, 5), moving_samples=100,
                   speed_within_2sigma=rng.randint(80, 100), position_within_2sigma=rng.randint(80, 100),
                   ato_spans=2, ato_arrived=rng.randint(1, 2), ato_on_target=rng.randint(0, 1),
                   ato_interventions=rng.randint(0, 3), ato_energy_kwh=rng.uniform(5.0, 9.0),
                   ato_margin_mps=rng.uniform(0.1, 2.0),
                   **{"ato_arrival_error_s.list": f"{rng.choice([-3.0, 1.0, 3.0])!r};{rng.uniform(-2, 2)!r}",
                      "ato_stop_error_m.list": f"{NAN if i in (12, 40) else rng.uniform(-0.5, 0.5)!r};0.1"})
        rows.append(row)
    return rows


def reference(rows: list[dict]) -> dict:
    """The summary's numbers as the summary over the sorted table computed them (lists of every
    row, Counter.most_common, the worst of the (|x|, run) pairs)."""
    ok = [r for r in rows if r["status"] == "ok"]
    failed = [r for r in rows if r["status"] != "ok"]
    out = {}
    for m in SUMMARY_METRICS:
        xs = [float(r[m]) for r in ok if r.get(m) is not None and math.isfinite(r[m])]
        out[m] = (min(xs), float(np.median(xs)), max(xs))
    out["failures"] = [(msg, n, [r["run_id"] for r in failed if r["error"] == msg][:5])
                       for msg, n in Counter(r["error"] for r in failed).most_common(5)]

    def worst(key):
        pairs = [(float(x), r["run_id"]) for r in ok for x in r[key].split(";")]
        finite = [(abs(x), i) for x, i in pairs if not math.isnan(x)]
        if len(finite) < len(pairs):
            return NAN, next(i for x, i in pairs if math.isnan(x))
        return max(finite)
    out["worst_arrival"], out["worst_stop"] = worst("ato_arrival_error_s.list"), worst("ato_stop_error_m.list")
    out["stops"] = sum(r["stops"] for r in ok)
    out["min_margin"] = min(r["ato_margin_mps"] for r in ok)
    return out


def test_the_streamed_summary_is_the_sorted_tables_in_any_order():
    rows = synthetic_rows(300, seed=5)
    ref = reference(rows)
    shuffled = rows[:]
    random.Random(11).shuffle(shuffled)
    st = SweepStats.of(shuffled)
    for m in SUMMARY_METRICS:
        xs = st.values[m]
        assert (min(xs), float(np.median(xs)), max(xs)) == ref[m], m
    assert st.top_failures(5) == ref["failures"]
    ato = st.ato_outcome()
    assert math.isnan(ato["worst_stop"][0]) and ato["worst_stop"][1] == ref["worst_stop"][1] == 12
    assert ato["worst_arrival"] == ref["worst_arrival"]
    assert (st.coverage()["stops"], ato["min_margin"]) == (ref["stops"], ref["min_margin"])
    assert (st.rows, st.ok, st.failed) == (300, 257, 43)


def test_the_summary_text_does_not_depend_on_the_rows_order(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nscenario = "{(ROOT / "scenarios/library/ato_nominal.toml").as_posix()}"\n'
                    f'seeds = 3\n', encoding="utf-8")
    sweep = load_sweep(path)
    rows = synthetic_rows(120, seed=2)
    shuffled = rows[::-1]

    def text(rs):
        return format_sweep_summary(sweep, SweepOutcome(SweepStats.of(rs), ran=120, resumed=0, missing=[],
                                                        wall_s=2.0, workers=2))
    assert text(rows) == text(shuffled)
    assert "9 x (runs 3, 17, 31, 45, 59, ...): dask: killed" in text(rows)
    assert "never came to rest (run 12)" in text(rows)


def test_the_plots_sample_is_the_same_rows_in_any_order():
    a, b = PlotSample(50), PlotSample(50)
    ids = list(range(1000))
    for i in ids:
        a.offer({"run_id": i})
    random.Random(3).shuffle(ids)
    for i in ids:
        b.offer({"run_id": i})
    assert [r["run_id"] for r in a.rows()] == [r["run_id"] for r in b.rows()]
    sample = [r["run_id"] for r in a.rows()]
    assert len(sample) == 50 and sample == sorted(sample)
    assert min(sample) < 200 and max(sample) > 800          # spread over the sweep, not its first ids


def _end_memory(tmp_path: Path, sweep, n: int, sample_rows: int, monkeypatch) -> int:
    """Peak bytes traced while streamed_end reads a results.csv of ``n`` full rows."""
    import harness.sweep.main as main
    monkeypatch.setattr(main, "PLOT_SAMPLE_ROWS", sample_rows)
    cols = sweep_columns(sweep)
    template = {c.key: {"int": 7, "float": 0.1 + 1e-9, "str": "ok"}[c.kind] for c in cols}
    out = tmp_path / f"out{n}"
    writer = ResultsWriter(out, sweep, None, resume=False, engine="batch", core="c test")
    for i in range(n):
        writer.write({**template, "run_id": i, "speed_rmse_filter": 0.01 * (i % 97)})
    writer._f.close()                          # no Parquet: only the end's reading is measured
    writer._unlock()
    meta = main.read_meta(out / "sweep.json")       # read_text reserves its size limit: not the end's memory
    monkeypatch.setattr(main, "read_meta", lambda path: meta)
    tracemalloc.start()
    stats, done, sample = streamed_end(out, sweep)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert (stats.rows, len(done), len(sample.rows)) == (n, n, min(n, sample_rows))
    return peak


def test_the_end_of_a_sweep_reads_its_rows_in_flat_memory(tmp_path, monkeypatch):
    """4,000 more rows cost the streamed end their run ids and summary values (~300 bytes a row),
    not the rows (a full row is ~10 kB as a dict: a table held would grow ~40 MB)."""
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nscenario = "{(ROOT / "scenarios/library/level_run.toml").as_posix()}"\n'
                    f'seeds = 3\n', encoding="utf-8")
    sweep = load_sweep(path)
    small = _end_memory(tmp_path, sweep, 1000, 200, monkeypatch)
    large = _end_memory(tmp_path, sweep, 5000, 200, monkeypatch)
    assert large - small < 4000 * 600, f"the end grew {large - small} bytes for 4,000 rows"


if __name__ == "__main__":
    pytest.main([__file__, "-q"])


def test_the_parquet_pass_gathers_the_end_that_a_pass_of_its_own_gathers(tmp_path):
    """run_sweep's end comes from the pass that writes results.parquet (ResultsWriter.close(on_row)):
    the same SweepStats, run ids and plot sample as streamed_end's own pass over results.csv."""
    from harness.sweep.main import StreamedEnd
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nscenario = "{(ROOT / "scenarios/library/level_run.toml").as_posix()}"\n'
                    f'seeds = 400\n', encoding="utf-8")
    sweep = load_sweep(path)
    out = tmp_path / "out"
    writer = ResultsWriter(out, sweep, None, resume=False, engine="batch", core="c test")
    rows = synthetic_rows(400, seed=5)
    random.Random(6).shuffle(rows)                                   # completion order
    for row in rows:
        writer.write({**row, "seed": row["run_id"] + 1})
    end = StreamedEnd(out, sweep)
    assert writer.close(on_row=end.add) is True                       # pyarrow is there: the pass was made
    stats, done, sample = end.result()
    stats2, done2, sample2 = streamed_end(out, sweep)
    assert done == done2 == set(range(400)) and stats.rows == stats2.rows == 400
    outcome = SweepOutcome(stats=stats, ran=400, resumed=0, missing=[], wall_s=1.0, workers=2)
    outcome2 = SweepOutcome(stats=stats2, ran=400, resumed=0, missing=[], wall_s=1.0, workers=2)
    assert format_sweep_summary(sweep, outcome) == format_sweep_summary(sweep, outcome2)
    assert [repr(r) for r in sample.rows] == [repr(r) for r in sample2.rows] and len(sample.rows) == 400   # nan: by text

"""The C scenario drivers (models/core/scenario_driver.c, and span_driver.c: the ATO drives) under
the sanitizers, and a one-ulp change in them failing the bit-identity test of whole runs against
the Python loop (harness.run.driver.run_on_chain).

The batch extension (models/_batch.c with the core) is built here twice more, the same way: with
the driver as it is, and with one expression of it changed by one ulp (an operand times
(1 + 2**-52)) -- the brake_to_stop demand, the cruise demand, the time table's interpolation, the
wind held over a step; in span_driver.c the time the ATO is called at and the payload boarded
at a line's dwells. The unchanged build gives run_on_chain's rows exactly; each mutant makes
them differ. The core's other files are compiled once, to objects, with -Wall -Wextra -Werror
(the binding against the Python headers included, as tests/model_tests/core/test_core_build.py
does for models/_railcar.c). The batch extension is also built with -fsanitize=address,undefined
and run, in a Python with the sanitizers' runtimes preloaded, over every scripted library scenario,
a refused script and a rejected step, the span scenarios ato_nominal and ato_line, and the run
metrics in C (the oracle filter and the coasts,
models/core/run_metrics.c) of those scenarios and a span scenario, and a refused coast: not a
sanitizer report, the rows still run_on_chain's, the metrics the Python reference's.
"""
from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from harness.run import batch as harness_batch
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario, scenario_from_dict
from models import batch

from batch_build import CORE, FLAGS, ONE_ULP, ROOT, build_batch, compile_objects, gcc

DRIVER = CORE / "scenario_driver.c"
SPAN_DRIVER = CORE / "span_driver.c"
LIBRARY = ROOT / "scenarios" / "library"

CRUISE_AND_TABLE = [
    {"name": "cruise", "step_s": 0.1, "duration_s": 120.0,
     "parameters": {"car.mass": 30.0, "seed": 4},
     "driver": [{"action": "traction", "until_speed_kmh": 30.0},
                {"action": "cruise", "target_speed_kmh": 40.0, "until_time_s": 60.0},
                {"action": "brake", "until_speed_mps": 0.5}]},
    {"name": "table", "step_s": 0.1, "duration_s": 80.0, "parameters": {"seed": 6},
     "driver_table": {"time_s": [0.0, 30.0, 50.0, 70.0], "traction_N": [10000.0, 30000.0, 0.0, 0.0],
                      "brake_N": [0.0, 0.0, 0.0, 25000.0]}},
]


def scenarios() -> dict:
    out = {n: load_scenario(LIBRARY / f"{n}.toml") for n in ("level_run", "headwind_change")}
    out.update({d["name"]: scenario_from_dict(d, f"<{d['name']}>", LIBRARY) for d in CRUISE_AND_TABLE})
    return out


def span_scenarios() -> dict:
    return {n: load_scenario(LIBRARY / f"{n}.toml") for n in ("ato_nominal", "ato_line")}


MUTATIONS = {
    "brake_to_stop": ("level_run", "double need = speed * speed / (2.0 * left);",
                      f"double need = speed * speed / (2.0 * left) * {ONE_ULP};"),
    "cruise": ("cruise", "double demand = 1000.0 * s->mass_t * CRUISE_GAIN * (p->target_speed_mps - speed);",
               f"double demand = 1000.0 * s->mass_t * CRUISE_GAIN * (p->target_speed_mps - speed) * {ONE_ULP};"),
    "time_table": ("table", "return demands(r0[1] + w * (r1[1] - r0[1]),",
                   f"return demands((r0[1] + w * (r1[1] - r0[1])) * {ONE_ULP},"),
    "wind": ("headwind_change", "return rc_wind_schedule_at(s->wind, s->n_wind, t);",
             f"return rc_wind_schedule_at(s->wind, s->n_wind, t) * {ONE_ULP};"),
}
"""name: (the scenario it shows on, the expression in scenario_driver.c, its one-ulp change)"""

SPAN_MUTATIONS = {
    "span_time": ("ato_nominal", "double t = (double)k * h;", f"double t = (double)k * h * {ONE_ULP};"),
    "span_payload": ("ato_line", "payload += st.payload_change;",
                     f"payload += st.payload_change * {ONE_ULP};"),
}
"""name: (the span scenario it shows on, the expression in span_driver.c, its one-ulp change)"""


@pytest.fixture(scope="module")
def objects(tmp_path_factory) -> list[Path]:
    """The binding and every core source but the drivers, compiled once."""
    return compile_objects(tmp_path_factory.mktemp("batch_objects"), (DRIVER, SPAN_DRIVER))


def build(objects: list[Path], driver_source: str, directory: Path, span_source: str | None = None):
    """models._batch with ``driver_source`` as scenario_driver.c and ``span_source`` as
    span_driver.c (default: the file's), imported from ``directory``."""
    return build_batch(objects, {"scenario_driver.c": driver_source,
                                 "span_driver.c": SPAN_DRIVER.read_text() if span_source is None else span_source},
                       directory)


def differing_outputs(scenario, module, monkeypatch) -> list[str]:
    """The outputs and inputs whose bits differ between run_on_chain and the batch run on
    ``module`` ("driver_steps" too if a span scenario's AtoSteps differ)."""
    expected = run_on_chain(scenario)
    monkeypatch.setattr(batch, "_batch", module)
    [got] = harness_batch.run_batch([scenario])
    monkeypatch.undo()
    if len(got.time) != len(expected.time):
        return [f"rows: {len(got.time)} != {len(expected.time)}"]
    pairs = [*((n, expected.signals[n], got.signals[n]) for n in expected.signals),
             *((f"input {n}", expected.inputs[n], got.inputs[n]) for n in expected.inputs)]
    steps = [] if got.driver_steps == expected.driver_steps else ["driver_steps"]   # the ATO's calls
    return [n for n, a, b in pairs if a.tobytes() != b.tobytes()] + steps


def test_the_unchanged_driver_built_here_gives_the_python_rows(objects, tmp_path, monkeypatch):
    module = build(objects, DRIVER.read_text(), tmp_path / "unchanged")
    for name, scenario in scenarios().items():
        assert differing_outputs(scenario, module, monkeypatch) == [], name


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_one_ulp_change_in_the_driver_is_caught(mutation, objects, tmp_path, monkeypatch):
    scenario_name, expression, changed = MUTATIONS[mutation]
    text = DRIVER.read_text()
    assert text.count(expression) == 1, f"{expression!r} is not once in {DRIVER.name}"
    module = build(objects, text.replace(expression, changed), tmp_path / mutation)
    scenario = scenarios()[scenario_name]
    differ = differing_outputs(scenario, module, monkeypatch)
    assert differ, f"{mutation}: the one-ulp change left every row of {scenario_name} the same"
    assert "car.speed" in differ or any(d.startswith("input") for d in differ), differ


@pytest.mark.parametrize("mutation", SPAN_MUTATIONS)
def test_a_one_ulp_change_in_the_span_driver_is_caught(mutation, objects, tmp_path, monkeypatch):
    scenario_name, expression, changed = SPAN_MUTATIONS[mutation]
    text = SPAN_DRIVER.read_text()
    assert text.count(expression) == 1, f"{expression!r} is not once in {SPAN_DRIVER.name}"
    module = build(objects, DRIVER.read_text(), tmp_path / mutation, text.replace(expression, changed))
    scenario = span_scenarios()[scenario_name]
    differ = differing_outputs(scenario, module, monkeypatch)
    assert differ, f"{mutation}: the one-ulp change left every row of {scenario_name} the same"
    # the calls' t (the ATO compares it with thresholds only: the rows may stay), the payload held
    assert ("driver_steps" if mutation == "span_time" else "input car.payload") in differ, differ


SANITIZED_RUNS = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("_batch", sys.argv[1])
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)
from dataclasses import replace
from pathlib import Path
from models import batch
from models.chain import StepRejected
from harness.run.batch import run_batch, run_chains, script_of
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario
batch._batch = module
library = [load_scenario(p) for p in sorted(Path(sys.argv[2]).glob("*.toml"))]
scripted = [sc for sc in library if sc.ato is None]
differ = [sc.name for sc, got in zip(scripted, run_batch(scripted))
          if any(got[n].tobytes() != run_on_chain(sc)[n].tobytes() for n in got.signals)]
sc = next(s for s in scripted if s.name == "level_run")     # its first phase: traction
setup = sc.chain_setup()
try:
    run_chains([(setup.config, setup.grade, setup.speed, script_of(sc)[:-1])])
except ValueError as e:
    print("refused:", e)
strong = replace(sc, phases=(replace(sc.phases[0], force_N=1e9),) + sc.phases[1:])
try:
    run_batch([strong])
except StepRejected as e:
    print("rejected:", e)
spans = [sc for sc in library if sc.name in ("ato_nominal", "ato_line")]
spans_differ = [sc.name for sc, got, want in zip(spans, run_batch(spans), map(run_on_chain, spans))
                if got.driver_steps != want.driver_steps
                or any(got[n].tobytes() != want[n].tobytes() for n in got.signals)]
print("spans", len(spans), "differ", spans_differ)
import os
from harness.metrics.run import run_metrics
metrics_differ = []
for sc in scripted + [s for s in library if s.name == "ato_nominal"]:
    result = run_on_chain(sc)
    ours = run_metrics(result)                  # the oracle and the coasts in this build's C
    os.environ["RAILCAR_PURE_PYTHON"] = "1"
    reference = run_metrics(result)
    del os.environ["RAILCAR_PURE_PYTHON"]
    if repr(ours.summary) != repr(reference.summary):
        metrics_differ.append(sc.name)
try:
    batch.coast_times([1.0] * 11, ((0.0,), (0.0,)), [], [[1.0] * 7])
except ValueError as e:
    print("coasts refused:", e)
print("metrics differ", metrics_differ)
print("scenarios", len(scripted), "differ", differ)
"""


def test_the_batch_extension_under_the_sanitizers(tmp_path):
    """ASan and UBSan in the extension, their runtimes preloaded into a fresh Python."""
    so = tmp_path / f"_batch{sysconfig.get_config_var('EXT_SUFFIX')}"
    sources = [ROOT / "models" / "_batch.c", *sorted(CORE.glob("*.c"))]
    proc = subprocess.run([gcc(), *FLAGS, "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                           "-shared", f"-I{sysconfig.get_paths()['include']}", f"-I{CORE}",
                           *map(str, sources), "-lm", "-o", str(so)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    runtimes = [subprocess.run([gcc(), f"-print-file-name={lib}"], capture_output=True, text=True).stdout.strip()
                for lib in ("libasan.so", "libubsan.so")]
    assert all(Path(r).is_file() for r in runtimes), runtimes
    env = dict(os.environ, LD_PRELOAD=":".join(runtimes), PYTHONPATH=str(ROOT),
               ASAN_OPTIONS="detect_leaks=0:halt_on_error=1",     # the interpreter's own leaks are not ours
               UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    run = subprocess.run([sys.executable, "-c", SANITIZED_RUNS, str(so), str(LIBRARY)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Sanitizer" not in run.stderr and "runtime error" not in run.stderr, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    assert lines[-1] == "scenarios 12 differ []", run.stdout
    assert lines[-2] == "metrics differ []", run.stdout          # run metrics: models/core/run_metrics.c
    assert lines[-3].startswith("coasts refused: coasts: expected rows of 8 values"), run.stdout
    assert lines[0].startswith("refused: run 0: script: expected"), run.stdout
    assert lines[1].startswith("rejected: run 0: step 0: traction_force_demand"), run.stdout
    assert lines[2] == "spans 2 differ []", run.stdout         # span_driver.c: the ATO drives

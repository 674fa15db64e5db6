"""The ATO closed-loop study's run in C (models/core/ato_closed_loop.c, bound as
models.compiled.run_ato_closed_loop) against the study's Python loop (studies/ato_closed_loop.py
python_run: the Python AtoController on the chain, the metrics of harness/metrics/ato.py), issue 30:

- every case and variant of the study, two seeds: the native run's metrics equal the Python run's
  bit for bit (the re-plans' wall times aside: the C controller does not time them), and so the
  study's table rows, character for character;
- the map from the chain's outputs to the controller's inputs the C loop uses is
  models.compiled.OUTPUT_NAMES' own;
- a one-ulp-sized mutation of the C loop's metric arithmetic (built through the ctypes shim
  tests/core_cases/ato_closed_loop_shim.c) makes its run differ, while the unmutated build gives
  the Python run exactly;
- bad settings are refused naming the setting, in the Python objects' words.
"""
from __future__ import annotations

import ctypes
import dataclasses
import math
import shutil
import struct
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from fmu_src.adapter import chain_config
from models import compiled
from models.ato.controller import AtoController
from models.ato.interface import ALL_INPUTS, AtoTuning
from models.chain import ChainConfig
from models.plant.dynamics import VehicleParams

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "studies"))
import ato_closed_loop as study  # noqa: E402

CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_closed_loop_shim.c"
LOOP_SOURCE = CORE / "ato_closed_loop.c"
FLAGS = ["-std=c99", "-O1", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fPIC"]
ONE_ULP = "(1.0 + 2.220446049250313e-16)"
SEEDS = (1, 2)
TEXT = 512



def bits(row: dict) -> dict:
    """The metrics of a run, floats by their bits (so that inf, -0.0 and every ulp count)."""
    return {k: struct.pack("<d", row[k]) if isinstance(row[k], float) else row[k]
            for k in study.METRICS}


_PYTHON_RUNS: dict = {}


def python_run(case: str, variant: str, seed: int) -> dict:
    """python_run, once per session (the mutation test reuses the nominal runs)."""
    key = (case, variant, seed)
    if key not in _PYTHON_RUNS:
        _PYTHON_RUNS[key] = study.python_run(case, variant, seed)
    return _PYTHON_RUNS[key]


def test_the_c_core_is_compiled_and_the_default():
    assert compiled.enabled(), "models._railcar is not built: python setup.py build_ext --inplace"
    assert study.default_controller() == "native"
    with pytest.raises(ValueError, match="controller must be one of"):
        study.run_one("nominal", "identified + re-plan", 1, controller="fortran")


@pytest.mark.parametrize("case", list(study.CASES))
def test_native_runs_equal_the_python_runs(case):
    """Every variant, seeds 1 and 2: the metrics bit for bit, the table's rows character for
    character (the references are stand-ins: they do not depend on the controller)."""
    native, python = [], []
    for variant in study.VARIANTS:
        got = study.native_runs(case, variant, SEEDS)
        for seed, row in zip(SEEDS, got):
            want = python_run(case, variant, seed)
            assert (row["case"], row["variant"], row["seed"]) == (case, variant, seed)
            assert bits(row) == bits(want), (case, variant, seed)
            assert row["replan_ms"] == [] and len(want["replan_ms"]) == want["replans"]
        native += got
        python += [python_run(case, variant, s) for s in SEEDS]
    refs = {case: (2.5, 2.3)}
    assert study.table(native, refs) == study.table(python, refs)
    # not vacuous: the runs arrive and stop, the re-planning variants re-plan
    assert all(math.isfinite(r["arrival"]) and abs(r["stop"]) < 1.0 for r in native)
    assert any(r["replans"] > 10 for r in native)


def test_the_loop_reads_the_controllers_inputs_from_the_chains_outputs():
    from models import _railcar
    assert _railcar.ATO_INPUT_OUTPUTS == tuple(compiled.OUTPUT_NAMES.index(n) for n in ALL_INPUTS)


# ------------------------------------------------------------------ refusals


def run_args(case="nominal", seed=1, **change):
    values, truth, wind = study.run_setup(case, seed)
    args = dict(cfg=chain_config(values), span=study.SPAN, car=study.CAR,
                tuning=study.VARIANTS["identified + re-plan"], truth=truth, wind=wind,
                step=study.STEP, max_steps=study.MAX_STEPS, seeds=[seed])
    args.update(change)
    return args


def refusal(**change) -> str:
    with pytest.raises(ValueError) as info:
        compiled.run_ato_closed_loop(**run_args(**change))
    return str(info.value)


def python_refusal(make) -> str:
    with pytest.raises(ValueError) as info:
        make()
    return str(info.value)


def test_bad_settings_are_refused_by_name():
    # the tuning: AtoTuning's own message (an AtoTuning built without its checks carries the value)
    bad_tuning = object.__new__(AtoTuning)
    for f in dataclasses.fields(AtoTuning):
        object.__setattr__(bad_tuning, f.name, getattr(AtoTuning(), f.name))
    object.__setattr__(bad_tuning, "replan_period", -1.0)
    assert refusal(tuning=bad_tuning) == python_refusal(lambda: AtoTuning(replan_period=-1.0))
    assert "replan_period" in refusal(tuning=bad_tuning)
    # the span: a schedule the car cannot keep, AtoController's message
    short = study.SPAN.with_schedule(60.0)
    text = refusal(span=short)
    assert text == python_refusal(lambda: AtoController(short, study.CAR, AtoTuning()))
    assert "schedule" in text
    # the configured car: a climb it cannot make (AtoController's check_span_for_car)
    weak = replace(study.CAR, traction_force_max=1000.0)
    assert refusal(car=weak) == python_refusal(lambda: AtoController(study.SPAN, weak, AtoTuning()))
    # the chain's configuration, in RailCarChain's words (the seed here)
    assert refusal(seeds=[-1]) == python_refusal(lambda: replace(ChainConfig(), seed=-1).validate())
    # the loop's own settings
    assert refusal(step=0.0) == "step must be > 0 and finite, got 0.0"
    assert refusal(max_steps=-1) == "max_steps must be >= 0, got -1.0"
    assert refusal(wind=math.nan) == "wind must be finite, got nan"
    assert refusal(truth=VehicleParams(mass=-2.0)) == "truth car.mass must be > 0, got -2.0"


def test_the_binding_refuses_wrong_lengths_by_name():
    from models import _railcar
    a = run_args()
    g = study.SPAN.grade
    good = [[*compiled._config_values(a["cfg"], 0.0), 20], g.distances, g.grades,
            (study.SPAN.length, study.SPAN.schedule, study.SPAN.stop), study.SPAN.limit_distances,
            study.SPAN.limit_speeds, compiled.dataclass_values(study.CAR),
            compiled.dataclass_values(a["tuning"]), compiled.dataclass_values(a["truth"])]
    short_tuning = list(good)
    short_tuning[7] = good[7][:-1]
    with pytest.raises(ValueError, match=f"tuning must have {len(good[7])} values, got {len(good[7]) - 1}"):
        _railcar.ato_closed_loop(*short_tuning, 0.1, 0.0, 10, [1], RuntimeError)
    no_limits = list(good)
    no_limits[4], no_limits[5] = (), ()
    with pytest.raises(ValueError, match="limits' distances and values"):
        _railcar.ato_closed_loop(*no_limits, 0.1, 0.0, 10, [1], RuntimeError)
    rows = _railcar.ato_closed_loop(*good, 0.1, 0.0, 10, [1, 2], RuntimeError)
    assert [r[7] for r in rows] == [10, 10]          # max_steps caps the loop


# ------------------------------------------------------------------ the mutation test


@pytest.fixture(scope="module")
def core_objects(tmp_path_factory) -> list[Path]:
    """Every core file but the loop's, compiled once (the mutants are linked against them)."""
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    out = tmp_path_factory.mktemp("core_objects")
    sources = [p for p in sorted(CORE.glob("*.c")) if p != LOOP_SOURCE] + [SHIM]
    proc = subprocess.run([gcc, *FLAGS, f"-I{CORE}", "-c", *map(str, sources)], cwd=out,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return sorted(out.glob("*.o"))


def shim_library(objects: list[Path], loop_source: Path, out: Path):
    gcc = shutil.which("gcc")
    proc = subprocess.run([gcc, *FLAGS, "-shared", f"-I{CORE}", str(loop_source), *map(str, objects),
                           "-o", str(out), "-lm"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    dll = ctypes.CDLL(str(out))
    D, L = ctypes.POINTER(ctypes.c_double), ctypes.c_long
    dll.shim_run.argtypes = [D, L, D, D, L, D, D, D, ctypes.c_int, D, D, D, ctypes.c_double,
                             ctypes.c_double, L, D, ctypes.c_char_p]
    dll.shim_run.restype = ctypes.c_int
    assert dll.shim_text_size() == TEXT
    return dll


def arr(values) -> ctypes.Array:
    values = [float(v) for v in values]
    return (ctypes.c_double * max(len(values), 1))(*values)


def shim_run(dll, case: str, variant: str, seed: int) -> dict:
    """The run through the shim, as native_runs' dict."""
    values, truth, wind = study.run_setup(case, seed)
    cfg = compiled.validate(chain_config(values), None, 0.0)
    chain_values = [*compiled._config_values(cfg, 0.0), int(cfg.identifier.slope_window)]
    span, g = study.SPAN, study.SPAN.grade
    out, msg = (ctypes.c_double * 9)(), ctypes.create_string_buffer(TEXT)
    status = dll.shim_run(arr(chain_values), len(chain_values), arr(g.distances), arr(g.grades),
                          len(g.grades), arr([span.length, span.schedule, span.stop]),
                          arr(span.limit_distances), arr(span.limit_speeds), len(span.limit_speeds),
                          arr(compiled.dataclass_values(study.CAR)),
                          arr(compiled.dataclass_values(study.VARIANTS[variant])),
                          arr(compiled.dataclass_values(truth)), study.STEP, wind,
                          study.MAX_STEPS, out, msg)
    assert status == 0, msg.value.decode()
    row = dict(zip(compiled.ATO_LOOP_FIELDS, out))
    for k in ("interventions", "replans", "steps"):
        row[k] = int(row[k])
    return row


MUTATIONS = (
    # re-associated: the energy's division by J_PER_KWH taken term by term
    ("return (traction_work / car->eta_f - car->eta * regen_work) / J_PER_KWH;",
     "return traction_work / car->eta_f / J_PER_KWH - car->eta * regen_work / J_PER_KWH;"),
    # one operand times (1 + 2**-52): a step's traction work, the speed-limit margin
    ("*traction_work = rc_min(traction, traction_force_limit(truth, vm)) * ds;",
     f"*traction_work = rc_min(traction, traction_force_limit(truth, vm)) * ds * {ONE_ULP};"),
    ("margin = rc_min(margin, rc_ato_v_lim(span, s1) - v1);",
     f"margin = rc_min(margin, rc_ato_v_lim(span, s1) * {ONE_ULP} - v1);"),
)
MUTATION_RUNS = (("nominal", "identified + re-plan", 1), ("wet rail", "configured, fixed plan", 2))


def test_the_shim_gives_the_python_runs(core_objects, tmp_path):
    dll = shim_library(core_objects, LOOP_SOURCE, tmp_path / "libloop.so")
    for run in MUTATION_RUNS:
        assert bits(shim_run(dll, *run)) == bits(python_run(*run)), run


@pytest.mark.parametrize("original, mutated", MUTATIONS)
def test_a_one_ulp_mutation_of_the_loop_is_caught(core_objects, tmp_path, original, mutated):
    source = LOOP_SOURCE.read_text()
    assert source.count(original) == 1, original
    mutant = tmp_path / "ato_closed_loop.c"
    mutant.write_text(source.replace(original, mutated))
    dll = shim_library(core_objects, mutant, tmp_path / "libmutant.so")
    assert any(bits(shim_run(dll, *run)) != bits(python_run(*run)) for run in MUTATION_RUNS)

"""The C model core (models/core/) without Python, under the sanitizers, and a mutation test.

tests/core_cases/chain_driver.c hosts the core in a plain C program: a file in (the flat
configuration, the profiles, the inputs of every step), a file out (the outputs at the start and
after every step). Here

- it is built once with -fsanitize=address,undefined -fno-sanitize-recover=all and runs every
  library scenario, with est.method 0 and 2 (the LS on Sidorenko's slopes, est.slope_window after
  the flat configuration) and est.physical 0 and 1 (OPTIONS), with the closed-loop inputs the
  Python chain (models.chain.RailCarChain) saw:
  exit 0, not a byte on stderr (any sanitizer report would be there), and every output of every
  step equal bit for bit to the Python chain's;
- a one-ulp-sized change of one expression (issue 17: "a one-ulp change in one C expression must
  fail a test") in plant.c, filter.c, ident.c, linalg4.c, estimator.c and railcar.c (and in
  est.method 2's and est.physical's code in estimator.c and ident.c, on such runs) -- a
  re-associated sum or one operand times (1 + 2**-52) -- makes the outputs differ from Python's,
  while the unmutated copy built the same way gives them exactly.
"""
from __future__ import annotations

import os
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.run.driver import drive_chain
from harness.run.scenario import load_scenario
from models import compiled
from models.chain import RailCarChain

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
DRIVER = ROOT / "tests" / "core_cases" / "chain_driver.c"
LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))
MAX_STEPS = None       # whole scenarios: station_day reaches its station stops (9000 steps)
STRICT = ["-std=c99", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
ONE_ULP = "(1.0 + 2.220446049250313e-16)"


def gcc() -> str:
    path = shutil.which("gcc")
    assert path, "gcc is needed (it builds the C core on every supported machine)"
    return path


def compile_(*args: str) -> None:
    proc = subprocess.run([gcc(), *args], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"gcc {' '.join(args)}:\n{proc.stderr}"


# ---------------------------------------------------------------- the Python chain's runs

PAPER_LS = {"est.method": 0}
SLOPE_LS = {"est.method": 2}
PHYSICAL = {"est.physical": 1}
OPTIONS = {"paper_ls": PAPER_LS, "slope_ls": SLOPE_LS, "physical": {**PAPER_LS, **PHYSICAL},
           "slope_ls_physical": {**SLOPE_LS, **PHYSICAL}}
"""The estimator options the core runs, each over the whole library (est.method named in each:
the FMUs' default is 2)."""


class Run:
    """One library scenario (with parameter ``overrides``) on the Python chain: the driver's
    input file and the outputs."""

    def __init__(self, path: Path, overrides: dict | None = None):
        sc = load_scenario(path)
        sc = replace(sc, parameters={**sc.parameters, **(overrides or {})})
        setup = sc.chain_setup()
        grade, speed = setup.grade, setup.speed
        chain = RailCarChain(setup.config, grade, speed)
        demands: list = []
        rows = drive_chain(chain, sc, MAX_STEPS, demands=demands)
        assert len(rows) == len(demands) + 1 > 100
        names = list(compiled.OUTPUT_NAMES)
        assert all(list(r) == names for r in rows), "RailCarChain.outputs() order != OUTPUT_NAMES"
        self.name = path.stem
        self.expected = np.array([[float(r[n]) for n in names] for r in rows])
        h = sc.step_s
        steps = np.array([(k * h, h, *d) for k, d in enumerate(demands)], dtype=float).reshape(-1, 6)
        self.cfg = compiled.validate(setup.config, speed, 0.0)
        self.grade, self.speed, self.steps = grade, speed, steps
        self.data = self.file_data(self.cfg)

    def file_data(self, cfg) -> np.ndarray:
        """The driver's input for this configuration (tests/core_cases/chain_driver.c): the flat
        configuration and est.slope_window after it (models/core/config.c)."""
        config = [*compiled._config_values(cfg, 0.0), cfg.identifier.slope_window]
        grade, speed, steps = self.grade, self.speed, self.steps
        sd, sv = (speed.distances, speed.speeds) if speed else ((), ())
        return np.concatenate([
            [len(config), len(grade.distances), len(sd), len(steps)], config,
            grade.distances, grade.grades, sd, sv, steps.ravel()]).astype("<f8")

    def write(self, directory: Path) -> Path:
        path = directory / f"{self.name}_{self.cfg.identifier.method}{self.cfg.identifier.physical}.in"
        self.data.tofile(path)
        return path


@pytest.fixture(scope="module")
def runs() -> dict[str, Run]:
    return {p.stem: Run(p) for p in LIBRARY}


@pytest.fixture(scope="module")
def option_runs(runs) -> dict[str, dict[str, Run]]:
    """The library with each of OPTIONS."""
    return {option: runs if not overrides else {p.stem: Run(p, overrides) for p in LIBRARY}
            for option, overrides in OPTIONS.items()}


@pytest.fixture(scope="module")
def slope_runs(option_runs) -> dict[str, Run]:
    """The library with est.method 2."""
    return option_runs["slope_ls"]


def run_driver(exe: Path, run: Run, directory: Path, env: dict | None = None):
    """(exit status, stderr, outputs as rows of OUTPUT_NAMES)"""
    out = directory / f"{run.name}.out"
    proc = subprocess.run([str(exe), str(run.write(directory)), str(out)], capture_output=True,
                          text=True, timeout=120, env=env)
    rows = np.fromfile(out, dtype="<f8") if out.exists() else np.empty(0)
    return proc.returncode, proc.stderr, rows.reshape(-1, len(compiled.OUTPUT_NAMES))


def differences(a: np.ndarray, b: np.ndarray) -> list[tuple[int, str]]:
    """(row, output name) where a and b are not the same float64 bits (NaN equals NaN)."""
    if a.shape != b.shape:
        return [(-1, f"shape {a.shape} != {b.shape}")]
    same = (a.view(np.uint64) == b.view(np.uint64)) | (np.isnan(a) & np.isnan(b))
    return [(int(i), compiled.OUTPUT_NAMES[j]) for i, j in zip(*np.nonzero(~same))]


# ---------------------------------------------------------------- sanitizers

@pytest.fixture(scope="module")
def sanitized_driver(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("sanitized") / "chain_driver"
    compile_(*STRICT, *SANITIZE, "-I", str(CORE), str(DRIVER),
             *sorted(str(p) for p in CORE.glob("*.c")), "-lm", "-o", str(exe))
    return exe


@pytest.mark.parametrize("option", OPTIONS)
@pytest.mark.parametrize("name", [p.stem for p in LIBRARY])
def test_library_scenario_under_sanitizers_bit_identical(name, option, option_runs,
                                                         sanitized_driver, tmp_path):
    run = option_runs[option][name]
    ident = run.cfg.identifier
    assert (ident.method, ident.physical) == (OPTIONS[option]["est.method"],
                                              OPTIONS[option].get("est.physical", 0))
    env = dict(os.environ, ASAN_OPTIONS="detect_leaks=1:halt_on_error=1",
               UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    status, stderr, rows = run_driver(sanitized_driver, run, tmp_path, env)
    assert status == 0, stderr[-3000:]
    assert stderr == "", stderr[-3000:]
    diff = differences(rows, run.expected)
    assert not diff, f"{name}: {len(diff)} outputs differ, first {diff[:5]}"


def test_driver_reports_a_rejected_step_and_a_refused_configuration(runs, sanitized_driver, tmp_path):
    run = runs["level_run"]
    n_steps = int(run.data[3])
    first_step = len(run.data) - 6 * n_steps
    bad = run.data.copy()
    bad[first_step + 6 * 10 + 2] = np.nan           # step 10's traction demand
    path = tmp_path / "bad.in"
    bad.tofile(path)
    proc = subprocess.run([str(sanitized_driver), str(path), str(tmp_path / "bad.out")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 3
    assert proc.stderr.startswith("step 10 rejected: traction_force_demand must be finite"), proc.stderr
    written = np.fromfile(tmp_path / "bad.out", dtype="<f8").reshape(-1, len(compiled.OUTPUT_NAMES))
    assert not differences(written, run.expected[:11])   # the start and the 10 steps before it
    run.file_data(replace(run.cfg, identifier=replace(run.cfg.identifier, method=1))).tofile(path)
    proc = subprocess.run([str(sanitized_driver), str(path), str(tmp_path / "refused.out")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("configuration refused: the C core does not cover est.method 1 or 3 "
                                  "(the Python chain runs it)"), \
        proc.stderr
    # est.method 2 without est.slope_window after the flat configuration
    method2 = run.file_data(replace(run.cfg, identifier=replace(run.cfg.identifier, method=2)))
    n_config = int(method2[0])
    np.concatenate([[n_config - 1], method2[1:4 + n_config - 1], method2[4 + n_config:]]).astype(
        "<f8").tofile(path)
    proc = subprocess.run([str(sanitized_driver), str(path), str(tmp_path / "refused.out")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("configuration refused: the C core does not cover est.method 2 "
                                  "without est.slope_window"), proc.stderr
    path.write_bytes(run.data[:-1].tobytes())           # one value short
    proc = subprocess.run([str(sanitized_driver), str(path), str(tmp_path / "short.out")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and "expected exactly" in proc.stderr


# ---------------------------------------------------------------- mutations

MUTATIONS = {
    # the position of the RK4 step: (v + 2 v2 + 2 v3) + v4 -> (v + 2 v2) + (2 v3 + v4)
    "plant_rk4_position": ("plant.c",
                           "double x_new = x + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4);",
                           "double x_new = x + h / 6.0 * (v + 2.0 * v2 + (2.0 * v3 + v4));"),
    # the filter's speed after an update with both measurements, eq. (15), re-associated
    "filter_update_speed": ("filter.c",
                            "xh0 = f->xb0 + k00 * e0 + k01 * e1;",
                            "xh0 = f->xb0 + (k00 * e0 + k01 * e1);"),
    # the identification's regressand y: the speed difference one ulp larger
    "ident_regressand": ("ident.c",
                         "* (speed_next - speed) / (RC_G * dtu)",
                         f"* ((speed_next - speed) * {ONE_ULP}) / (RC_G * dtu)"),
    # Gaussian elimination's back substitution (the batch and the running estimate)
    "linalg4_back_substitution": ("linalg4.c",
                                  "x[i] = s / a[ri + i];",
                                  f"x[i] = s * {ONE_ULP} / a[ri + i];"),
    # the process noise's gain k of OnlineEstimator.process_noise
    "estimator_process_noise": ("estimator.c",
                                "double k = RC_G * dt / 1000.0 / (1.0 + e->gamma);",
                                f"double k = RC_G * dt / 1000.0 / (1.0 + e->gamma) * {ONE_ULP};"),
    # the speed sensor's noise amplitude in RailCarChain._take_sample
    "railcar_speed_sensor": ("railcar.c",
                             "c->sensor_speed = s->speed + (f->speed_std + f->speed_std_rel",
                             f"c->sensor_speed = s->speed + (f->speed_std * {ONE_ULP} + f->speed_std_rel"),
}
# est.method 2's own code, checked on est.method 2 runs of MUTATION_SCENARIOS
SLOPE_MUTATIONS = {
    # SlopeLS's value V_c: the window's mean speed
    "slope_value": ("estimator.c",
                    "double v_c = v_sum / (double)s->size;",
                    f"double v_c = v_sum * {ONE_ULP} / (double)s->size;"),
    # the slope's weight of interval j's force, grade (centred_slope_weights' c)
    "slope_interval_weights": ("ident.c",
                               "c[j] = dts[j] * tail;",
                               f"c[j] = dts[j] * tail * {ONE_ULP};"),
    # the prior's new information at a mass restart (reweight_prior)
    "slope_prior_reweight": ("ident.c",
                             "j0_new[i] = s2_new / prior_var;",
                             f"j0_new[i] = s2_new * {ONE_ULP} / prior_var;"),
}
# est.physical's projection, checked on est.physical 1 runs (est.method 2: more projections)
PHYSICAL_MUTATIONS = {
    # the projected Theta: theta - C[:, active] lambda
    "physical_projection": ("estimator.c", "t[i] = th[i] - s;", f"t[i] = th[i] - s * {ONE_ULP};"),
}
# One ulp can vanish in a scenario (the RK4 mutation leaves coasting_rusich_row1 unchanged, the
# sensor one coasting_rusich_row2); each mutation above changes both of these.
MUTATION_SCENARIOS = ("station_day", "crush_load")


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    """A copy of models/core with every unit compiled to an object (-O2, the strict flags)."""
    d = tmp_path_factory.mktemp("core_copy")
    for p in [*CORE.glob("*.c"), *CORE.glob("*.h"), DRIVER]:
        shutil.copy(p, d / p.name)
    sources = sorted(d.glob("*.c"))
    procs = [subprocess.Popen([gcc(), *STRICT, "-O2", "-c", str(s), "-o", str(s.with_suffix(".o"))],
                              cwd=d, stderr=subprocess.PIPE, text=True) for s in sources]
    for s, p in zip(sources, procs):
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, f"{s.name}: {err}"
    return d


def build_mutant(pristine: Path, directory: Path, mutation: tuple[str, str, str] | None) -> Path:
    """The driver from the copy with at most one source file mutated (only that unit recompiled:
    the mutations are in .c files, whose code no other unit includes)."""
    objects = {p.stem: p for p in pristine.glob("*.o")}
    if mutation is not None:
        filename, target, replacement = mutation
        text = (pristine / filename).read_text()
        assert text.count(target) == 1, f"{filename}: the mutation's target occurs {text.count(target)} times: {target!r}"
        mutated = directory / filename
        mutated.write_text(text.replace(target, replacement))
        obj = mutated.with_suffix(".o")
        compile_(*STRICT, "-O2", "-I", str(pristine), "-c", str(mutated), "-o", str(obj))
        objects[mutated.stem] = obj
    exe = directory / "chain_driver"
    compile_(*[str(o) for o in objects.values()], "-lm", "-o", str(exe))
    return exe


def test_the_unmutated_copy_gives_python_s_outputs(pristine, option_runs, tmp_path):
    exe = build_mutant(pristine, tmp_path, None)
    for run in [option_runs[o][n] for o in OPTIONS for n in MUTATION_SCENARIOS]:
        status, stderr, rows = run_driver(exe, run, tmp_path)
        assert status == 0 and stderr == "", stderr
        assert not differences(rows, run.expected), run.name


def changed_rows(exe, runs, tmp_path) -> dict[str, int]:
    """MUTATION_SCENARIOS' runs through ``exe``: scenario -> rows that differ from Python's."""
    changed = {}
    for name in MUTATION_SCENARIOS:
        status, stderr, rows = run_driver(exe, runs[name], tmp_path)
        assert status == 0 and stderr == "", stderr
        changed[name] = len(differences(rows, runs[name].expected))
    return changed


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_one_ulp_mutation_changes_the_outputs(mutation, pristine, runs, tmp_path):
    """The mutation must fail the comparison (in at least one of the scenarios)."""
    exe = build_mutant(pristine, tmp_path, MUTATIONS[mutation])
    changed = changed_rows(exe, runs, tmp_path)
    assert any(changed.values()), f"{mutation}: {MUTATION_SCENARIOS} equal Python's outputs bit for bit"


@pytest.mark.parametrize("mutation", SLOPE_MUTATIONS)
def test_a_one_ulp_mutation_of_slope_ls_changes_the_outputs(mutation, pristine, slope_runs, tmp_path):
    """est.method 2's code: the mutation must fail the comparison on an est.method 2 run."""
    exe = build_mutant(pristine, tmp_path, SLOPE_MUTATIONS[mutation])
    changed = changed_rows(exe, slope_runs, tmp_path)
    assert any(changed.values()), f"{mutation}: {MUTATION_SCENARIOS} equal Python's outputs bit for bit"


@pytest.mark.parametrize("mutation", PHYSICAL_MUTATIONS)
def test_a_one_ulp_mutation_of_the_projection_changes_the_outputs(mutation, pristine, option_runs,
                                                                  tmp_path):
    """est.physical's code: the mutation must fail the comparison on an est.physical 1 run."""
    exe = build_mutant(pristine, tmp_path, PHYSICAL_MUTATIONS[mutation])
    runs = option_runs["slope_ls_physical"]
    changed = changed_rows(exe, runs, tmp_path)
    assert any(changed.values()), f"{mutation}: {MUTATION_SCENARIOS} equal Python's outputs bit for bit"

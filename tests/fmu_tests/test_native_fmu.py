"""The native RailCar FMU (issue 18, fmu_src/build/native.py + fmu_src/c/native_railcar.c): the C core
behind our FMI 2.0 glue, no Python. Built once per module from the current sources, next to a
fresh pythonfmu RailCar.fmu (conftest's session build), and compared with it bit for bit.
"""
from __future__ import annotations

import subprocess
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.validation import validate_fmu

from conftest import DISCARD, ERROR, OK, ROOT, FmuFile, Slave, fifo_released
from fmu_src.build import native, toolchain
from fmu_src.variables import FORMER_DEFAULTS
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario
from test_profile_files import unfit  # noqa: F401 (a fixture)

LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))


@pytest.fixture(scope="module")
def native_fmu(native_fmus) -> Path:
    return native_fmus["RailCarNative"]


@pytest.fixture(scope="module")
def pair(built_fmus, native_fmu, tmp_path_factory) -> dict[str, FmuFile]:
    """name -> FmuFile for the pythonfmu RailCar.fmu ("py") and the native one ("c")."""
    out = {}
    for key, path in (("py", built_fmus["RailCar"]), ("c", native_fmu)):
        unzipdir = extract(str(path), unzipdir=str(tmp_path_factory.mktemp(f"unzip_native_{key}")))
        out[key] = FmuFile("RailCar", path, read_model_description(str(path)), unzipdir)
    return out


@pytest.fixture(scope="module")
def runners(built_fmus, native_fmu):
    py, c = FmuRunner(built_fmus["RailCar"]), FmuRunner(native_fmu)
    yield py, c
    py.close()
    c.close()


def bits(a) -> np.ndarray:
    """The float64 bit patterns (NaN == NaN, -0.0 != 0.0)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


# ------------------------------------------------------------------------------- the header

def test_table_header_is_current():
    proc = subprocess.run([sys.executable, "-m", "fmu_src.build.native", "--check"], cwd=ROOT,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_check_fails_on_a_stale_header(tmp_path, monkeypatch, capsys):
    stale = tmp_path / "native_railcar_table.h"
    stale.write_text(native.generate_header().replace("/* 14 */ 20,", "/* 14 */ 21,"))
    monkeypatch.setattr(native, "TABLE_HEADER", stale)
    monkeypatch.setattr(native, "ROOT", tmp_path)
    assert native.main(["--check"]) == 1
    assert "out of date" in capsys.readouterr().err


def test_every_config_index_is_explained():
    sources, constants = native.config_sources()
    from models.compiled import _config_values
    from fmu_src.adapter import chain_config
    from fmu_src.variables import variables_for
    table = variables_for("RailCar")
    # a random configuration: every index is what the mapping says
    rng = np.random.default_rng(18)
    values = {}
    for v in table:
        if v.type == "Real":
            values[v.name] = float(rng.uniform(0.01, 9.0))
        elif v.type == "Integer":
            values[v.name] = int(rng.integers(0, 1000))
        else:
            values[v.name] = ""
    cfg = _config_values(chain_config(values), 3.5)
    for k, s in enumerate(sources):
        want = (constants[k] if s == native.CONFIG_CONSTANT else 3.5
                if s == native.CONFIG_START_TIME else values[table[s].name])
        assert cfg[k] == want, (k, s)


# ------------------------------------------------------------------------------ the package

def test_binary_needs_no_python(native_fmu, tmp_path):
    with zipfile.ZipFile(native_fmu) as z:
        so = tmp_path / "RailCar.so"
        so.write_bytes(z.read("binaries/linux64/RailCar.so"))
        names = z.namelist()
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(so)], capture_output=True,
                               text=True, check=True).stdout
    python = [line for line in undefined.splitlines()
              if line.split()[-1].startswith(("Py", "_Py"))]
    assert not python, python
    ldd = subprocess.run(["ldd", str(so)], capture_output=True, text=True).stdout
    assert "python" not in ldd.lower(), ldd
    assert b"native C core backend" in so.read_bytes()
    assert not [n for n in names if n.endswith(".py") or "/models/" in n], names


def test_validates_and_describes_the_same_variables(native_fmu, built_fmus):
    assert validate_fmu(str(native_fmu)) == []
    md_c = read_model_description(str(native_fmu))
    md_py = read_model_description(str(built_fmus["RailCar"]))
    assert md_c.guid != md_py.guid
    assert md_c.coSimulation.modelIdentifier == "RailCar"
    assert ([(v.name, v.valueReference, v.type, v.causality, v.variability, v.start, v.unit)
             for v in md_c.modelVariables]
            == [(v.name, v.valueReference, v.type, v.causality, v.variability, v.start, v.unit)
                for v in md_py.modelVariables])
    assert md_c.coSimulation.needsExecutionTool is False or \
        str(md_c.coSimulation.needsExecutionTool).lower() == "false"
    with zipfile.ZipFile(native_fmu) as z:
        sources = sorted(n[len("sources/"):] for n in z.namelist() if n.startswith("sources/"))
        profiles = [n for n in z.namelist() if n.startswith("resources/profiles/")]
    listed = md_c.buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert listed and set(listed) <= set(sources)
    assert {s.name for s in native.c_sources()} == set(listed)
    assert "profiles/steep_grades.csv" in [p[len("resources/"):] for p in profiles]


def test_sources_compile_flat(native_fmu, tmp_path):
    """sources/ is a working source FMU: its .c files build from that one folder."""
    with zipfile.ZipFile(native_fmu) as z:
        z.extractall(tmp_path)
        md = read_model_description(str(native_fmu))
    src = tmp_path / "sources"
    out = tmp_path / "flat.so"
    cmd = [*toolchain.find_compiler(), "-std=c99", "-O2", "-ffp-contract=off", "-fPIC", "-shared",
           "-pthread", "-Wl,--no-undefined", "-I", str(src), "-I", str(toolchain.fmi_headers()),
           *[str(src / f) for f in md.buildConfigurations[0].sourceFileSets[0].sourceFiles], "-o", str(out), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


# ---------------------------------------------------------------- bit for bit with pythonfmu

@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_bit_identical(runners, path):
    py, c = runners
    scenario = load_scenario(path)
    a, b = py.run(scenario), c.run(scenario)
    assert np.array_equal(bits(a.time), bits(b.time))
    assert a.signals.keys() == b.signals.keys()
    for name in a.signals:
        diff = np.flatnonzero(bits(a.signals[name]) != bits(b.signals[name]))
        assert diff.size == 0, (f"{path.stem}: {name} differs first at row {diff[0]}: "
                                f"{a.signals[name][diff[0]]!r} vs {b.signals[name][diff[0]]!r}")
    assert a.log == b.log


def _outputs(s: Slave) -> list:
    reals = [v.name for v in s.fmu_file.md.modelVariables
             if v.causality == "output" and v.type == "Real"]
    ints = [v.name for v in s.fmu_file.md.modelVariables
            if v.causality == "output" and v.type == "Integer"]
    return (list(bits(s.get_reals(reals)))
            + list(s.fmu.getInteger([s.fmu_file.vr[n] for n in ints])))


def _drive(fmu: FmuFile, parameters: dict, start_time: float, inputs, n_steps: int,
           step: float = 0.1, times=None):
    """Outputs in initialisation mode, after it, and after every step; statuses; the log.
    Step k starts at times[k] (default start_time + k * step) with inputs(k)."""
    with Slave(fmu, "drive") as s:
        s.setup(parameters, start_time)
        rows = [_outputs(s)]
        assert s.exit_init() == OK, s.log_text()
        rows.append(_outputs(s))
        statuses = []
        for k in range(n_steps):
            s.set(inputs(k))
            t = times[k] if times is not None else start_time + k * step
            statuses.append(s.do_step(t, step))
            rows.append(_outputs(s))
        return rows, statuses, [str(m) for m in s.messages]


VARIANTS = {
    "singer_track_sensors_start_time": (
        {"filter.kind": 4, "sensor.track_spacing": 150.0, "sensor.track_jitter": 1e-3,
         "seed": 7, "car.length": 20.0, "sensor.position_std_rel": 0.002,
         "track.grade_profile": "profiles/steep_grades.csv"}, 12.5),
    "relative_speed_noise": (
        {"sensor.speed_std_rel": 0.02, "sensor.speed_std": 0.01, "seed": 9}, 0.0),
    "singer_relative_speed_noise": (
        {"filter.kind": 4, "sensor.speed_std_rel": 0.02, "seed": 4}, 2.0),
    "speed_profile_linearised": (
        {"track.speed_profile": "profiles/default_speed.csv", "filter.kind": 0, "seed": 3,
         "est.forgetting": 0.01, "car.initial_speed": 5.0}, 0.0),
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_variants_with_relative_profiles_and_start_time(pair, variant):
    parameters, start_time = VARIANTS[variant]

    def inputs(k):
        return {"traction_force_demand": 30e3 if k < 300 else 0.0,
                "brake_force_demand": 0.0 if k < 500 else 20e3,
                "wind_speed": 3.0 if 200 <= k < 400 else 0.0, "car.payload": 2.0 if k > 100 else 0.0}

    a = _drive(pair["py"], parameters, start_time, inputs, 700)
    b = _drive(pair["c"], parameters, start_time, inputs, 700)
    assert a[1] == b[1] == [OK] * 700
    for k, (ra, rb) in enumerate(zip(a[0], b[0])):
        assert ra == rb, f"row {k}"
    assert a[2] == b[2]


def test_nan_traction_is_discarded_and_the_instance_goes_on(pair):
    """Step 50 (t = 5.0) is discarded; step 51 retries t = 5.0 with a good input and goes on."""
    def inputs(k):
        return {"traction_force_demand": float("nan") if k == 50 else 20e3,
                "brake_force_demand": 0.0, "wind_speed": 0.0, "car.payload": 0.0}

    times = [0.1 * k for k in range(51)] + [0.1 * (k - 1) for k in range(51, 120)]
    a = _drive(pair["py"], {"seed": 5}, 0.0, inputs, 120, times=times)
    b = _drive(pair["c"], {"seed": 5}, 0.0, inputs, 120, times=times)
    assert b[1][50] == DISCARD and b[1].count(DISCARD) == 1
    assert a[1] == b[1]
    assert a[0] == b[0]                          # step 51 goes on from where step 49 ended
    discards = [m for m in b[2] if m.startswith("[discard]")]
    assert len(discards) == 1 and discards[0].startswith("[discard] step discarded: ")
    assert "traction_force_demand" in discards[0]
    assert [m for m in a[2] if m.startswith("[discard]")] == discards


def _init_failure(fmu: FmuFile, parameters: dict) -> tuple[int, str]:
    """exitInitializationMode's status and message (after "initialisation failed: ", the FMU's
    unzip folder written <FMU>)."""
    with Slave(fmu, "bad") as s:
        s.setup(parameters)
        status = s.exit_init()
        text = [m.message for m in s.messages if m.status == ERROR]
        # the instance stays usable: reset, then a good initialisation
        assert s.reset() == OK
        s.initialize({})
        s.step_to(0.1)
    text = text[0].split("initialisation failed: ", 1)[1] if text else ""
    return status, text.replace(str(Path(fmu.unzipdir).resolve()), "<FMU>")


@pytest.mark.parametrize("parameters, named", [
    ({"car.mass": -1.0}, "car.mass"),
    ({"sensor.speed_std_rel": -0.1}, "sensor.speed_std_rel"),
    ({"sensor.speed_std_rel": float("inf")}, "sensor.speed_std_rel"),
    ({"sensor.sample_period": 0.0}, "sensor.sample_period"),
    ({"filter.singer_p0": 0.95, "filter.kind": 4}, "filter.singer_*"),
    ({"track.grade_profile": "no/such/file.csv"}, "track.grade_profile"),
    ({"track.grade_profile": "g" * 300 + ".csv"}, "File name too long"),
    ({"track.speed_profile": "profiles/steep_grades.csv"}, "track.speed_profile"),
    ({"track.grade_profile": "/dev/zero"}, "it is a device, not a regular file"),
])
def test_bad_parameter_is_an_error_naming_it_as_python_does(pair, parameters, named):
    status_py, text_py = _init_failure(pair["py"], parameters)
    status_c, text_c = _init_failure(pair["c"], parameters)
    assert status_c == status_py == ERROR
    assert named in text_c
    assert text_c == text_py.splitlines()[0]


@pytest.mark.parametrize("case", ["fifo", "zero", "folder", "too_big"])
@pytest.mark.parametrize("param", ["track.grade_profile", "track.speed_profile"])
def test_a_profile_that_is_no_regular_file_is_refused_as_python_does(pair, unfit, param, case):
    """A FIFO, a device, a folder, a file over the 16 MiB bound: refused before it is opened (a
    FIFO's opening would wait for ever: fifo_released lets such a reader go, and fails it)."""
    path, why = unfit[case]
    with fifo_released(Path(unfit["fifo"][0])) as opened:
        status_py, text_py = _init_failure(pair["py"], {param: path})
        status_c, text_c = _init_failure(pair["c"], {param: path})
    assert opened == []
    assert status_c == status_py == ERROR
    assert text_c == text_py.splitlines()[0] == (
        f"{param}: cannot read '{path}' (looked for {path}): {why}")


@pytest.mark.parametrize("option", [{"est.method": 1}, {"est.method": 3}])
def test_an_option_only_python_runs_is_refused_naming_it(pair, option):
    """The options the C core does not run (models/compiled.py NOT_COVERED)."""
    status, text = _init_failure(pair["c"], option)
    (name, value), = option.items()
    assert status == ERROR
    assert f"{name} = {value}" in text and "RailCar.fmu" in text


@pytest.mark.parametrize("stem", ["ato_speed_noise", "coasting_rusich_row3"])
def test_physical_runs_natively_bit_identical(runners, stem):
    """est.physical 1 (A0, A2 >= 0 by projection) in the native FMU, where the paper's free LS's
    A0 or A2 goes negative: every output bit for bit the pythonfmu FMU's, no negative A0, A2."""
    py, c = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / f"{stem}.toml")
    scenario = replace(scenario, parameters={**scenario.parameters, **FORMER_DEFAULTS})
    free = c.run(scenario).signals
    assert np.any((free["est.A0"] < 0.0) | (free["est.A2"] < 0.0))
    scenario = replace(scenario, parameters={**scenario.parameters, "est.physical": 1})
    a, b = py.run(scenario), c.run(scenario)
    assert np.array_equal(bits(a.time), bits(b.time))
    for name in a.signals:
        diff = np.flatnonzero(bits(a.signals[name]) != bits(b.signals[name]))
        assert diff.size == 0, f"{stem}: {name} differs first at row {diff[0]}"
    assert np.all(b.signals["est.A0"] >= 0.0) and np.all(b.signals["est.A2"] >= 0.0)


def assert_runs_bit_identical(a, b, case: str) -> None:
    """Every output of run b bit for bit run a's, naming the first that differs."""
    assert np.array_equal(bits(a.time), bits(b.time)), case
    for name in a.signals:
        diff = np.flatnonzero(bits(a.signals[name]) != bits(b.signals[name]))
        assert diff.size == 0, f"{case}: {name} differs first at row {diff[0]}"


SLOPE_LS_CASES = [
    ("ato_speed_noise", {"est.method": 2}),
    ("ato_speed_noise", {"est.method": 2, "est.slope_window": 6}),
    ("coasting_rusich_row3", {"est.method": 2, "est.slope_window": 6, "est.physical": 1}),
    ("station_day", {"est.sigma2_method": 1}),
    ("ato_speed_noise", {"est.method": 2, "est.sigma2_method": 1, "est.physical": 1}),
]
"""est.method 2 (LS on Sidorenko's slopes): the default window, a non-default one (it must reach
the core, after the flat configuration) and with est.physical 1's projection; est.sigma2_method 1
(the likelihood bank) alone and with both."""


@pytest.mark.parametrize("stem,option", SLOPE_LS_CASES)
def test_slope_ls_runs_natively_bit_identical(runners, stem, option):
    """est.method 2 and est.sigma2_method 1 in the native FMU: every output bit for bit the
    pythonfmu FMU's."""
    py, c = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / f"{stem}.toml")
    scenario = replace(scenario, parameters={**scenario.parameters, **option})
    b = c.run(scenario)
    assert_runs_bit_identical(py.run(scenario), b, f"{stem} {option}")
    assert np.isfinite(b.signals["est.mass"]).any()              # the estimator did estimate
    if option.get("est.physical"):
        assert np.all(b.signals["est.A0"] >= 0.0) and np.all(b.signals["est.A2"] >= 0.0)


def test_slope_window_reaches_the_native_core(runners):
    """The control for the comparison above: est.slope_window 6 and 10 give different estimates
    (so the FMU's parameter is what the core uses), and est.method 2 differs from 0."""
    _, c = runners
    scenario = load_scenario(ROOT / "scenarios" / "library" / "ato_speed_noise.toml")
    runs = {}
    for key, option in (("m0", {"est.method": 0}), ("w10", {"est.method": 2, "est.slope_window": 10}),
                        ("w6", {"est.method": 2, "est.slope_window": 6})):
        runs[key] = c.run(replace(scenario, parameters={**scenario.parameters, **option})).signals
    for a, b in (("w10", "w6"), ("m0", "w10")):
        assert not np.array_equal(bits(runs[a]["est.mass"]), bits(runs[b]["est.mass"])), (a, b)


def test_innovation_gate_warning_as_python_logs_it(pair):
    """Sensors far better than the process noise the estimator assumes: the gate refuses
    measurements, each such step logs guarded_step's warning (and the step is OK)."""
    parameters = {"car.process_noise_psd": 1.0, "est.sigma2_initial": 1e-12,
                  "sensor.speed_std": 1e-4, "sensor.position_std": 1e-3}

    def inputs(k):
        return {"traction_force_demand": 30e3 if k % 40 < 20 else 0.0,
                "brake_force_demand": 0.0 if k % 40 < 20 else 40e3}

    a = _drive(pair["py"], parameters, 0.0, inputs, 200)
    b = _drive(pair["c"], parameters, 0.0, inputs, 200)
    assert a[1] == b[1] == [OK] * 200
    assert a[0] == b[0]
    warnings = [m for m in b[2] if m.startswith("[warning]")]
    assert len(warnings) > 10 and warnings[0].startswith(
        "[warning] 2 measurement(s) refused by the innovation gate in this step")
    assert a[2] == b[2]


COVARIANCES = ("est.cov_A0_A1", "est.cov_A0_A2", "est.cov_A1_A2")


def test_covariance_outputs_compared_and_seen_to_the_ulp(pair):
    """est.cov_* (the A's covariances, appended to the table) are among the outputs _drive
    compares, identified (not 0) by the end and bit-identical; one ulp off in any is a difference."""
    def inputs(k):
        return {"traction_force_demand": 30e3 if k < 300 else 0.0,
                "brake_force_demand": 0.0 if k < 450 else 20e3}

    a = _drive(pair["py"], {"seed": 5}, 0.0, inputs, 600)
    b = _drive(pair["c"], {"seed": 5}, 0.0, inputs, 600)
    reals = [v.name for v in pair["c"].md.modelVariables
             if v.causality == "output" and v.type == "Real"]
    assert reals[-5:-2] == list(COVARIANCES)         # the table's end: earlier vrs unchanged
    assert a[0] == b[0] and a[1] == b[1] == [OK] * 600
    for name in COVARIANCES:
        k = reals.index(name)
        x = float(np.int64(b[0][-1][k]).view(np.float64))
        assert x != 0.0 and np.isfinite(x), name
        off = list(b[0][-1])
        off[k] = int(bits([np.nextafter(x, np.copysign(np.inf, x))])[0])
        assert a[0][-1] != off, name


FORCE_MEANS = ("car.traction_force_mean", "car.brake_force_mean")


def test_force_mean_outputs_compared_and_seen_to_the_ulp(pair):
    """car.*_force_mean (the forces RailCar's estimator was fed, appended to the table last) are
    among the outputs _drive compares: 0 before the first step, the demand's mean while it is
    held below the limits, bit-identical; one ulp off in either is a difference."""
    def inputs(k):
        return {"traction_force_demand": 25e3 if k < 100 else 0.0,
                "brake_force_demand": 0.0 if k < 150 else 20e3}

    a = _drive(pair["py"], {"seed": 5}, 0.0, inputs, 200)
    b = _drive(pair["c"], {"seed": 5}, 0.0, inputs, 200)
    reals = [v.name for v in pair["c"].md.modelVariables
             if v.causality == "output" and v.type == "Real"]
    assert reals[-2:] == list(FORCE_MEANS)           # the table's end: earlier vrs unchanged
    assert a[0] == b[0] and a[1] == b[1] == [OK] * 200
    for name, row in (("car.traction_force_mean", 50), ("car.brake_force_mean", -1)):
        k = reals.index(name)
        assert [float(np.int64(r[k]).view(np.float64)) for r in b[0][:2]] == [0.0, 0.0], name
        x = float(np.int64(b[0][row][k]).view(np.float64))
        assert x > 1e3 and np.isfinite(x), name
        off = list(b[0][row])
        off[k] = int(bits([np.nextafter(x, np.inf)])[0])
        assert a[0][row] != off, name


def test_the_comparison_sees_a_difference(pair):
    """Another seed on one side: the rows differ (the equality above is not vacuous)."""
    def inputs(k):
        return {"traction_force_demand": 20e3}

    a = _drive(pair["py"], {"seed": 1}, 0.0, inputs, 20)
    b = _drive(pair["c"], {"seed": 2}, 0.0, inputs, 20)
    assert a[0][0] == b[0][0] and a[0][-1] != b[0][-1]


def test_clean_under_address_and_undefined_sanitizers(pair, tmp_path):
    """The backend, glue and core linked into a C host under ASan/UBSan (fmu_cases/native_host.c):
    steps, a discarded step and its retry, failed initialisations, reset, strings, free."""
    exe = tmp_path / "native_host"
    cmd = [*toolchain.find_compiler(), "-std=c99", "-O1", "-g", "-ffp-contract=off",
           "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-pthread",
           "-I", str(native.C_DIR), "-I", str(native.CORE_DIR), "-I", str(toolchain.fmi_headers()),
           str(ROOT / "tests" / "fmu_cases" / "native_host.c"),
           *[str(s) for s in native.c_sources()], "-o", str(exe), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    f = pair["c"]
    uri = (Path(f.unzipdir).resolve() / "resources").as_uri()
    args = [str(f.vr[n]) for n in ("car.mass", "traction_force_demand", "track.grade_profile",
                                   "track.speed_profile", "car.speed")]
    run = subprocess.run([str(exe), uri, f.md.guid, *args], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 0 and run.stdout.rstrip().endswith("ok"), run.stdout + run.stderr
    assert "runtime error" not in run.stderr and "Sanitizer" not in run.stderr, run.stderr
    assert "step discarded: " in run.stdout and "car.mass" in run.stdout

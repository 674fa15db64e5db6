"""SSP systems (harness.systems.ssp) run by our own master (harness.systems.master) and by libcosim
(harness.systems.libcosim): the same .ssp, the same table, bit for bit.

- the package written is read back to the same system; fmpy's SSP reader validates it against
  the SSP 1.0 schemas and sees the same parameters and connections; every bad input (unknown
  component or variable, type or unit mismatch, an output bound as a parameter, a missing FMU,
  malformed XML, ...) is an SspError naming the file, the element and the variable;
- RailCar -> RailCarEstimator (the measured speed, distance and applied forces), native and
  pythonfmu FMUs: every Real and Integer output of both components, at every time point from
  the initial values on, has the same bits in both masters (tolerance: none; the comparison is
  shown to see one ulp of one parameter);
- RailCar <-> AtoController (the filter's and estimator's outputs in, the demands back, the loop
  broken by the Jacobi step delay): the same in both masters, and the car stops at the mark;
- a component's discard or error stops the run with a message naming it, the call, the time and
  the status; the process goes on; FMI 3 components run in our master (libcosim refuses them).
"""
from __future__ import annotations

import math
import zipfile
from pathlib import Path

import numpy as np
import pytest

from harness.systems.master import MasterError, Result, run_system, time_grid
from harness.systems.ssp import Component, Connection, SspError, SystemSpec, write_ssp
from harness.systems.ssp_read import read_ssp

pytest.importorskip("libcosimpy")
from harness.systems.libcosim import run_libcosim  # noqa: E402

STEP = 0.1
N_PE = 300                      # 30 s: the car accelerates up the demo profile's hill
N_ATO = 500                     # 50 s: the ATO's 400 m span, schedule 45 s, and 5 s standing
CAR = {"car.mass": 36.0, "seed": 11, "traction_force_demand": 30e3,
       "track.grade_profile": "profiles/demo_grade.csv"}          # in the FMU's resources/
EST = {"est.mass_initial": 30.0, "est.batch_size": 40}
MEASURED = (("sensor.speed", "sensor.speed"), ("sensor.position", "sensor.position"),
            ("car.traction_force", "traction_force"), ("car.brake_force", "brake_force"))
from harness.systems.scenario_system import ATO_FEED, DEMANDS  # noqa: E402  (what the ATO reads and asks)
SPAN = {"span.stop": 400.0, "span.schedule": 45.0, "span.grade_profile": "profiles/ato_span_grade.csv"}


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def plant_estimator(car_fmu, est_fmu, car=None, name="plant_estimator") -> SystemSpec:
    return SystemSpec(name, [Component("car", car_fmu, CAR if car is None else car),
                             Component("est", est_fmu, EST)],
                      [Connection(f"car.{a}", f"est.{b}") for a, b in MEASURED], STEP,
                      stop=N_PE * STEP, description="RailCar's measurements into RailCarEstimator")


def ato_system(car_fmu, ato_fmu) -> SystemSpec:
    return SystemSpec("ato_span", [Component("car", car_fmu, {"seed": 31, "car.mass": 30.0,
                                                              "track.grade_profile": SPAN["span.grade_profile"]}),
                                   Component("ato", ato_fmu, SPAN)],
                      [Connection(f"car.{v}", f"ato.{v}") for v in ATO_FEED]
                      + [Connection(f"ato.{v}", f"car.{v}") for v in DEMANDS], STEP, stop=N_ATO * STEP)


def assert_same(a: Result, b: Result) -> None:
    """Every column of libcosim's table ``b`` has the same bits in ours, ``a``."""
    assert np.array_equal(bits(a.time), bits(b.time))
    assert set(b.signals) <= set(a.signals) and len(b.signals) >= 20
    for name, y in b.signals.items():
        x = a[name]
        same = np.array_equal(bits(x), bits(y)) if y.dtype.kind == "f" else np.array_equal(x, y)
        first = None if same else int(np.flatnonzero(x != y)[0])
        assert same, f"{name} differs first at t = {a.time[first]} s: {x[first]!r} vs {y[first]!r}"
        assert a.units[name] == b.units[name]


@pytest.fixture(scope="module")
def native(built_fmus) -> dict[str, Path]:
    d = built_fmus["RailCar"].parent / "native"
    return {n: d / f"{n}.fmu" for n in ("RailCarNative", "RailCarEstimatorNative", "RailCarNative3",
                                        "RailCarEstimatorNative3")}


@pytest.fixture(scope="module")
def pe_ssp(native, tmp_path_factory) -> Path:
    return write_ssp(plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"]),
                     tmp_path_factory.mktemp("ssp") / "plant_estimator.ssp")


@pytest.fixture(scope="module")
def pe_runs(pe_ssp):
    return run_system(pe_ssp), run_libcosim(pe_ssp, log_level="ERROR")


# ------------------------------------------------------------------------ the file itself

def test_written_system_reads_back_the_same(native, pe_ssp):
    spec = plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"])
    got = read_ssp(pe_ssp).spec
    assert (got.name, got.step, got.start, got.stop, got.description) == \
        (spec.name, 0.1, 0.0, 30.0, spec.description)
    assert [(c.name, c.fmu, dict(c.parameters)) for c in got.components] == [
        ("car", "resources/RailCarNative.fmu", CAR), ("est", "resources/RailCarEstimatorNative.fmu", EST)]
    assert type(got.components[0].parameters["seed"]) is int
    assert list(got.connections) == list(spec.connections)
    with zipfile.ZipFile(pe_ssp) as z:
        assert sorted(z.namelist()) == ["SystemStructure.ssd", "resources/RailCarEstimatorNative.fmu",
                                        "resources/RailCarNative.fmu", "resources/car.ssv",
                                        "resources/est.ssv"]
        assert z.read("resources/RailCarNative.fmu") == native["RailCarNative"].read_bytes()
        ssd = z.read("SystemStructure.ssd").decode()
    # every input and output is a connector with its type and unit; the units are defined
    assert '<ssd:Connector name="car.speed" kind="output">\n            <ssc:Real unit="m/s" />' in ssd
    assert '<ssd:Connector name="est.status" kind="output">\n            <ssc:Integer />' in ssd
    assert '<ssc:Unit name="t">\n      <ssc:BaseUnit kg="1" factor="1000.0" />' in ssd
    assert '<osp:FixedStepAlgorithm baseStepSize="0.1" />' in ssd


def test_fmpy_validates_the_package_against_the_ssp_schemas(pe_ssp):
    from fmpy.ssp.ssd import read_ssd
    ssd = read_ssd(str(pe_ssp))                      # raises unless the SSD and SSVs are schema-valid
    comps = {c.name: c for c in ssd.system.elements}
    params = {p.name: (p.type, p.value, p.unit)
              for p in comps["car"].parameterBindings[0].parameterValues[0].parameters}
    assert params == {"car.mass": ("Real", "36.0", "t"), "seed": ("Integer", "11", None),
                      "traction_force_demand": ("Real", "30000.0", "N"),
                      "track.grade_profile": ("String", "profiles/demo_grade.csv", None)}
    assert [(c.startElement, c.startConnector, c.endElement, c.endConnector)
            for c in ssd.system.connections] == [("car", a, "est", b) for a, b in MEASURED]
    assert {u.name for u in ssd.units} >= {"m/s", "m", "N", "t", "N/kN"}


# ---------------------------------------------------------------------------- bad input

def _spec(native, connections=None, car=None, est_fmu=None):
    spec = plant_estimator(native["RailCarNative"], est_fmu or native["RailCarEstimatorNative"], car=car)
    if connections is not None:
        spec = SystemSpec(spec.name, spec.components, [Connection(*c) for c in connections], STEP)
    return spec


WRITE_ERRORS = {
    "unknown component": (dict(connections=[("train.sensor.speed", "est.sensor.speed")]),
                          ["connection 1 (train.sensor.speed -> est.sensor.speed)", "no component named 'train'"]),
    "unknown variable": (dict(connections=[("car.sensor.speeed", "est.sensor.speed")]),
                         ["connection 1", "component 'car' (RailCar) has no variable 'sensor.speeed'"]),
    "type mismatch": (dict(connections=[("car.car.mode", "est.sensor.speed")]),
                      ["connection 1", "type mismatch: car.car.mode is Integer, est.sensor.speed is Real"]),
    "unit mismatch": (dict(connections=[("car.car.speed", "est.sensor.position")]),
                      ["connection 1", "unit mismatch: car.car.speed [m/s], est.sensor.position [m]"]),
    "output to output": (dict(connections=[("car.car.speed", "est.filter.speed")]),
                         ["connection 1", "est.filter.speed is an output"]),
    "input driven twice": (dict(connections=[("car.sensor.speed", "est.sensor.speed"),
                                             ("car.car.speed", "est.sensor.speed")]),
                           ["connection 2", "est.sensor.speed is already driven by car.sensor.speed"]),
    "unknown parameter": (dict(car={"car.mas": 36.0}),
                          ["parameter binding of 'car'", "has no variable 'car.mas'"]),
    "output bound": (dict(car={"car.speed": 3.0}),
                     ["parameter binding car.car.speed", "'car.speed' is an output"]),
    "bad value": (dict(car={"car.mass": "heavy"}),
                  ["parameter binding car.car.mass (Real)", "'heavy' is not a valid Real"]),
    "non-finite value": (dict(car={"car.mass": math.inf}), ["car.car.mass", "not a finite Real"]),
    "integer range": (dict(car={"seed": 2**31}), ["car.seed", "outside the 32-bit Integer range"]),
    "missing FMU": (dict(est_fmu=Path("nowhere/Est.fmu")),
                    ["component 'est': FMU file not found: nowhere/Est.fmu"]),
}


@pytest.mark.parametrize("case", list(WRITE_ERRORS))
def test_writing_a_bad_system_names_the_element(native, tmp_path, case):
    kwargs, words = WRITE_ERRORS[case]
    target = tmp_path / "bad.ssp"
    with pytest.raises(SspError) as e:
        write_ssp(_spec(native, **kwargs), target)
    assert str(target) in str(e.value)
    for w in words:
        assert w in str(e.value)
    assert not target.exists()


def _rewrite(ssp: Path, dest: Path, member: str, edit) -> Path:
    """A copy of ``ssp`` with ``member`` passed through ``edit`` (text -> text; None drops it)."""
    with zipfile.ZipFile(ssp) as src, zipfile.ZipFile(dest, "w") as out:
        for item in src.namelist():
            data = src.read(item)
            if item == member:
                text = edit(None if item.endswith(".fmu") else data.decode())
                if text is None:
                    continue
                data = text.encode()
            out.writestr(item, data)
    return dest


SSD, CAR_SSV = "SystemStructure.ssd", "resources/car.ssv"
READ_ERRORS = {
    "malformed SSD": (SSD, lambda t: t.replace("</ssd:Elements>", "", 1),
                      ["bad.ssp: SystemStructure.ssd: malformed XML", "line"]),
    "no SSD": (SSD, lambda t: None, ["bad.ssp: no SystemStructure.ssd in the package"]),
    "missing FMU": ("resources/RailCarEstimatorNative.fmu", lambda t: None,
                    ["component 'est'", "FMU 'resources/RailCarEstimatorNative.fmu' is not in the package"]),
    "unknown component": (SSD, lambda t: t.replace('endElement="est"', 'endElement="estimator"', 1),
                          ["SystemStructure.ssd: connection 1 (estimator.sensor.speed)",
                           "no component named 'estimator'"]),
    "undeclared connector": (SSD, lambda t: t.replace('startConnector="sensor.speed"',
                                                      'startConnector="sensor.sped"', 1),
                             ["connection 1 (car.sensor.sped)", "component 'car' declares no connector 'sensor.sped'"]),
    "connector not in FMU": (SSD, lambda t: t.replace('<ssd:Connector name="car.grade"',
                                                      '<ssd:Connector name="car.gradient"', 1),
                             ["component 'car': connector 'car.gradient'", "has no variable 'car.gradient'"]),
    "connector type": (SSD, lambda t: t.replace('name="car.speed" kind="output">\n            <ssc:Real unit="m/s" />',
                                                'name="car.speed" kind="output">\n            <ssc:Integer />', 1),
                       ["connector 'car.speed'", "type mismatch: ssc:Integer, the FMU's variable is Real"]),
    "connector unit": (SSD, lambda t: t.replace('name="car.speed" kind="output">\n            <ssc:Real unit="m/s" />',
                                                'name="car.speed" kind="output">\n            <ssc:Real unit="km/h" />', 1),
                       ["connector 'car.speed'", "unit 'km/h', the FMU's is 'm/s'"]),
    "connector kind": (SSD, lambda t: t.replace('name="car.speed" kind="output"', 'name="car.speed" kind="input"', 1),
                       ["connector 'car.speed'", "kind 'input', but the FMU's variable is an output"]),
    "parameter type": (CAR_SSV, lambda t: t.replace('<ssv:Real value="36.0" unit="t" />', '<ssv:Integer value="36" />'),
                       ["bad.ssp: resources/car.ssv: parameter 'car.mass'", "type mismatch: ssv:Integer for car.car.mass"]),
    "parameter unknown": (CAR_SSV, lambda t: t.replace('name="car.mass"', 'name="car.mas"'),
                          ["resources/car.ssv: parameter 'car.mas'", "has no variable 'car.mas'"]),
    "parameter value": (CAR_SSV, lambda t: t.replace('value="11"', 'value="eleven"'),
                        ["parameter binding car.seed (Integer)", "'eleven' is not a valid Integer"]),
    "parameter set malformed": (CAR_SSV, lambda t: t.replace("</ssv:Parameters>", ""),
                                ["bad.ssp: resources/car.ssv: malformed XML"]),
    "no step": (SSD, lambda t: t.replace('baseStepSize="0.1"', 'stepSize="0.1"'),
                ["<FixedStepAlgorithm> has no 'baseStepSize' attribute"]),
    "transformation": (SSD, lambda t: t.replace('endConnector="sensor.speed" />',
                                                'endConnector="sensor.speed"><ssc:LinearTransformation factor="2" /></ssd:Connection>', 1),
                       ["connection 1", "<LinearTransformation> is not supported"]),
}


@pytest.mark.parametrize("case", list(READ_ERRORS))
def test_reading_a_bad_package_names_the_file_element_and_variable(pe_ssp, tmp_path, case):
    member, edit, words = READ_ERRORS[case]
    bad = _rewrite(pe_ssp, tmp_path / "bad.ssp", member, edit)
    with pytest.raises(SspError) as e:
        read_ssp(bad)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert str(bad) in str(e.value)


def _inline(ssd: str, ssv: str) -> str:
    """The SSD with car's parameter set inline (ssd:ParameterValues) instead of resources/car.ssv."""
    body = ssv.split("?>", 1)[1].strip()
    return ssd.replace('<ssd:ParameterBinding source="resources/car.ssv" type="application/x-ssp-parameter-set" />',
                       f"<ssd:ParameterBinding><ssd:ParameterValues>{body}</ssd:ParameterValues></ssd:ParameterBinding>")


def test_an_inline_parameter_set_reads_and_runs_the_same(pe_ssp, pe_runs, tmp_path):
    """A parameter set inline in the SSD (the other form libcosim reads) gives the same system and,
    in both masters, the same numbers."""
    with zipfile.ZipFile(pe_ssp) as z:
        ssv = z.read(CAR_SSV).decode()
    inline = _rewrite(pe_ssp, tmp_path / "inline.ssp", SSD, lambda t: _inline(t, ssv))
    inline = _rewrite(inline, tmp_path / "inline2.ssp", CAR_SSV, lambda t: None)   # the file goes
    assert read_ssp(inline).spec == read_ssp(pe_ssp).spec
    ref, _ = pe_runs
    for run in (run_system(inline, n_steps=50), run_libcosim(inline, n_steps=50, log_level="ERROR")):
        for name, x in run.signals.items():
            assert np.array_equal(bits(x), bits(ref[name][:51])), (run.master, name)


def test_what_libcosim_would_read_otherwise_is_refused(pe_ssp, tmp_path):
    """Two parameter bindings (libcosim applies only the first) are refused by our reader; other
    namespace prefixes (libcosim looks up 'ssd:' literally) by the libcosim runner."""
    two = _rewrite(pe_ssp, tmp_path / "two.ssp", SSD, lambda t: t.replace(
        '<ssd:ParameterBinding source="resources/car.ssv" type="application/x-ssp-parameter-set" />',
        '<ssd:ParameterBinding source="resources/car.ssv" /><ssd:ParameterBinding source="resources/est.ssv" />'))
    with pytest.raises(SspError, match="component 'car': 2 ssd:ParameterBinding elements; one is supported"):
        read_ssp(two)
    other = _rewrite(pe_ssp, tmp_path / "prefix.ssp", SSD,
                     lambda t: t.replace("ssd:", "s:").replace("xmlns:ssd=", "xmlns:s="))
    assert read_ssp(other).spec == read_ssp(pe_ssp).spec          # the same SSP to a namespace-aware reader
    with pytest.raises(SspError, match="libcosim reads the namespace prefix 'ssd:' literally"):
        run_libcosim(other, n_steps=2)


def test_not_a_package(tmp_path):
    (tmp_path / "x.ssp").write_text("hello")
    with pytest.raises(SspError, match=r"x.ssp: not an SSP package \(a zip archive\)"):
        read_ssp(tmp_path / "x.ssp")
    with pytest.raises(SspError, match=r"y.ssp: no such file"):
        read_ssp(tmp_path / "y.ssp")


# ------------------------------------------------------------------ the two masters agree

def test_plant_and_estimator_bit_identical_in_both_masters(pe_runs):
    ours, lc = pe_runs
    assert ours.master == "harness.systems.master" and lc.master == "libcosim"
    assert len(ours.time) == N_PE + 1 and np.array_equal(ours.time, time_grid(0.0, STEP, N_PE))
    assert_same(ours, lc)
    # a real run: the car moves, the estimator fed through the connections identifies the mass
    assert ours["car.car.speed"][-1] > 15
    fed, own = ours["est.est.mass"][-1], ours["car.est.mass"][-1]
    # the two estimators see the same measurements a step apart in their forces: they agree
    # within the stated uncertainty (30 s of constant traction: est.mass_std 0.8 t here)
    stated = ours["car.est.mass_std"][-1]
    assert fed != 30.0 and fed == pytest.approx(36.0, rel=0.03) and abs(fed - own) <= 2.0 * stated
    # the estimator's first step is fed the car's measurement at t = 0 (libcosim's initialisation
    # carries the outputs into the inputs before the first step)
    assert ours["est.filter.speed"][2] != 0.0


def test_a_moving_start_shows_libcosims_initialisation(native, tmp_path):
    """The car starts at 12 m/s, 50 m, and the estimator's connected sensor.speed also gets a
    start value of 5 m/s. Observing the estimator's inputs in both masters (same bits) shows what
    libcosim does: in initialisation mode the connections carry RailCar's outputs, which are its
    start values (0) until fmi2ExitInitializationMode, and they overwrite the start value 5; after
    it they carry the outputs at t = 0, which the estimator's first step gets."""
    car = dict(CAR, **{"car.initial_speed": 12.0, "car.initial_position": 50.0})
    spec = plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"], car=car)
    spec = SystemSpec("moving", [spec.components[0], Component("est", native["RailCarEstimatorNative"],
                                                               dict(EST, **{"sensor.speed": 5.0}))],
                      spec.connections, STEP)
    ssp = write_ssp(spec, tmp_path / "moving.ssp")
    outputs = ["car.sensor.speed", "car.sensor.position", "est.sensor.speed", "est.sensor.position",
               "est.filter.speed", "est.est.mass"]
    ours = run_system(ssp, n_steps=50, outputs=outputs)
    lc = run_libcosim(ssp, n_steps=50, outputs=outputs, log_level="ERROR")
    for name in outputs:
        assert np.array_equal(bits(ours[name]), bits(lc[name])), name
    assert ours["car.sensor.speed"][0] == pytest.approx(12.0, abs=0.2)
    assert ours["est.sensor.speed"][0] == 0.0 and ours["est.sensor.position"][0] == 0.0
    for name in ("sensor.speed", "sensor.position"):          # Jacobi: one step behind
        assert np.array_equal(ours[f"est.{name}"][1:], ours[f"car.{name}"][:-1]), name
    assert ours["est.filter.speed"][1] > 5.0


def test_the_comparison_sees_one_ulp_of_one_parameter(native, pe_runs, tmp_path):
    _, lc = pe_runs
    car = dict(CAR, **{"car.mass": math.nextafter(36.0, math.inf)})
    ssp = write_ssp(plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"], car=car),
                    tmp_path / "ulp.ssp")
    assert read_ssp(ssp).spec.components[0].parameters["car.mass"] == math.nextafter(36.0, math.inf)
    other = run_system(ssp, outputs=list(lc.signals))
    with pytest.raises(AssertionError, match="differs first"):
        assert_same(other, lc)


def test_pythonfmu_plant_and_estimator_in_both_masters(built_fmus, pe_runs, tmp_path):
    """The pythonfmu RailCar.fmu and RailCarEstimator.fmu in both masters: bit-identical to each
    other and to the native pair."""
    ssp = write_ssp(plant_estimator(built_fmus["RailCar"], built_fmus["RailCarEstimator"]),
                    tmp_path / "plant_estimator_py.ssp")
    native_run, _ = pe_runs
    ours = run_system(ssp, n_steps=100)
    lc = run_libcosim(ssp, n_steps=100, log_level="ERROR")
    assert_same(ours, lc)
    for name, x in ours.signals.items():
        assert np.array_equal(bits(x), bits(native_run[name][:101])), name


def test_fmi3_components_in_our_master(native, pe_runs, tmp_path):
    """The FMI 3 native FMUs in our master give the FMI 2 system's numbers; libcosim 0.11 runs FMI
    2.0 only, and run_libcosim says so before libcosim is asked."""
    ssp = write_ssp(plant_estimator(native["RailCarNative3"], native["RailCarEstimatorNative3"]),
                    tmp_path / "plant_estimator3.ssp")
    ref, _ = pe_runs
    ours = run_system(ssp, n_steps=100)
    for name, x in ref.signals.items():
        assert np.array_equal(bits(ours[name]), bits(x[:101])), name
    with pytest.raises(SspError, match="component 'car' is an FMI 3.0 FMU; libcosim 0.11 runs FMI 2.0 only"):
        run_libcosim(ssp, n_steps=10)
    bad = write_ssp(plant_estimator(native["RailCarNative3"], native["RailCarEstimatorNative3"],
                                    car=dict(CAR, **{"car.mass": 0.0})), tmp_path / "bad3.ssp")
    with pytest.raises(MasterError, match="(?s)component 'car': fmi3ExitInitializationMode at t = 0.0 s "
                                          "returned error\n.*car.mass must be > 0"):
        run_system(bad, n_steps=2)


def test_result_csv_has_units_and_exact_values(pe_runs, tmp_path):
    ours, _ = pe_runs
    path = ours.write_csv(tmp_path / "r.csv")
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    assert header[:3] == ["time [s]", "car.car.speed [m/s]", "car.car.position [m]"]
    assert "car.car.mode [-]" in header and "est.est.mass [t]" in header
    assert len(lines) == N_PE + 2
    last = dict(zip(header, lines[-1].split(",")))
    assert float(last["est.est.mass [t]"]) == ours["est.est.mass"][-1]
    assert last["est.est.status [-]"] == str(ours["est.est.status"][-1])


# ------------------------------------------------------------------------ failures

def test_a_discarded_step_stops_the_run_naming_component_time_and_status(native, tmp_path):
    car = dict(CAR, traction_force_demand=-5.0)
    ssp = write_ssp(plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"], car=car),
                    tmp_path / "discard.ssp")
    with pytest.raises(MasterError) as e:
        run_system(ssp, n_steps=10)
    assert e.value.message == "plant_estimator: component 'car': doStep at t = 0.0 s returned discard"
    assert any("traction_force_demand must be finite and >= 0" in m for m in e.value.log)
    with pytest.raises(MasterError, match=r"libcosim stopped at t = 0.0 s: .*car: Step not complete"):
        run_libcosim(ssp, n_steps=10, log_level="ERROR")


def test_an_fmu_without_a_binary_stops_the_run_naming_it(native, tmp_path):
    """The estimator's FMU without binaries/: the run stops at instantiation, naming the
    component; the car's instance, instantiated before it, is freed."""
    broken = tmp_path / "RailCarEstimatorNative.fmu"
    with zipfile.ZipFile(native["RailCarEstimatorNative"]) as src, zipfile.ZipFile(broken, "w") as out:
        for item in src.namelist():
            if not item.startswith("binaries/"):
                out.writestr(item, src.read(item))
    ssp = write_ssp(plant_estimator(native["RailCarNative"], broken), tmp_path / "nobinary.ssp")
    with pytest.raises(MasterError, match=r"plant_estimator: component 'est': instantiate at t = 0.0 s "
                                          r"failed \(Exception: Cannot find shared library"):
        run_system(ssp, n_steps=2)


def test_a_failed_initialisation_stops_the_run_naming_the_parameter(native, pe_ssp, tmp_path):
    car = dict(CAR, **{"car.mass": -1.0})
    ssp = write_ssp(plant_estimator(native["RailCarNative"], native["RailCarEstimatorNative"], car=car),
                    tmp_path / "init.ssp")
    with pytest.raises(MasterError) as e:
        run_system(ssp, n_steps=10)
    assert e.value.message == ("plant_estimator: component 'car': fmi2ExitInitializationMode at t = 0.0 s "
                               "returned error")
    assert "car.mass must be > 0, got -1.0" in str(e.value)
    # the process goes on, and the next run works
    assert len(run_system(pe_ssp, n_steps=2).time) == 3


def test_unknown_outputs_and_stop_times_are_refused(pe_ssp):
    with pytest.raises(SspError, match="output 'est.est.mas': .*has no variable 'est.mas'"):
        run_system(pe_ssp, n_steps=2, outputs=["est.est.mas"])
    with pytest.raises(SspError, match="output 'estimator.est.mass': no component named 'estimator'"):
        run_libcosim(pe_ssp, n_steps=2, outputs=["estimator.est.mass"])
    with pytest.raises(SspError, match=r"stop time 1.05 s is not start \+ a whole number of steps"):
        run_system(pe_ssp, stop_time=1.05)


# ---------------------------------------------------------------------- the ATO system

@pytest.fixture(scope="module")
def ato_runs(native, built_fmus, tmp_path_factory):
    ato = built_fmus["RailCar"].parent / "AtoController.fmu"
    if not ato.is_file():
        pytest.skip("no AtoController.fmu in the build")
    ssp = write_ssp(ato_system(native["RailCarNative"], ato), tmp_path_factory.mktemp("ato") / "ato.ssp")
    return run_system(ssp), run_libcosim(ssp, log_level="ERROR")


def test_ato_system_bit_identical_in_both_masters(ato_runs):
    ours, lc = ato_runs
    assert len(ours.time) == N_ATO + 1
    assert_same(ours, lc)
    # libcosim's table lacks only the Boolean outputs (its time series hold none)
    assert set(ours.signals) - set(lc.signals) == {n for n, x in ours.signals.items() if x.dtype == bool}


def test_ato_system_stops_the_car_at_the_mark(ato_runs):
    ours, _ = ato_runs
    speed, position = ours["car.car.speed"], ours["car.car.position"]
    finished = np.flatnonzero(ours["ato.ato.finished"])
    assert finished.size and ours["ato.ato.finished"][finished[0]:].all()
    arrival = ours.time[finished[0]]
    assert abs(arrival - SPAN["span.schedule"]) < 2.0, arrival
    assert abs(position[-1] - SPAN["span.stop"]) < 0.5 and speed[-1] == 0.0
    assert speed.max() < 22.3                          # the default 80 km/h limit
    # after initialisation: a holding brake; then the plant applies each command one step later
    # (Jacobi: the demand computed at t reaches the car for [t + h, t + 2h])
    demand_t, demand_b = ours["ato.traction_force_demand"], ours["ato.brake_force_demand"]
    assert demand_t[0] == 0.0 and demand_b[0] > 0.0
    assert np.array_equal(ours["car.car.brake_force"][1:], demand_b[:-1])
    assert np.all(ours["car.car.traction_force"][1:] <= demand_t[:-1])
    assert not np.any((demand_t > 0) & (demand_b > 0))


def test_ato_refusing_its_parameters_stops_our_master(native, built_fmus, tmp_path):
    """An infeasible schedule: the pythonfmu AtoController fails exitInitializationMode (Error, not
    Fatal: its instance is freed) naming the parameter; the run stops, naming the component."""
    ato = built_fmus["RailCar"].parent / "AtoController.fmu"
    if not ato.is_file():
        pytest.skip("no AtoController.fmu in the build")
    spec = ato_system(native["RailCarNative"], ato)
    bad = SystemSpec(spec.name, [spec.components[0], Component("ato", ato, dict(SPAN, **{"span.schedule": 5.0}))],
                     spec.connections, STEP)
    with pytest.raises(MasterError) as e:
        run_system(write_ssp(bad, tmp_path / "bad_ato.ssp"), n_steps=5)
    assert e.value.message == "ato_span: component 'ato': fmi2ExitInitializationMode at t = 0.0 s returned error"
    assert "span.schedule" in str(e.value)
    # libcosim aborts its process on it: isolated, the abort is a MasterError here
    with pytest.raises(MasterError) as e:
        run_libcosim(tmp_path / "bad_ato.ssp", n_steps=5, log_level="ERROR", isolated=True)
    assert e.value.message == ("ato_span: libcosim's process was killed by SIGABRT (an FMU failing "
                               "initialisation aborts libcosim)")
    assert "span.schedule = 5.00 s is infeasible" in str(e.value)


def test_libcosim_in_a_child_process_gives_the_same_table(pe_ssp, pe_runs):
    _, lc = pe_runs
    child = run_libcosim(pe_ssp, log_level="ERROR", isolated=True)
    assert child.units == lc.units and list(child.signals) == list(lc.signals)
    assert_same(child, lc)
    with pytest.raises(SspError, match="output 'est.est.mas'"):
        run_libcosim(pe_ssp, n_steps=2, outputs=["est.est.mas"], isolated=True)

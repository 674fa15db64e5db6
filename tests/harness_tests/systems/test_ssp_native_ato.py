"""The all-native ATO closed loop as an SSP package (issue 30): RailCarNative <-> AtoControllerNative,
built from a span scenario by ``python -m harness system build`` (harness.systems.scenario_system), run
in our master, libcosim and ecos.

- ``--fmu`` chooses the AtoController's FMU as it chooses the car's: ``auto`` the native FMU when
  harness.run.fmus.uncovered says it runs the parameters the system gives it, else the pythonfmu
  FMU, saying why; ``native`` refuses at build what the native FMU does not run, naming it;
  ``python`` the pythonfmu FMU. A line follows whatever ``uncovered`` says (today the native ATO
  runs one span; when it runs lines, the same test holds with the other branch);
- the library's span (scenarios/library/ato_nominal.toml, --jacobi: libcosim and ecos step
  Jacobi) built all-native runs in the three masters: libcosim gives our master's bits for every
  output it observes, ecos every Integer and Boolean, and every Real within RELATIVE_TOLERANCE;
- the native ATO is the pythonfmu ATO bit for bit in our master (the ATO stepping first);
- the line (scenarios/library/ato_line.toml, --jacobi), on whichever ATO ``auto`` picks, gives a
  row per master, not a crash, over its first 150 s (ecos's summed clock drifts with the steps:
  3.5e-11 relative over the whole line's 4750 steps, within 1e-11 over the first 1500);
- the three native FMUs wired as a tool would wire them (scenarios/systems/ato_three_native.toml)
  stop the car at the mark in our master and give the same numbers in libcosim and ecos;
- ``--fmi 3`` builds on the FMI 3.0 natives (RailCarNative3, AtoControllerNative3): checked in ours
  and ecos when the session's build has AtoControllerNative3.fmu, else the build's refusal naming
  the missing file is what is checked.

The tolerance for ecos: RELATIVE_TOLERANCE of test_ssp_ecos.py (1e-11 relative to max(1, |ours|)),
which says why: ecos gives doStep the time as a running sum of the step, ours and libcosim
k * 10^8 ns / 10^9, and the ATO uses the time it is given. Measured on the all-native span:
8.6e-14 (1950 steps), the same as with the pythonfmu ATO. Where ecos or libcosim cannot run here,
the test is skipped with a reason naming its check and what to install.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from fmu_src.variables import ATO
from harness.run.fmus import uncovered
from harness.systems import scenario_system as scenario_module
from harness.systems.cli import build, compare_masters, main
from harness.systems.ecos import ecos_unavailable
from harness.systems.master import run_system
from harness.systems.ssp import PackedFile, SspError
from harness.systems.ssp_read import read_ssp
from harness.systems.scenario_system import scenario_system
from test_ssp_ecos import RELATIVE_TOLERANCE

NOMINAL = ROOT / "scenarios" / "library" / "ato_nominal.toml"
LINE = ROOT / "scenarios" / "library" / "ato_line.toml"
NATIVE_ATO, PYTHON_ATO = "AtoControllerNative.fmu", "AtoController.fmu"


def need(master: str, check: str) -> None:
    """Skip, naming ``check`` and what is missing, where ``master`` cannot run on this machine."""
    if master == "ecos":
        why = ecos_unavailable()
    else:
        try:
            import libcosimpy  # noqa: F401
            why = None
        except ImportError as e:
            why = f"running a system in libcosim needs libcosimpy (pip install libcosimpy): {e}"
    if why:
        pytest.skip(f"not checked on this machine: {check}: {why}")


@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return built_fmus["RailCar"].parent


def ato_parameters(system) -> dict:
    """The AtoController's parameters as the build gave them to uncovered (a packed file by name)."""
    ato = next(c for c in system.spec.components if c.name == "ato")
    return {k: str(v) if isinstance(v, PackedFile) else v for k, v in ato.parameters.items()}


# ---------------------------------------------------------------------- which ATO FMU runs

def test_auto_picks_the_native_ato_for_a_span_and_says_so(dist, tmp_path, capsys):
    system = scenario_system(NOMINAL, dist, "auto")
    assert uncovered(ATO, ato_parameters(system)) is None
    assert (system.car.kind, system.ato.kind) == ("native", "native")
    assert system.ato.path == dist / "native" / NATIVE_ATO
    assert [Path(c.fmu).name for c in system.spec.components] == ["RailCarNative.fmu", NATIVE_ATO]
    assert main(["build", str(NOMINAL), str(tmp_path / "a.ssp"), "--dist", str(dist)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == (f"fmu: ato: native {dist / 'native' / NATIVE_ATO} (--fmu auto: the C core covers "
                        f"the parameters, bit-identical to the pythonfmu FMU)")
    assert lines[0].startswith("fmu: car: native ") and lines[2] == str(tmp_path / "a.ssp")
    md = read_ssp(tmp_path / "a.ssp").models
    assert not any(m.coSimulation.needsExecutionTool for m in md.values())     # no Python anywhere


def test_python_and_native_are_what_was_asked(dist):
    python = scenario_system(NOMINAL, dist, "python")
    assert (python.car.kind, python.ato.kind) == ("python", "python")
    assert python.ato.path == dist / PYTHON_ATO
    native = scenario_system(NOMINAL, dist, "native")
    assert native.ato.path == dist / "native" / NATIVE_ATO and native.ato.why == "as asked"
    # the parameters are the same whichever FMU runs them (one variable table)
    assert python.spec.components[1].parameters.keys() == native.spec.components[1].parameters.keys()


def test_what_the_native_ato_does_not_run_goes_python_or_is_refused(dist, monkeypatch):
    """The choice is harness.run.fmus.uncovered's: a reason from it sends auto to the pythonfmu FMU,
    naming it, and refuses --fmu native at build; the car's choice is untouched."""
    said = []

    def refusing(model, parameters):
        said.append(model)
        return "span.stop = 2150.0 (a stand-in reason)" if model == ATO else uncovered(model, parameters)
    monkeypatch.setattr(scenario_module, "uncovered", refusing)
    monkeypatch.setattr("harness.run.fmus.uncovered", refusing)
    auto = scenario_system(NOMINAL, dist, "auto")
    assert ATO in said and auto.car.kind == "native"
    assert auto.ato.kind == "python" and auto.ato.path == dist / PYTHON_ATO
    assert auto.ato.why == ("ato_nominal sets span.stop = 2150.0 (a stand-in reason), which the native FMU "
                            "does not cover")
    with pytest.raises(SspError) as e:
        scenario_system(NOMINAL, dist, "native")
    assert str(e.value) == (f"{NOMINAL}: --fmu native: ato_nominal sets span.stop = 2150.0 (a stand-in "
                            f"reason), which the native {NATIVE_ATO} does not run (--fmu auto or python runs "
                            f"the pythonfmu AtoController.fmu)")


def test_a_line_goes_where_uncovered_says(dist):
    """Today the native ATO runs one span, so a line's ATO is the pythonfmu one; once it runs lines
    (harness.run.fmus.ATO_NOT_COVERED empty) the line is native, and this test holds unchanged."""
    auto = scenario_system(LINE, dist, "auto")
    params = ato_parameters(auto)
    assert params["line.profile"] == "<ato_line_line.csv, made at build>"
    why = uncovered(ATO, params)
    assert auto.car.kind == "native"
    if why is None:
        assert auto.ato.kind == "native" and scenario_system(LINE, dist, "native").ato.kind == "native"
        return
    assert "line.profile" in why
    assert auto.ato.kind == "python" and auto.ato.why == f"ato_line sets {why}, which the native FMU does not cover"
    with pytest.raises(SspError, match=r"--fmu native: ato_line sets line.profile = .* which the native "
                                       r"AtoControllerNative.fmu does not run"):
        scenario_system(LINE, dist, "native")


def test_without_the_native_ato_auto_says_so_and_native_is_refused(dist, tmp_path):
    import shutil
    (tmp_path / "native").mkdir()
    for name in ("RailCar.fmu", PYTHON_ATO, "native/RailCarNative.fmu"):
        shutil.copy(dist / name, tmp_path / name)
    missing = tmp_path / "native" / NATIVE_ATO
    auto = scenario_system(NOMINAL, tmp_path, "auto")
    assert auto.car.kind == "native" and auto.ato.kind == "python"
    assert auto.ato.why == f"no native FMU: {missing} is missing (build.py builds it with a C compiler on linux x86-64)"
    with pytest.raises(SspError) as e:
        scenario_system(NOMINAL, tmp_path, "native")
    assert str(e.value) == (f"{NOMINAL}: --fmu native: {missing} is missing (build.py builds it with a C "
                            f"compiler on linux x86-64); --fmu python runs the pythonfmu FMU")


def test_a_description_refuses_fmu_and_fmi(dist, tmp_path):
    with pytest.raises(SspError, match="a system description names its FMUs"):
        build(ROOT / "scenarios" / "systems" / "ato_span.toml", tmp_path / "x.ssp", dist, "native")


# ---------------------------------------------------------------------- three masters

@pytest.fixture(scope="module")
def nominal_jacobi(dist, tmp_path_factory) -> Path:
    return build(NOMINAL, tmp_path_factory.mktemp("native_ato") / "ato_nominal.ssp", dist, "auto", jacobi=True)


def test_the_all_native_span_gives_the_same_numbers_in_three_masters(nominal_jacobi, capsys):
    need("libcosim", "the all-native span in libcosim")
    need("ecos", "the all-native span in ecos")
    rows = compare_masters(read_ssp(nominal_jacobi), ("ours", "libcosim", "ecos"))
    ours, libcosim, ecos = rows
    assert [r.error for r in rows] == ["", "", ""]
    assert len(ours.result.time) == 1951 and len(ours.compared) == 45
    # libcosim: every output it observes (Real and Integer: all but the Booleans) the same bits
    assert len(libcosim.identical) == len(libcosim.compared) == 43 and libcosim.max_abs == 0.0
    # ecos: Integers and Booleans equal, Reals within the tolerance; it differs somewhere (the time sum)
    assert len(ecos.compared) == 45 and not ecos.integer_diffs
    assert 0.0 < ecos.max_rel <= RELATIVE_TOLERANCE, (ecos.max_rel, ecos.worst)
    position = [r.result["car.car.position"][-1] for r in rows]
    assert position[0] == position[1] and abs(position[0] - 2150.0) < 0.3
    assert main(["compare", str(nominal_jacobi), "--masters", "ours,libcosim,ecos"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "ato_nominal.ssp: 1950 steps of 0.1 s, compared with our master (harness.systems.master)"
    assert out[3].startswith("libcosim  yes       43        43    0.0e+00  0.0e+00  -")
    assert out[4].startswith("ecos      yes       45")


def test_the_native_ato_is_the_pythonfmu_ato_bit_for_bit(dist, tmp_path):
    """The ATO stepping first (the default build), in our master: both FMU kinds, every output."""
    native = run_system(build(NOMINAL, tmp_path / "n.ssp", dist, "native"))
    python = run_system(build(NOMINAL, tmp_path / "p.ssp", dist, "python"))
    assert len(native.time) == 1951 and native.signals.keys() == python.signals.keys()
    for name, x in native.signals.items():
        assert x.tobytes() == python[name].tobytes(), name


def test_the_line_gives_a_row_per_master(dist, tmp_path):
    """The line on the ATO auto picks: every master runs it (the pythonfmu ATO runs in libcosim and,
    from Python, in ecos) or says why in its row; over its first 150 s (the first span and its dwell)."""
    need("libcosim", "the line in libcosim")
    need("ecos", "the line in ecos")
    ssp = build(LINE, tmp_path / "line.ssp", dist, "auto", jacobi=True)
    rows = compare_masters(read_ssp(ssp), ("ours", "libcosim", "ecos"), stop_time=150.0)
    assert [r.error for r in rows] == ["", "", ""]
    assert len(rows[1].identical) == len(rows[1].compared) == 43
    assert not rows[2].integer_diffs and rows[2].max_rel <= RELATIVE_TOLERANCE, (rows[2].max_rel, rows[2].worst)


THREE_TOLERANCE = 1e-9
"""ecos against ours on the three-FMU loop: measured 2.2e-11 (car.car.traction_force, 1500 steps: the
separate estimator and the ATO both use ecos's summed time, and the demand carries it into the car);
1e-9 is 45 times that and 500 times tighter than ecos's printed 6 decimals."""


def test_the_three_native_fmus_wired_as_a_tool_would_run_in_three_masters(dist, tmp_path):
    """scenarios/systems/ato_three_native.toml (docs/using_fmus.md, "A Modelica user's path"):
    RailCarNative -> RailCarEstimatorNative -> AtoControllerNative -> RailCarNative stops the car at
    the mark in our master; libcosim gives the same bits, ecos our numbers within THREE_TOLERANCE."""
    from harness.systems.ato_run import system_ato_metrics
    from harness.systems.cli import build_system
    ssp = build_system(ROOT / "scenarios" / "systems" / "ato_three_native.toml", tmp_path / "three.ssp", dist)
    system = read_ssp(ssp)
    assert [Path(c.fmu).name for c in system.spec.components] == ["RailCarNative.fmu", "RailCarEstimatorNative.fmu",
                                                                  NATIVE_ATO]
    ours = run_system(system)
    [m] = system_ato_metrics(system, ours)
    assert abs(m.stop_error_m) <= 0.3 and abs(m.arrival_error_s) <= 2.5 and m.interventions == 0, m
    need("libcosim", "the three native FMUs in libcosim")
    need("ecos", "the three native FMUs in ecos")
    _, libcosim, ecos = compare_masters(system, ("ours", "libcosim", "ecos"))
    assert libcosim.error == "" and len(libcosim.identical) == len(libcosim.compared) == 63
    assert ecos.error == "" and len(ecos.compared) == 65 and not ecos.integer_diffs
    assert ecos.max_rel <= THREE_TOLERANCE, (ecos.max_rel, ecos.worst)


# ---------------------------------------------------------------------- FMI 3

def test_fmi3_runs_the_fmi3_natives_or_says_which_is_missing(dist, tmp_path):
    """With AtoControllerNative3.fmu in the build: the span on the FMI 3.0 natives gives the FMI 2
    system's bits in our master and our numbers in ecos (libcosim refuses FMI 3 in its row). Without
    it: the build names the missing file."""
    ato3 = dist / "native" / "AtoControllerNative3.fmu"
    if not ato3.is_file():
        with pytest.raises(SspError) as e:
            build(NOMINAL, tmp_path / "a3.ssp", dist, "auto", jacobi=True, fmi=3)
        assert str(e.value) == (f"--fmi 3: {ato3} is missing (build.py builds the FMI 3.0 natives it can; "
                                f"--fmi 2 runs the FMI 2.0 FMUs)")
        return
    system3 = scenario_system(NOMINAL, dist, "auto", jacobi=True, fmi=3)
    assert [Path(c.fmu).name for c in system3.spec.components] == ["RailCarNative3.fmu", ato3.name]
    ssp3 = build(NOMINAL, tmp_path / "a3.ssp", dist, "auto", jacobi=True, fmi=3)
    ssp2 = build(NOMINAL, tmp_path / "a2.ssp", dist, "auto", jacobi=True)
    ours3, ours2 = run_system(ssp3, stop_time=60.0), run_system(ssp2, stop_time=60.0)
    for name, x in ours2.signals.items():
        assert x.tobytes() == ours3[name].tobytes(), name
    need("ecos", "the FMI 3 span in ecos")
    ours, libcosim, ecos = compare_masters(read_ssp(ssp3), ("ours", "libcosim", "ecos"), stop_time=60.0)
    assert libcosim.refused and "FMI 3.0 FMU; libcosim 0.11 runs FMI 2.0 only" in libcosim.error
    assert ecos.error == "" and not ecos.integer_diffs and ecos.max_rel <= RELATIVE_TOLERANCE


def test_fmi3_refuses_what_has_no_fmi3_fmu(dist, tmp_path):
    with pytest.raises(SspError, match=r"--fmi 3 --fmu python: the pythonfmu RailCar.fmu is FMI 2.0 only"):
        scenario_system(NOMINAL, dist, "python", fmi=3)
    with pytest.raises(SspError, match=r"--fmi 5: expected one of 2, 3"):
        scenario_system(NOMINAL, dist, "auto", fmi=5)

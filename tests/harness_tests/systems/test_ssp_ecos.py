"""Our SSP packages in ecos (harness.systems.ecos), a third, independent C++ master, against our own
master (harness.systems.master; libcosim gives its numbers bit for bit, test_ssp_master.py):

- the library's plant + estimator system (scenarios/systems/plant_estimator.toml, built by our
  builder on the native RailCar and RailCarEstimator, FMI 2; and the same on the FMI 3 natives)
  runs in ecos with every parameter set applied (each parameter read back through ecos has the
  package's bits; the car climbs 350 m; with no set applied the runner says which parameter is
  not) and gives our numbers: every Integer the same, every Real within RELATIVE_TOLERANCE; the
  car's outputs have the same bits;
- RailCar <-> the pythonfmu AtoController (scenarios/systems/ato_span.toml) runs too (its Boolean
  ato.finished observed, which libcosim cannot) and stops the car at the mark as in ours;
- what ecos would run wrongly or silently is refused or reported: parameter sets of several names,
  a step order, a start time other than 0; a step an FMU discards and an initialisation an FMU
  fails (ecos ignores both statuses) are MasterErrors naming the component, where, and the
  FMU's message; FMI 3 String parameters, which ecos 0.7.2 cannot read back, are named in
  EcosResult.limits;
- without ecospy or libtbb12 the runner says which to install; ``system compare`` prints the three
  masters' table.

Where ecos cannot run on this machine (ecospy or libtbb12 missing), each test that needs it is
skipped with a reason naming its check and what to install (.ci/run installs both, so CI runs them).

The tolerance. ecos prints 6 decimals in its CSV, but harness.systems.ecos reads every value as a
double through ecospy, so the comparison is far tighter than that. The two masters differ in one
thing only: ecos gives doStep the time as a running sum of the step (0.30000000000000004 at the
third step), ours and libcosim k * 10^8 ns / 10^9 (0.3). Components that use the time they are
given (the separate RailCarEstimator, the AtoController's schedule) differ in the last bits; the
largest relative difference measured is 3.6e-14 (ato_span, 500 steps) and 3.0e-14 (plant_estimator,
300 steps). RELATIVE_TOLERANCE = 1e-11 is 300 times that, and 50 000 times tighter than ecos's
printed digits (5e-7 on a value near 1), so a parameter not applied or a connection carried a
step late fails it.
"""
from __future__ import annotations

import builtins
import sys
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from harness.systems.cli import build, build_system, compare_masters, load_system, main
from harness.systems.ecos import EcosMissing, ecos_unavailable, run_ecos
from harness.systems.master import MasterError, run_system
from harness.systems.ssp import PARAMETER_SET, SspError, write_ssp
from harness.systems.ssp_read import read_ssp

SYSTEMS = ROOT / "scenarios" / "systems"
RELATIVE_TOLERANCE = 1e-11          # |ecos - ours| / max(1, |ours|); the module's text says why
WHY_NOT = ecos_unavailable()


def need_ecos(check: str) -> None:
    """Skip, naming ``check`` and what is missing, where ecos cannot run on this machine."""
    if WHY_NOT:
        pytest.skip(f"not checked on this machine: {check}: {WHY_NOT}")


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def assert_close(ours, ecos, exact_prefix: str | None = None) -> None:
    """Every output of ``ecos`` is in ``ours``: Integers and Booleans equal, Reals within
    RELATIVE_TOLERANCE; those starting with ``exact_prefix`` with the same bits."""
    assert np.array_equal(ours.time, ecos.time)
    assert len(ecos.signals) >= 20
    for name, y in ecos.signals.items():
        x = ours[name]
        assert ecos.units[name] == ours.units[name], name
        if y.dtype.kind != "f":
            assert y.dtype == x.dtype and np.array_equal(x, y), name
            continue
        rel = np.abs(x - y) / np.maximum(1.0, np.abs(x))
        k = int(np.argmax(rel))
        assert rel[k] <= RELATIVE_TOLERANCE, f"{name} at t = {ours.time[k]} s: ours {x[k]!r}, ecos {y[k]!r}"
        if exact_prefix and name.startswith(exact_prefix):
            assert np.array_equal(bits(x), bits(y)), name


@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return built_fmus["RailCar"].parent


@pytest.fixture(scope="module")
def pe(dist, tmp_path_factory) -> Path:
    """The library's plant_estimator system, as our builder makes it (FMI 2 natives)."""
    return build_system(SYSTEMS / "plant_estimator.toml", tmp_path_factory.mktemp("ecos") / "pe.ssp", dist)


@pytest.fixture(scope="module")
def pe3(dist, tmp_path_factory) -> Path:
    """The same system on the FMI 3 natives."""
    spec = load_system(SYSTEMS / "plant_estimator.toml", dist)
    comps = [replace(c, fmu=Path(str(c.fmu).replace(".fmu", "3.fmu"))) for c in spec.components]
    return write_ssp(replace(spec, components=comps), tmp_path_factory.mktemp("ecos3") / "pe3.ssp")


@pytest.fixture(scope="module")
def pe_runs(pe):
    need_ecos("plant_estimator (FMI 2) in ecos")
    return run_system(pe), run_ecos(pe)


# ---------------------------------------------------------------------- the package's layout

def test_every_parameter_set_has_the_one_name_ecos_is_told(pe):
    """Each component's .ssv is bound to it (ours and libcosim) and named PARAMETER_SET (ecos
    gathers sets by name); read_ssp keeps the names."""
    with zipfile.ZipFile(pe) as z:
        for member in ("resources/car.ssv", "resources/est.ssv"):
            assert f'name="{PARAMETER_SET}"' in z.read(member).decode()
    assert PARAMETER_SET == "start_values"
    assert read_ssp(pe).parameter_sets == {"car": PARAMETER_SET, "est": PARAMETER_SET}


def _renamed(ssp: Path, dest: Path, member: str, name: str) -> Path:
    with zipfile.ZipFile(ssp) as src, zipfile.ZipFile(dest, "w") as out:
        for item in src.namelist():
            data = src.read(item)
            if item == member:
                data = data.replace(f'name="{PARAMETER_SET}"'.encode(), f'name="{name}"'.encode())
            out.writestr(item, data)
    return dest


def test_sets_of_several_names_are_refused_before_ecos_runs(pe, tmp_path):
    """A package written before the sets had one name (each named after its component): ecos would
    apply one and run the other component on its start values; refused, saying so. Ours still
    reads and runs it (it applies each bound set whatever its name)."""
    old = _renamed(_renamed(pe, tmp_path / "a.ssp", "resources/car.ssv", "car"), tmp_path / "old.ssp",
                   "resources/est.ssv", "est")
    with pytest.raises(SspError, match=r"old.ssp: the components' parameter sets have different names "
                                       r"\(car: 'car', est: 'est'\); ecos applies one named set to the "
                                       r"whole system.*rebuild the package"):
        run_ecos(old, n_steps=2)
    assert run_system(old, n_steps=2)["car.car.position"][-1] > 0.0


# -------------------------------------------------------------------- the numbers, FMI 2 and 3

def test_plant_estimator_in_ecos_gives_our_numbers(pe_runs):
    ours, ecos = pe_runs
    assert ecos.master == "ecos" and len(ecos.time) == 301 and ecos.limits == []
    assert set(ecos.signals) == set(ours.signals)            # no Boolean output here: all observed
    # RailCar samples on its own clock: its outputs have the same bits; the estimator's within
    # the tolerance, and not all the same bits (the time ecos gives it differs)
    assert_close(ours, ecos, exact_prefix="car.")
    assert not all(np.array_equal(bits(ours[n]), bits(ecos[n])) for n in ecos.signals if n.startswith("est."))
    # ecos's own clock is the running sum of the step
    assert ecos.ecos_time[3] == 0.1 + 0.1 + 0.1 != ours.time[3]


def test_the_parameter_sets_were_applied_and_the_car_moves(pe, pe_runs):
    """The package's car (36 t, 30 kN up the demo grade) climbs 351 m in 30 s in both; with the
    set not applied (as in ecos told no set name) the runner stops on the first parameter the
    FMU does not have."""
    ours, ecos = pe_runs
    assert ecos["car.car.position"][-1] == ours["car.car.position"][-1]
    assert 350.0 < ecos["car.car.position"][-1] < 352.0
    assert np.max(ecos["car.car.traction_force"]) == 30e3        # the demand, until power limits it
    assert 35.0 < ecos["est.est.mass"][-1] < 36.0                    # from its 30 t prior towards 36 t
    unapplied = read_ssp(pe)
    unapplied.parameter_sets = {}                 # ecos then applies no set
    with pytest.raises(MasterError, match=r"plant_estimator: ecos did not apply the parameter car.car.mass: "
                                          r"the package says 36.0, the FMU has 30.0 after initialisation"):
        run_ecos(unapplied, n_steps=2)


def test_fmi3_natives_in_ecos_give_our_numbers(pe, pe3):
    """ecos loads our FMI 3 FMUs and gives the FMI 2 system's numbers in ours; it cannot read an
    FMI 3 String back, which the result names."""
    need_ecos("plant_estimator (FMI 3) in ecos")
    ours, ecos3 = run_system(pe), run_ecos(pe3)
    assert_close(ours, ecos3, exact_prefix="car.")
    assert ecos3.limits == ["component 'car' (FMI 3): String parameters track.grade_profile set but not "
                            "read back (ecos 0.7.2 reads an FMI 3 String as '')"]


def test_the_pythonfmu_ato_runs_in_ecos_and_stops_the_car(dist, tmp_path):
    """RailCar <-> the pythonfmu AtoController runs in ecos from Python (ecos's CLI, a program
    without Python, crashes on it with no message): our numbers, the Boolean ato.finished
    included, and the car at the mark."""
    need_ecos("ato_span (pythonfmu AtoController) in ecos")
    ssp = build_system(SYSTEMS / "ato_span.toml", tmp_path / "ato.ssp", dist)
    ours, ecos = run_system(ssp), run_ecos(ssp)
    assert_close(ours, ecos)
    finished = ecos["ato.ato.finished"]
    assert finished.dtype == bool and finished.any() and finished[np.argmax(finished):].all()
    assert abs(ecos["car.car.position"][-1] - 400.0) < 0.5 and ecos["car.car.speed"][-1] == 0.0


# ------------------------------------------------------------------ what ecos would do silently

def _pe_with(dist, tmp_path, name: str, suffix: str = "", **car) -> Path:
    spec = load_system(SYSTEMS / "plant_estimator.toml", dist)
    comps = [replace(c, fmu=Path(str(c.fmu).replace(".fmu", f"{suffix}.fmu")),
                     parameters=dict(c.parameters, **car) if c.name == "car" else c.parameters)
             for c in spec.components]
    return write_ssp(replace(spec, components=comps), tmp_path / name)


def test_a_discarded_step_is_an_error_not_a_silent_run(dist, tmp_path):
    need_ecos("a discarded step in ecos")
    ssp = _pe_with(dist, tmp_path, "discard.ssp", traction_force_demand=-5.0)
    with pytest.raises(MasterError) as e:
        run_ecos(ssp, n_steps=5)
    assert e.value.message == ("plant_estimator: component 'car': discard at step 1 (t = 0.0 s) in ecos (ecos "
                               "ignores the status its FMUs return and would have run on): step discarded: "
                               "traction_force_demand must be finite and >= 0 [N], got -5.0")


@pytest.mark.parametrize("suffix", ["", "3"], ids=["fmi2", "fmi3"])
def test_a_failed_initialisation_is_an_error_not_a_silent_run(dist, tmp_path, suffix):
    need_ecos(f"a failed initialisation in ecos (FMI {suffix or '2'})")
    ssp = _pe_with(dist, tmp_path, "init.ssp", suffix, **{"car.mass": -1.0})
    with pytest.raises(MasterError) as e:
        run_ecos(ssp, n_steps=5)
    api = "fmi3" if suffix else "fmi2"
    assert e.value.message == (f"plant_estimator: component 'car': error in initialisation in ecos (ecos "
                               f"ignores the status its FMUs return and would have run on): "
                               f"{api}ExitInitializationMode: initialisation failed: car.mass must be > 0, got -1.0")


def test_what_ecos_would_run_wrongly_is_refused(dist, pe, tmp_path):
    """A step order (ecos steps Jacobi) and a start time other than 0 (ecos's clock starts at 0):
    refused before ecos is asked, so these need no ecos."""
    ordered = build(ROOT / "scenarios" / "library" / "ato_nominal.toml", tmp_path / "ordered.ssp", dist, "native")
    with pytest.raises(SspError, match=r"steps its components in an order \(ato then car, Gauss-Seidel\); "
                                       r"ecos steps them all at once \(Jacobi\)"):
        run_ecos(ordered, n_steps=2)
    late = read_ssp(pe)
    late.spec = replace(late.spec, start=1.0)
    with pytest.raises(SspError, match=r"start time 1.0 s: ecos 0.7.2 counts its clock from 0"):
        run_ecos(late, n_steps=2)


def test_without_ecospy_or_libtbb_the_runner_says_what_to_install(pe, monkeypatch):
    monkeypatch.setitem(sys.modules, "ecospy", None)           # as if not installed
    assert "pip install ecospy==0.7.2" in ecos_unavailable()
    with pytest.raises(EcosMissing, match="running a system in ecos needs ecospy 0.7.2"):
        run_ecos(pe, n_steps=2)
    monkeypatch.delitem(sys.modules, "ecospy")
    real_import = builtins.__import__

    def no_tbb(name, *args, **kwargs):
        if name == "ecospy":                       # what ctypes raises when libtbb12 is missing
            raise OSError("libtbb.so.12: cannot open shared object file: No such file or directory")
        return real_import(name, *args, **kwargs)
    monkeypatch.setattr(builtins, "__import__", no_tbb)
    assert ecos_unavailable() == ("ecospy is installed but its library cannot be loaded (install Debian's "
                                  "libtbb12: apt-get install libtbb12): libtbb.so.12: cannot open shared "
                                  "object file: No such file or directory")


# ------------------------------------------------------------------------- the command line

def test_compare_prints_the_three_masters(pe, capsys):
    need_ecos("system compare with ecos")
    rows = compare_masters(read_ssp(pe), ("ours", "libcosim", "ecos"), stop_time=3.0)
    assert [r.master for r in rows] == ["ours", "libcosim", "ecos"]
    assert len(rows[1].identical) == len(rows[1].compared) >= 50          # libcosim: the same bits
    assert 0.0 < rows[2].max_rel <= RELATIVE_TOLERANCE and not rows[2].integer_diffs
    assert main(["compare", str(pe), "--stop", "3"]) == 0
    out = capsys.readouterr().out
    assert "pe.ssp: 30 steps of 0.1 s, compared with our master" in out
    assert out.splitlines()[3].startswith("libcosim  yes       54        54    0.0e+00  0.0e+00  -")
    assert out.splitlines()[4].startswith("ecos      yes       54")
    assert main(["run", str(pe), "--master", "ecos", "--stop", "3", "--output", "car.car.position"]) == 0
    assert "ecos: 30 steps to t = 3.0 s" in capsys.readouterr().out


def test_compare_names_a_master_that_refuses(pe3, capsys):
    need_ecos("system compare with ecos (FMI 3)")
    assert main(["compare", str(pe3), "--stop", "1"]) == 0                 # a refusal is a limit
    out = capsys.readouterr().out
    assert "libcosim  no: " in out and "is an FMI 3.0 FMU; libcosim 0.11 runs FMI 2.0 only" in out
    assert "ecos: component 'car' (FMI 3): String parameters track.grade_profile set but not read back" in out


def test_the_pythonfmu_ato_refusing_its_parameters_is_an_error(dist, tmp_path):
    """An infeasible schedule: the AtoController fails exitInitializationMode, which ecos ignores;
    the runner stops on the FMU's message."""
    need_ecos("a pythonfmu FMU failing initialisation in ecos")
    spec = load_system(SYSTEMS / "ato_span.toml", dist)
    comps = [replace(c, parameters=dict(c.parameters, **{"span.schedule": 5.0})) if c.name == "ato" else c
             for c in spec.components]
    ssp = write_ssp(replace(spec, components=comps), tmp_path / "bad_ato.ssp")
    with pytest.raises(MasterError, match=r"ato_span: component 'ato': error in initialisation in ecos .*"
                                          r"span.schedule = 5.00 s is infeasible"):
        run_ecos(ssp, n_steps=3)


def test_a_crash_of_ecos_s_process_is_an_error_naming_the_signal(pe, tmp_path, monkeypatch):
    """ecos's process dying on a signal (as its CLI does on a pythonfmu FMU: exit 139, no word) is a
    MasterError, never an empty result: here a stand-in for the child that kills itself."""
    need_ecos("a crash of ecos's process")
    crash = tmp_path / "crash.sh"
    crash.write_text("#!/bin/sh\necho '[2026-01-01 00:00:00.000] [ecos] [debug] Loading SSP'\nkill -SEGV $$\n")
    crash.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(crash))
    with pytest.raises(MasterError) as e:
        run_ecos(pe, n_steps=2)
    assert e.value.message == "plant_estimator: ecos's process was killed by SIGSEGV loading the package"
    assert e.value.log == ["[2026-01-01 00:00:00.000] [ecos] [debug] Loading SSP"]

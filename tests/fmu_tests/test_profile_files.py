"""Issue 29, "Every FMU": a profile parameter must name a regular file of at most
fmu_src.adapter.PROFILE_MAX_BYTES. A FIFO (whose opening waited for ever), a device (/dev/zero:
"out of memory", no name), a folder and a file over the bound are refused at
exitInitializationMode, naming the parameter, the file and why, in the same words by the
pythonfmu FMUs and the native ones (tests/fmu_tests/test_native_fmu.py compares those, with
this module's ``unfit`` files and ``fifo_released``).
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import ERROR, OK, FmuFile, Slave, fifo_released
from fmu_src.adapter import PROFILE_MAX_BYTES

BOUND_TEXT = "16777216 bytes (16 MiB)"




@pytest.fixture(scope="module")
def unfit(tmp_path_factory) -> dict[str, tuple[str, str]]:
    """name -> (absolute path, why the FMU refuses it); the big file is sparse (nothing written)."""
    tmp = tmp_path_factory.mktemp("unfit_profiles")
    os.mkfifo(tmp / "fifo.csv")
    (tmp / "folder").mkdir()
    with open(tmp / "too_big.csv", "wb") as f:
        f.truncate(PROFILE_MAX_BYTES + 1)
    return {"fifo": (str(tmp / "fifo.csv"), "it is a FIFO, not a regular file"),
            "zero": ("/dev/zero", "it is a device, not a regular file"),
            "folder": (str(tmp / "folder"), "it is a folder, not a regular file"),
            "too_big": (str(tmp / "too_big.csv"),
                        f"it has {PROFILE_MAX_BYTES + 1} bytes, more than the {BOUND_TEXT} a profile "
                        f"may have")}


def _refusal(fmu: FmuFile, parameters: dict, fifo: Path) -> str:
    """exitInitializationMode's error message (after "initialisation failed: "); the instance
    must then reset and initialise well."""
    with fifo_released(fifo) as opened, Slave(fmu, "unfit") as s:
        s.setup(parameters)
        status = s.exit_init()
        errors = [m.message for m in s.messages if m.status == ERROR]
        assert s.reset() == OK
        s.initialize({})
    assert opened == [], f"{fmu.name} opened the FIFO"
    assert status == ERROR and errors, (fmu.name, status, s.log_text())
    return errors[0].split("initialisation failed: ", 1)[-1].splitlines()[0]


@pytest.mark.parametrize("case", ["fifo", "zero", "folder", "too_big"])
@pytest.mark.parametrize("fmu, param", [("RailCar", "track.grade_profile"),
                                        ("RailCar", "track.speed_profile"),
                                        ("RailCarEstimator", "track.grade_profile")])
def test_railcar_and_the_estimator_refuse_it_naming_the_parameter(fmus, unfit, fmu, param, case):
    """(the native FMUs' same words: tests/fmu_tests/test_native_fmu.py)"""
    path, why = unfit[case]
    message = _refusal(fmus[fmu], {param: path}, Path(unfit["fifo"][0]))
    assert message == f"{param}: cannot read '{path}' (looked for {path}): {why}"


@pytest.mark.parametrize("case", ["fifo", "zero", "folder", "too_big"])
@pytest.mark.parametrize("param", ["span.grade_profile", "span.speed_limit_profile"])
def test_the_ato_controller_refuses_it_naming_the_parameter(fmus, unfit, param, case):
    path, why = unfit[case]
    message = _refusal(fmus["AtoController"], {param: path}, Path(unfit["fifo"][0]))
    assert message == f"{param}: cannot read '{path}' (looked for {path}): {why}"

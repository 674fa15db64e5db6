"""Build every FMU into one folder and validate each: what ``python build.py`` runs.

    python build.py [--dest dist] [--pythonfmu-binary] [--no-native]

1. our FMI 2 binary for the pythonfmu FMUs (``pythonfmu_fmus.compile_binary``; without a C
   compiler, or with ``--pythonfmu-binary``, pythonfmu's binary stays, with a loud warning);
2. the pythonfmu FMUs ``DEST/RailCar.fmu``, ``DEST/RailCarEstimator.fmu``,
   ``DEST/AtoController.fmu`` (``pythonfmu_fmus.build_pythonfmu``);
3. with our binary and unless ``--no-native``: the native FMUs (no Python at run time,
   docs/native_fmus.md) into ``DEST/native/``: RailCarNative.fmu, RailCarEstimatorNative.fmu and
   AtoControllerNative.fmu (FMI 2.0, ``native``), RailCarNative3.fmu, RailCarEstimatorNative3.fmu and
   AtoControllerNative3.fmu (FMI 3.0, ``native_fmi3``), each with binaries for every platform of ``toolchain.TARGETS`` whose
   compiler this machine has (linux x86-64, Windows x86-64 with mingw-w64, linux aarch64 with
   gcc-aarch64-linux-gnu); a missing compiler is printed as a SKIPPED platform.

The build fails (exit code 1) unless ``fmpy.validation.validate_fmu`` reports no problem for
every FMU; one line per FMU says what was built.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from fmu_src.variables import ATO, ESTIMATOR, RAILCAR

from .toolchain import ROOT, warn

PYTHONFMU_FMUS = (RAILCAR, ESTIMATOR, ATO)


def validate(path: Path) -> list[str]:
    """fmpy's validation of the FMU: its problems, none when it is good."""
    from fmpy.validation import validate_fmu
    return list(validate_fmu(str(path)))


def binary_folders(path: Path) -> list[str]:
    """The binaries/ folders of the FMU at ``path``: its platforms."""
    import zipfile
    with zipfile.ZipFile(path) as z:
        return sorted({n.split("/")[1] for n in z.namelist()
                       if n.startswith("binaries/") and n.count("/") == 2 and not n.endswith("/")})


def report(path: Path, problems: list[str], what: str) -> bool:
    """Print the FMU's validation; True when it has no problem."""
    if problems:
        print(f"{path}: fmpy.validation found {len(problems)} problem(s):")
        for p in problems:
            print(f"  - {p}")
        return False
    print(f"built {path} (validate_fmu: no problems; {what})")
    return True


def build_all(dest: Path, pythonfmu_binary: bool = False, native: bool = True) -> bool:
    """Build and validate every FMU into ``dest`` (see the module); True when all are good."""
    from . import native_fmi3, pythonfmu_fmus
    from . import native as native_fmi2
    good = True
    with tempfile.TemporaryDirectory() as tmp:
        if pythonfmu_binary:
            warn("--pythonfmu-binary: the FMUs keep pythonfmu's linux64 binary (fmi2Fatal on any "
                 "Python exception; the host crashes when such an instance is freed)")
            binary = None
        else:
            binary = pythonfmu_fmus.compile_binary(Path(tmp))
        which = ("our FMI 2 binary (fmu_src/c)" if binary is not None
                 else "pythonfmu's binary (WARNING: see above)")
        built = {}
        for name in PYTHONFMU_FMUS:
            path = built[name] = pythonfmu_fmus.build_pythonfmu(name, dest, binary)
            good &= report(path, validate(path), f"linux64: {which}")
        if binary is not None and native:
            native_dir = dest / "native"
            for path in (native_fmi2.build_native_fmu(native_dir, built[RAILCAR]),
                         native_fmi2.build_native_estimator_fmu(native_dir, built[ESTIMATOR]),
                         native_fmi2.build_native_ato(native_dir, built[ATO]),
                         native_fmi3.build_native3_fmu(native_dir, built[RAILCAR]),
                         native_fmi3.build_native3_estimator_fmu(native_dir, built[ESTIMATOR]),
                         native_fmi3.build_native_ato3(native_dir, built[ATO])):
                good &= report(path, validate(path),
                               f"native, no Python at run time: {', '.join(binary_folders(path))}")
    return good


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description="Build dist/RailCar.fmu, dist/RailCarEstimator.fmu, dist/AtoController.fmu "
                    "and the native FMUs; validate them.")
    ap.add_argument("--dest", default=str(ROOT / "dist"), help="output folder (default: dist/)")
    ap.add_argument("--pythonfmu-binary", action="store_true",
                    help="keep pythonfmu's linux64 binary instead of compiling ours (for comparisons)")
    ap.add_argument("--no-native", action="store_true",
                    help="skip the native FMUs (dist/native/, built from the C model core)")
    args = ap.parse_args(argv)
    try:
        good = build_all(Path(args.dest), args.pythonfmu_binary, native=not args.no_native)
    except RuntimeError as e:          # a compiler or pythonfmu failure: its message, exit code 1
        raise SystemExit(str(e)) from None
    return 0 if good else 1

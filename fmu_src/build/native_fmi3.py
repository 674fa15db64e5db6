"""The native RailCar, RailCarEstimator (issue 18) and AtoController (issue 30) FMUs for FMI 3.0
co-simulation: the C core, no Python.

    python -m fmu_src.build.native_fmi3 DEST     build DEST/RailCarNative3.fmu,
                                                 DEST/RailCarEstimatorNative3.fmu and
                                                 DEST/AtoControllerNative3.fmu

RailCar and RailCarEstimator are each one ``native.NativeSpec`` (RAILCAR_SPEC, ESTIMATOR_SPEC;
default RailCar); the AtoController (``build_native_ato3``) is the FMI 2 AtoControllerNative's
backend ``fmu_src/c/native_ato.c`` (``native.ato_c_sources``) behind the same FMI 3 glue, with
FMU states as the other two (that backend saves and restores the whole controller). A binary
is the FMI 2 native FMU's backend (``fmu_src/c/native_railcar.c`` or ``native_estimator.c`` and
what it needs, as ``native.c_sources(spec)`` lists them) and ``models/core/*.c`` behind the FMI
3.0 glue ``fmu_src/c/fmi3_glue.c`` instead of ``fmi2_glue.c``: the backend links unchanged.

``modelDescription.xml`` is ``model_description.fmi3``: the variables of ``RailCar.fmu`` /
``RailCarEstimator.fmu`` with the same names and value references, and the independent "time"
after them. Outputs are ``initial="calculated"``: set in fmi3ExitInitializationMode (RailCar's
chain computes them, RailCarEstimator's hold the table's start values until the first step, as
the FMI 2 FMUs do). The binaries are ``binaries/<platform tuple>/<modelIdentifier>.so|.dll``
for each platform of ``toolchain.TARGETS`` this machine has a compiler for (x86_64-linux,
x86_64-windows, aarch64-linux; the others are skipped with a printed message); ``sources/``
holds the C sources with an FMI 3 ``sources/buildDescription.xml`` and every header they need:
the FMI 3 headers of the glue and the FMI 2 headers the backend's types come from, so that
``sources/`` compiles alone. ``documentation/index.html`` lists the platforms.
"""
from __future__ import annotations

import hashlib
import sys
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from fmu_src.variables import ATO, variables_for

from . import model_description, native
from .native import ESTIMATOR_SPEC, RAILCAR_SPEC, NativeSpec
from .toolchain import C_DIR, LINUX_X86_64, Target, fmi_headers

GENERATION_TOOL = "fmu_src/build/native_fmi3.py (C core, no Python)"
SPECS = (RAILCAR_SPEC, ESTIMATOR_SPEC)
PLATFORM = LINUX_X86_64.tuple
GLUE3_SOURCE, GLUE3_HEADER = "fmi3_glue.c", "fmi3_glue.h"
FMI3_HEADERS = ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")
ATO_NATIVE3_NAME = f"{native.ATO_NATIVE_NAME}3"


def native3_name(spec: NativeSpec = RAILCAR_SPEC) -> str:
    """RailCarNative3, RailCarEstimatorNative3: the FMI 2 native FMU's name + 3."""
    return f"{spec.native_name}3"


def c_sources(spec: NativeSpec = RAILCAR_SPEC) -> list[Path]:
    """The FMI 3 glue, then the native backend's sources without the FMI 2 glue, then the core."""
    backend = [p for p in native.c_sources(spec) if p.name != "fmi2_glue.c"]
    return [C_DIR / GLUE3_SOURCE, *backend]


def c_headers(spec: NativeSpec = RAILCAR_SPEC) -> list[Path]:
    """The FMI 3 glue's header, the FMI 2 FMU's headers (fmi2_glue.h and the FMI 2 headers stay:
    they are the backend interface) and the FMI 3 headers of the glue."""
    return [C_DIR / GLUE3_HEADER, *native.c_headers(spec),
            *[fmi_headers() / h for h in FMI3_HEADERS]]


def compile_binary(out: Path, spec: NativeSpec = RAILCAR_SPEC,
                   target: Target = LINUX_X86_64) -> Path:
    """The FMI 3 binary of ``spec`` for ``target``; RuntimeError with the compiler's output."""
    return native.compile_for(target, c_sources(spec), out,
                              f"the FMI 3 native FMU {native3_name(spec)}")


def instantiation_token(spec: NativeSpec = RAILCAR_SPEC) -> str:
    """Derived from the variable table and every source (same sources => same token)."""
    return _token(native3_name(spec), spec.fmu, [*c_sources(spec), *c_headers(spec)])


def _token(native_name: str, fmu: str, files: list[Path]) -> str:
    h = hashlib.sha256(f"{native_name}|fmi3|".encode())
    for v in variables_for(fmu):
        h.update(repr((v.name, v.causality, v.type, v.unit, v.start, v.min, v.max)).encode())
    for p in files:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def model_description_xml(token: str, spec: NativeSpec = RAILCAR_SPEC) -> bytes:
    """The FMI 3.0 modelDescription.xml of RailCarNative3.fmu (or ``spec``'s FMU)."""
    return model_description.fmi3(spec.fmu, token, GENERATION_TOOL)


def build_description(spec: NativeSpec = RAILCAR_SPEC) -> bytes:
    """sources/buildDescription.xml (FMI 3.0): one configuration, every .c file, the flat
    sources/ folder as the include directory, no preprocessor definitions, the libraries."""
    return _build_description(spec.fmu, c_sources(spec))


def _build_description(fmu: str, sources: list[Path]) -> bytes:
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    conf = ET.SubElement(root, "BuildConfiguration", modelIdentifier=fmu,
                         description="C99, no preprocessor definitions; link with -lm, and "
                                     "-pthread on POSIX systems (Windows: no thread library)")
    # compilerOptions: an attribute of SourceFileSet in the FMI 3.0 standard's
    # fmi3BuildDescription.xsd (fmpy/schema/fmi3/). -ffp-contract=off keeps a*b+c unfused, as
    # bit-identity with the Python reference needs; the core's .c files also turn contraction
    # off themselves (rc_fp_contract.h), for importers that drop the option.
    files = ET.SubElement(conf, "SourceFileSet", language="C99",
                          compilerOptions="-ffp-contract=off")
    for src in sources:
        ET.SubElement(files, "SourceFile", name=src.name)
    ET.SubElement(files, "IncludeDirectory", name=".")     # relative to sources/
    ET.SubElement(conf, "Library", name="m", description="the C maths library (libm)")
    ET.SubElement(conf, "Library", name="pthread",
                  description="POSIX threads (the instance registry's lock); not on Windows, "
                              "where the glue uses a Win32 SRW lock")
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def build_native3(spec: NativeSpec, dest_dir, python_fmu=None, targets=None) -> Path:
    """Compile and zip ``dest_dir/<spec.native_name>3.fmu``. ``python_fmu`` (the pythonfmu FMU
    of ``spec.fmu``, default dist/'s via fmu_src.build.dist.current_pythonfmu) only supplies the
    profiles under resources/; ``targets``: the platforms (default: those this machine has a
    compiler for, the others printed). Refuses to build when the backend's table header is out
    of date."""
    targets, python_fmu = native.build_inputs(spec, native3_name(spec), python_fmu, targets)
    files = [*c_sources(spec), *c_headers(spec)]
    xml = model_description_xml(instantiation_token(spec), spec)
    return _write_fmu3(dest_dir, native3_name(spec), spec.fmu, xml, c_sources(spec), files,
                       python_fmu, targets)


def _write_fmu3(dest_dir, native_name: str, fmu: str, xml: bytes, sources: list[Path],
                files: list[Path], python_fmu, targets) -> Path:
    """Compile ``sources`` for each of ``targets`` and zip ``dest_dir/<native_name>.fmu``: the
    description ``xml``, the binaries, the platforms page, ``files`` and buildDescription.xml
    under sources/, the pythonfmu FMU's profiles under resources/."""
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    target = dest / f"{native_name}.fmu"
    names = [p.name for p in files]
    assert len(set(names)) == len(names), "two C files of the same name: sources/ is flat"
    with tempfile.TemporaryDirectory() as tmp:
        binaries = native.compile_platforms(targets, sources, Path(tmp),
                                            lambda t: f"binaries/{t.tuple}/{fmu}{t.extension}",
                                            f"the FMI 3 native FMU {native_name}")
        _, profiles = native.read_pythonfmu(python_fmu, fmu)
        tmp_fmu = Path(tmp) / target.name
        with zipfile.ZipFile(tmp_fmu, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", xml)
            for name, binary in binaries.items():
                z.writestr(name, binary.read_bytes())
            z.writestr("documentation/index.html", native.platforms_page(
                f"{native_name}.fmu (FMI 3.0)", [t.tuple for t in targets],
                "Any other platform: sources/buildDescription.xml lists what to compile. "
                + native.SOURCES_NOTE))
            z.writestr("sources/buildDescription.xml", _build_description(fmu, sources))
            for p in files:
                z.writestr(f"sources/{p.name}", p.read_bytes())
            for name, data in profiles:          # relative profile paths resolve here first
                z.writestr(name, data)
        target.write_bytes(tmp_fmu.read_bytes())
    return target


def build_native3_fmu(dest_dir, railcar_fmu=None) -> Path:
    """``dest_dir/RailCarNative3.fmu``; ``railcar_fmu``: the pythonfmu RailCar.fmu (profiles)."""
    return build_native3(RAILCAR_SPEC, dest_dir, railcar_fmu)


def build_native3_estimator_fmu(dest_dir, estimator_fmu=None) -> Path:
    """``dest_dir/RailCarEstimatorNative3.fmu``; ``estimator_fmu``: the pythonfmu
    RailCarEstimator.fmu (profiles)."""
    return build_native3(ESTIMATOR_SPEC, dest_dir, estimator_fmu)


# ------------------------------------------------------------- the native AtoController (issue 30)

def ato_c_sources() -> list[Path]:
    """The FMI 3 glue, then the FMI 2 AtoControllerNative's sources without the FMI 2 glue."""
    return [C_DIR / GLUE3_SOURCE,
            *[p for p in native.ato_c_sources() if p.name != "fmi2_glue.c"]]


def ato_c_headers() -> list[Path]:
    """The FMI 3 glue's header, the FMI 2 AtoControllerNative's headers (the backend interface
    fmi2_glue.h and the FMI 2 headers it includes) and the FMI 3 headers."""
    return [C_DIR / GLUE3_HEADER, *native.ato_c_headers(),
            *[fmi_headers() / h for h in FMI3_HEADERS]]


def ato_instantiation_token() -> str:
    """instantiation_token's rule for AtoControllerNative3: the table and every C file."""
    return _token(ATO_NATIVE3_NAME, ATO, [*ato_c_sources(), *ato_c_headers()])


def ato_model_description_xml(token: str) -> bytes:
    """AtoControllerNative3's modelDescription.xml: FMU states, as the other native FMUs."""
    return model_description.fmi3(ATO, token, GENERATION_TOOL)


def build_native_ato3(dest_dir, python_fmu=None, targets=None) -> Path:
    """``dest_dir/AtoControllerNative3.fmu`` (FMI 3.0): native_ato.c behind fmi3_glue.c, for
    each platform of ``targets`` (default: those with a compiler here). ``python_fmu``: the
    pythonfmu AtoController.fmu (default dist/'s), which supplies the profiles under resources/.
    Refuses to build when native_ato_table.h is out of date."""
    targets, python_fmu = native.ato_build_inputs(ATO_NATIVE3_NAME, python_fmu, targets)
    return _write_fmu3(dest_dir, ATO_NATIVE3_NAME, ATO,
                       ato_model_description_xml(ato_instantiation_token()), ato_c_sources(),
                       [*ato_c_sources(), *ato_c_headers()], python_fmu, targets)


if __name__ == "__main__":
    if len(sys.argv) != 2 or sys.argv[1].startswith("-"):
        print("\n".join(__doc__.splitlines()[4:7]), file=sys.stderr)
        sys.exit(2)
    for _spec in SPECS:
        print(f"built {build_native3(_spec, sys.argv[1])}")
    print(f"built {build_native_ato3(sys.argv[1])}")

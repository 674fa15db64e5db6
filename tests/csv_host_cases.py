"""Helpers for tests/fmu_tests/test_native_csv_host.py: build the C host tests/fmu_cases/csv_host.c, unpack
a native FMU for it, write its PARAMS/INPUTS files, run it and read OUT.csv back.

The host's command line and file formats are documented in the header of csv_host.c.
"""
from __future__ import annotations

import re
import subprocess
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from fmpy import read_model_description

HOST_SOURCE = Path(__file__).resolve().parent / "fmu_cases" / "csv_host.c"
# the flags the task sets for the host (house rules: -ffp-contract=off too), libdl only
HOST_FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]

# FMI 2 / FMI 3 type names -> the host's type words and its OUTPUT/column letters
TYPE_WORD = {"Real": "real", "Float64": "real", "Integer": "integer", "Int32": "integer",
             "Boolean": "boolean", "String": "string"}
TYPE_LETTER = {"real": "r", "integer": "i", "boolean": "b"}


def compile_host(compiler: list[str], headers: Path, out: Path) -> Path:
    """cc <flags> -I <fmpy/c-code> csv_host.c -o out -ldl; fails with the compiler's message."""
    cmd = [*compiler, *HOST_FLAGS, "-I", str(headers), str(HOST_SOURCE), "-o", str(out), "-ldl"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr}"
    return out


@dataclass
class NativeFmu:
    """One native FMU unpacked for the host: its binary, resources/ folder, GUID or
    instantiationToken, and name -> (value reference, host type word) from its model description."""
    version: int                  # 2 or 3
    root: Path
    binary: Path
    resources: Path
    token: str
    vars: dict = field(repr=False)          # name -> (vr, type word)
    outputs: list = field(repr=False)       # output names in model-description order

    @classmethod
    def unpack(cls, fmu: Path, dest: Path) -> "NativeFmu":
        md = read_model_description(str(fmu))
        with zipfile.ZipFile(fmu) as z:
            z.extractall(dest)
        version = int(md.fmiVersion[0])
        ident = md.coSimulation.modelIdentifier
        platform = "linux64" if version == 2 else "x86_64-linux"
        binary = dest / "binaries" / platform / f"{ident}.so"
        assert binary.is_file(), binary
        variables = {v.name: (v.valueReference, TYPE_WORD[v.type]) for v in md.modelVariables}
        outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        return cls(version, dest, binary, dest / "resources", md.guid, variables, outputs)

    def spec(self, name: str) -> str:
        """The host's column/OUTPUT name of a variable: type letter and value reference."""
        vr, word = self.vars[name]
        return f"{TYPE_LETTER[word]}{vr}"


def write_params(path: Path, fmu: NativeFmu, parameters: dict) -> Path:
    lines = ["vr,type,value"]
    for name, value in parameters.items():
        vr, word = fmu.vars[name]
        text = {"real": lambda x: repr(float(x)), "integer": lambda x: str(int(x)),
                "boolean": lambda x: "true" if x else "false", "string": str}[word](value)
        lines.append(f"{vr},{word},{text}")
    path.write_text("\n".join(lines) + "\n")
    return path


def write_inputs(path: Path, fmu: NativeFmu, names, times, rows) -> Path:
    """Header "time [s]" and the inputs' specs; row k: repr(times[k]) and repr of each value
    (repr round-trips a double exactly)."""
    lines = [",".join(["time [s]"] + [fmu.spec(n) for n in names])]
    for t, row in zip(times, rows):
        lines.append(",".join([repr(float(t))] + [repr(float(x)) for x in row]))
    path.write_text("\n".join(lines) + "\n")
    return path


@dataclass
class HostRun:
    returncode: int
    stderr: str
    header: list
    time: np.ndarray
    columns: dict          # output name -> array (float64 for reals, int64 otherwise)
    status: np.ndarray

    def messages(self, call_status: str) -> list[str]:
        """The FMU's messages the host reported at one level ("Warning" in an OK call, or a
        call that returned "Discard"/"Error"), without the host's "where" prefix."""
        out = []
        pattern = re.compile(r"csv_host: .*?: fmi[23]\w+(?:\(vr \d+\))?"
                             r"(?: returned (\w+)|: (\w+)): (.*)$")
        for line in self.stderr.splitlines():
            m = pattern.match(line)
            if m and (m.group(1) or m.group(2)) == call_status:
                out.append(m.group(3))
        return out


def read_output(path: Path, fmu: NativeFmu, outputs: list[str]) -> tuple:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    assert header == ["time [s]"] + [fmu.spec(n) for n in outputs] + ["status"], header
    cells = [line.split(",") for line in lines[1:]]
    assert all(len(c) == len(header) for c in cells)
    time = np.array([float(c[0]) for c in cells])
    columns = {}
    for j, name in enumerate(outputs, start=1):
        if fmu.vars[name][1] == "real":
            columns[name] = np.array([float(c[j]) for c in cells])
        else:
            columns[name] = np.array([int(c[j]) for c in cells], dtype=np.int64)
    status = np.array([int(c[-1]) for c in cells])
    return header, time, columns, status


def run_host(host: Path, fmu: NativeFmu, params: Path, inputs: Path, out: Path,
             outputs: list[str], step: float | None = None, stop: float | None = None,
             options: tuple = (), env: dict | None = None, timeout: float = 60) -> HostRun:
    """Run the host; OUT.csv read back when it was written."""
    cmd = [str(host), *options]
    if step is not None:
        cmd += ["-s", repr(float(step))]
    if stop is not None:
        cmd += ["-e", repr(float(stop))]
    cmd += [f"fmi{fmu.version}", str(fmu.binary), str(fmu.resources), fmu.token, str(params),
            str(inputs), str(out), *[fmu.spec(n) for n in outputs]]
    if out.exists():
        out.unlink()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout)
    if out.exists():
        header, time, columns, status = read_output(out, fmu, outputs)
    else:
        header, time, columns, status = [], np.array([]), {}, np.array([], dtype=int)
    return HostRun(proc.returncode, proc.stderr, header, time, columns, status)


def bits(a) -> np.ndarray:
    """float64 bit patterns: exact comparison (NaN == NaN, -0.0 != 0.0)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def assert_same(expected: dict, got: dict, what: str) -> None:
    """Every output at every row bit-identical (reals as float64 bits, integers as integers)."""
    assert expected.keys() == got.keys(), what
    for name in expected:
        a, b = np.asarray(expected[name]), np.asarray(got[name])
        assert a.shape == b.shape, f"{what}: {name}: {a.shape} rows vs {b.shape}"
        if a.dtype.kind == "f" or b.dtype.kind == "f":
            diff = np.flatnonzero(bits(a) != bits(b))
        else:
            diff = np.flatnonzero(a != b)
        assert diff.size == 0, (f"{what}: {name} differs at {diff.size} row(s), first row "
                                f"{diff[0]}: {a[diff[0]]!r} vs {b[diff[0]]!r}")

"""The native FMUs' foreign binaries against their Linux x86-64 binary, on every library scenario.

For each library scenario (scenarios/library/*.toml) the native RailCar (fmu_src's C core behind
the FMI 2 glue, through fmpy) runs the scenario closed loop with harness.run.runner.FmuRunner,
which records the inputs it sent at each step. Those inputs, and the run's forces and sensor
outputs as the estimator's inputs (as tests/fmu_tests/test_native_csv_host.py builds them), are
replayed open loop through the C host tests/fmu_cases/csv_host.c on the four native FMUs
(RailCarNative, RailCarEstimatorNative: FMI 2.0; RailCarNative3, RailCarEstimatorNative3: FMI 3.0):

- linux x86-64: the host built with this machine's compiler, the binaries/linux64 and
  binaries/x86_64-linux libraries: the reference;
- linux aarch64: the host cross-compiled (gcc-aarch64-linux-gnu), run under qemu-aarch64 with
  the aarch64 C library, on binaries/aarch64-linux;
- Windows x86-64: the host built with mingw-w64 (LoadLibrary/GetProcAddress), run under Wine with
  Windows paths (Z:\\...) for everything, the profile files the scenarios name included, on
  binaries/win64 and binaries/x86_64-windows.

Each foreign platform runs every case in ONE host process (``csv_host -b RUNS.txt``): a process
start is what costs under Wine. The outputs are compared with the x86-64 ones output by output:
the largest difference over all rows in units in the last place (ulps: how many doubles lie
between the two values) and absolutely.

    python tests/fmu_cases/cross_platform.py [--dist DIR] [--markdown]

prints the table "scenario x output -> largest difference" for both platforms (building the FMUs
into a temporary folder unless --dist names a build.py output folder holding native/).
tests/fmu_tests/test_cross_platform.py runs the same sweep and bounds the differences.

FMU states: run_state_round_trips runs csv_host -k (the state's round trip, pass B from the
serialized bytes, pass C from the state itself, against pass A bit for bit) for a list of cases in
one host process, optionally deserializing another platform's bytes (-L);
state_field_difference names where two serialized states first differ.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
for _folder in (ROOT, HERE.parent):          # the project, and tests/ for csv_host_cases
    if str(_folder) not in sys.path:
        sys.path.insert(0, str(_folder))

from csv_host_cases import HOST_FLAGS, HOST_SOURCE, NativeFmu, read_output  # noqa: E402
from fmu_src.build import native, toolchain  # noqa: E402
from fmu_src.build.toolchain import LINUX_AARCH64, LINUX_X86_64, WINDOWS_X86_64  # noqa: E402

LIBRARY = ROOT / "scenarios" / "library"
NATIVE = {  # native FMU -> (modelIdentifier, FMI version)
    "RailCarNative": ("RailCar", 2),
    "RailCarEstimatorNative": ("RailCarEstimator", 2),
    "RailCarNative3": ("RailCar", 3),
    "RailCarEstimatorNative3": ("RailCarEstimator", 3),
}
ATO_NATIVE = {  # the native AtoControllers: fed a span's inputs by the tests, not a scenario
    "AtoControllerNative": ("AtoController", 2),
    "AtoControllerNative3": ("AtoController", 3),
}
FOREIGN = (LINUX_AARCH64, WINDOWS_X86_64)
AARCH64_SYSROOT = Path("/usr/aarch64-linux-gnu")    # Debian's libc6-arm64-cross
QEMU = "qemu-aarch64"
RAILCAR_INPUTS = tuple(native.RAILCAR_SPEC.inputs)       # FmuRunner's INPUTS, in its order
ESTIMATOR_INPUTS = tuple(native.ESTIMATOR_SPEC.inputs)


class Unavailable(RuntimeError):
    """This machine cannot run a platform's check; the message names what is missing and the
    Debian package that provides it."""


# --------------------------------------------------------------------------------- the hosts

@dataclass
class Platform:
    """One platform's host: how to start it and how it names files."""
    target: toolchain.Target
    host: Path
    prefix: list                     # the command before the host: qemu or Wine
    env: dict = field(default_factory=lambda: dict(os.environ))

    @property
    def windows(self) -> bool:
        return self.target is WINDOWS_X86_64

    def path(self, p: Path) -> str:
        """A file's name as the host sees it: Wine's drive Z: is the Linux root."""
        return "Z:" + str(p).replace("/", "\\") if self.windows else str(p)

    def binary(self, root: Path, name: str) -> Path:
        """The FMU's library for this platform in the FMU unpacked at ``root``."""
        model, version = {**NATIVE, **ATO_NATIVE}[name]
        folder = self.target.fmi2_folder if version == 2 else self.target.tuple
        return root / "binaries" / folder / f"{model}{self.target.extension}"

    def command(self, runs: Path) -> list[str]:
        return [*self.prefix, self.path(self.host) if self.windows else str(self.host),
                "-b", self.path(runs)]


def wine_command() -> str | None:
    """wine64 or wine on PATH, else Debian's /usr/lib/wine/wine64 (wine64 puts it off PATH)."""
    for candidate in ("wine64", "wine"):
        if shutil.which(candidate):
            return shutil.which(candidate)
    return "/usr/lib/wine/wine64" if Path("/usr/lib/wine/wine64").is_file() else None


def host_compile_command(target: toolchain.Target, out: Path) -> list[str]:
    """The host's build for ``target``: the house flags, fmpy's FMI headers; libdl but on
    Windows (LoadLibrary is in KERNEL32)."""
    cc = toolchain.target_compiler(target)
    if cc is None:
        raise Unavailable(toolchain.missing_compiler(target))
    libraries = [] if target is WINDOWS_X86_64 else ["-ldl"]
    return [*cc, *HOST_FLAGS, "-I", str(toolchain.fmi_headers()), str(HOST_SOURCE), "-o",
            str(out), *libraries]


def build_platform(target: toolchain.Target, folder: Path) -> Platform:
    """Compile the host for ``target`` into ``folder`` and find what runs it; Unavailable when
    this machine lacks the compiler, qemu, the aarch64 C library or Wine."""
    if target is LINUX_AARCH64:
        if shutil.which(QEMU) is None:
            raise Unavailable(f"{target.tuple}: {QEMU} not found (apt-get install qemu-user)")
        if not (AARCH64_SYSROOT / "lib").is_dir():
            raise Unavailable(f"{target.tuple}: no {AARCH64_SYSROOT}/lib "
                              "(apt-get install libc6-arm64-cross)")
        prefix = [QEMU, "-L", str(AARCH64_SYSROOT)]
    elif target is WINDOWS_X86_64:
        wine = wine_command()
        if wine is None:
            raise Unavailable(f"{target.tuple}: no Wine (apt-get install wine64)")
        prefix = [wine]
    else:
        prefix = []
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"csv_host_{target.tuple}{'.exe' if target is WINDOWS_X86_64 else ''}"
    cmd = host_compile_command(target, out)
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling the host for {target.tuple} failed:\n{' '.join(cmd)}\n"
                           f"{proc.stderr}")
    env = dict(os.environ)
    if target is WINDOWS_X86_64:
        # a prefix of our own (created on first use, ~10 s), no Wine debug chatter on stderr
        env.update(WINEPREFIX=str(folder / "wineprefix"), WINEDEBUG="-all")
    return Platform(target, out, prefix, env)


# --------------------------------------------------------------------------------- the cases

@dataclass
class Case:
    """One native FMU on one scenario: its parameters and the inputs it replays."""
    scenario: str
    fmu: str                    # a key of NATIVE
    parameters: dict
    inputs: tuple               # input names, the columns of ``rows``
    times: np.ndarray           # the start of each step [s]
    rows: np.ndarray
    step: float | None          # fixed step [s] (RailCar: the scenario's), None: t_k+1 - t_k
    stop: float                 # [s]
    closed_loop: dict | None = None     # RailCar: the closed-loop run's outputs (replay check)

    @property
    def key(self) -> str:
        return f"{self.scenario}.{self.fmu}"


def library_scenarios() -> list[str]:
    return sorted(p.stem for p in LIBRARY.glob("*.toml"))


def closed_loop_cases(native_dir: Path, scenarios: list[str] | None = None) -> list[Case]:
    """Every scenario run closed loop on the native RailCar FMI 2 (FmuRunner through fmpy: the
    same inputs the pythonfmu RailCar gets, tests/fmu_tests/test_native_fmu.py), turned into one
    case per native FMU."""
    from harness.run.runner import FmuRunner
    from harness.run.scenario import load_scenario
    from fmu_src.variables import ESTIMATOR, variables_for
    est_parameters = {v.name for v in variables_for(ESTIMATOR) if v.causality == "parameter"}
    cases = []
    with FmuRunner(native_dir / "RailCarNative.fmu") as runner:
        for stem in scenarios or library_scenarios():
            sc = load_scenario(LIBRARY / f"{stem}.toml")
            run = runner.run(sc)
            n = len(run.time) - 1
            car_times = np.arange(n) * sc.step_s
            car_rows = np.column_stack([run.inputs[name][:n] for name in RAILCAR_INPUTS])
            t, sig = run.time, run.signals
            # the estimator at t_k sees the measurements at t_k and the forces over [t_k, t_k+1]
            est_rows = np.column_stack([sig["car.traction_force"][1:], sig["car.brake_force"][1:],
                                        sig["sensor.speed"][:-1], sig["sensor.position"][:-1],
                                        sig["sensor.track_speed"][:-1],
                                        sig["sensor.track_time"][:-1]])
            est_params = {k: v for k, v in sc.parameters.items() if k in est_parameters}
            for name, (model, _) in NATIVE.items():
                if model == "RailCar":
                    cases.append(Case(stem, name, dict(sc.parameters), RAILCAR_INPUTS, car_times,
                                      car_rows, sc.step_s, sc.duration_s,
                                      {n: sig[n] for n in runner.outputs}))
                else:
                    cases.append(Case(stem, name, est_params, ESTIMATOR_INPUTS, t[:-1], est_rows,
                                      None, float(t[-1])))
    return cases


def unpack_all(native_dir: Path, folder: Path) -> dict[str, NativeFmu]:
    return {name: NativeFmu.unpack(native_dir / f"{name}.fmu", folder / name) for name in NATIVE}


def _value_text(value, word: str, platform: Platform) -> str:
    if word == "string":
        text = str(value)
        # a file the scenario names (a grade profile): the platform's name for it
        return platform.path(Path(text)) if Path(text).is_absolute() else text
    if word == "real":
        return repr(float(value))
    if word == "integer":
        return str(int(value))
    return "true" if value else "false"


def _input_text(value, word: str) -> str:
    """An input cell as the host reads it: reals by repr (exact), Int32 and Booleans as integers."""
    return repr(float(value)) if word == "real" else str(int(value))


def write_case_files(case: Case, fmu: NativeFmu, platform: Platform, folder: Path) -> Path:
    """PARAMS.csv and INPUTS.csv of one case for one platform; its OUT.csv path."""
    folder.mkdir(parents=True, exist_ok=True)
    params = ["vr,type,value"]
    for name, value in case.parameters.items():
        vr, word = fmu.vars[name]
        params.append(f"{vr},{word},{_value_text(value, word, platform)}")
    (folder / "params.csv").write_text("\n".join(params) + "\n")
    lines = [",".join(["time [s]", *(fmu.spec(n) for n in case.inputs)])]
    words = [fmu.vars[n][1] for n in case.inputs]
    lines += [",".join([repr(float(t)), *(_input_text(x, w) for x, w in zip(row, words))])
              for t, row in zip(case.times, case.rows)]
    (folder / "inputs.csv").write_text("\n".join(lines) + "\n")
    return folder / "out.csv"


def run_platform(platform: Platform, cases: list[Case], fmus: dict[str, NativeFmu],
                 folder: Path, timeout: float = 900) -> dict[str, dict]:
    """Every case through one host process; case key -> output name -> values (float64 reals,
    int64 integers), the time column under "time". RuntimeError naming the runs that failed."""
    lines, outs = [], {}
    for case in cases:
        fmu = fmus[case.fmu]
        case_folder = folder / platform.target.tuple / case.key
        out = write_case_files(case, fmu, platform, case_folder)
        if out.exists():
            out.unlink()
        args = ["-q"]
        args += ["-s", repr(float(case.step))] if case.step is not None else []
        args += ["-e", repr(float(case.stop)), f"fmi{fmu.version}",
                 platform.path(platform.binary(fmu.root, case.fmu)), platform.path(fmu.resources),
                 fmu.token, platform.path(case_folder / "params.csv"),
                 platform.path(case_folder / "inputs.csv"), platform.path(out),
                 *(fmu.spec(n) for n in fmu.outputs)]
        lines.append("\t".join(args))
        outs[case.key] = (out, fmu)
    runs = folder / platform.target.tuple / "runs.txt"
    runs.write_text("\n".join(lines) + "\n")
    proc = subprocess.run(platform.command(runs), capture_output=True, text=True,
                          env=platform.env, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"{platform.target.tuple}: {' '.join(platform.command(runs))} exited "
                           f"with {proc.returncode}:\n{proc.stderr[-4000:]}")
    got = {}
    for case in cases:
        out, fmu = outs[case.key]
        if not out.is_file():
            raise RuntimeError(f"{platform.target.tuple}: {case.key}: no {out}\n{proc.stderr}")
        _, time, columns, status = read_output(out, fmu, fmu.outputs)
        if len(time) != len(case.times) + 1 or status.any():
            raise RuntimeError(f"{platform.target.tuple}: {case.key}: {len(time)} rows for "
                               f"{len(case.times)} steps, statuses {sorted(set(status))}")
        got[case.key] = {"time": time, **columns}
    return got


# ------------------------------------------------------------------- FMU states (csv_host -k)

@dataclass
class StateRun:
    """One case's FMU-state round trip through csv_host -k on one platform (the host's header
    documents the passes): its REPORT.txt as key -> the rest of the line, the bytes it serialized
    at the state's row (-S), and whether pass A's OUT.csv was written."""
    key: str
    row: int                    # the state is taken before this row's step
    report: dict
    state: bytes | None
    out_written: bool

    def identical(self) -> bool:
        """Passes B and C replayed pass A bit for bit, and no call failed."""
        return (self.report.get("pass_b") == "identical" and self.report.get("pass_c") ==
                "identical" and "failed" not in self.report)


def state_row(case: Case) -> int:
    """The row in the middle of the run (the ATO's span: mid-span)."""
    return len(case.times) // 2


def _read_report(path: Path) -> dict:
    if not path.is_file():
        return {}
    return dict((line.split(" ", 1) + [""])[:2] for line in path.read_text().splitlines() if line)


def run_state_round_trips(platform: Platform, cases: list[Case], fmus: dict[str, NativeFmu],
                          folder: Path, foreign: dict[str, Path] | None = None,
                          timeout: float = 900):
    """Every case's state round trip (csv_host -k at state_row, -S the bytes) in one host
    process; with ``foreign`` (case key -> bytes another platform serialized at that row) each
    such case also runs with -L: pass B deserializes the other platform's bytes. Returns
    (case key -> StateRun, case key -> StateRun of the -L runs, the host's CompletedProcess); the
    caller judges the exit status, since a refused state is an expected outcome of -L."""
    lines, runs = [], []
    foreign = foreign or {}
    for case in cases:
        fmu = fmus[case.fmu]
        case_folder = folder / platform.target.tuple / case.key
        write_case_files(case, fmu, platform, case_folder)
        variants = [("", None)] + ([("_foreign", foreign[case.key])] if case.key in foreign else [])
        for suffix, bytes_in in variants:
            files = {name: case_folder / f"{name}{suffix}{ext}" for name, ext in
                     (("out", ".csv"), ("state", ".bin"), ("report", ".txt"))}
            for f in files.values():
                f.unlink(missing_ok=True)
            args = ["-q", "-k", str(state_row(case)), "-R", platform.path(files["report"])]
            args += (["-S", platform.path(files["state"])] if bytes_in is None
                     else ["-L", platform.path(bytes_in)])
            args += ["-s", repr(float(case.step))] if case.step is not None else []
            args += ["-e", repr(float(case.stop)), f"fmi{fmu.version}",
                     platform.path(platform.binary(fmu.root, case.fmu)),
                     platform.path(fmu.resources), fmu.token,
                     platform.path(case_folder / "params.csv"),
                     platform.path(case_folder / "inputs.csv"), platform.path(files["out"]),
                     *(fmu.spec(n) for n in fmu.outputs)]
            lines.append("\t".join(args))
            runs.append((case, suffix, files))
    batch = folder / platform.target.tuple / "state_runs.txt"
    batch.write_text("\n".join(lines) + "\n")
    proc = subprocess.run(platform.command(batch), capture_output=True, text=True,
                          env=platform.env, timeout=timeout)
    own, loaded = {}, {}
    for case, suffix, files in runs:
        run = StateRun(case.key, state_row(case), _read_report(files["report"]),
                       files["state"].read_bytes() if files["state"].is_file() else None,
                       files["out"].is_file())
        (loaded if suffix else own)[case.key] = run
    return own, loaded, proc


def state_field_difference(a: bytes, b: bytes) -> str:
    """Where two serialized FMU states (glue_common.c's layout) first differ, named: the header's
    fields by name, else the offset into the model's part."""
    if a == b:
        return "equal"
    if len(a) != len(b):
        prefix = f"{len(a)} vs {len(b)} bytes; "
    else:
        prefix = ""
    at = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    header = [(0, 8, "magic"), (8, 12, "format version"), (12, 16, "byte-order mark"),
              (16, 24, "type sizes (double, long, void *, int, size_t)"),
              (24, 28, "layout fingerprint"), (28, 32, "token length"),
              (32, 40, "total length")]
    for lo, hi, name in header:
        if lo <= at < hi:
            return f"{prefix}first at byte {at}: the header's {name} ({a[lo:hi].hex()} vs {b[lo:hi].hex()})"
    token_len = int.from_bytes(a[28:32], sys.byteorder)
    model_at = 40 + token_len + 24
    if at < model_at:
        return f"{prefix}first at byte {at}: the token or the glue's fields"
    if at >= len(a) - 8:
        return f"{prefix}first at byte {at}: the checksum"
    return f"{prefix}first at byte {at}: offset {at - model_at} of the model's part"


# ------------------------------------------------------------------------------ comparison

def _ordered(a: np.ndarray) -> np.ndarray:
    """float64 bits as integers in the doubles' order (-0.0 and +0.0 both 0)."""
    i = np.ascontiguousarray(a, dtype=np.float64).view(np.int64)
    return np.where(i < 0, -(i & np.int64(0x7FFF_FFFF_FFFF_FFFF)), i)


def ulp_distance(a, b) -> np.ndarray:
    """Per row: how many doubles apart a and b are (0: the same value; float: inf where only one
    is NaN or the distance does not fit). Integer columns: their difference."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind != "f":
        return np.abs(a.astype(np.float64) - b.astype(np.float64))
    out = np.zeros(a.shape)
    same_bits = _ordered(a) == _ordered(b)
    nan = np.isnan(a) | np.isnan(b)
    out[nan & ~(np.isnan(a) & np.isnan(b))] = np.inf
    rows = np.flatnonzero(~same_bits & ~nan)
    oa, ob = _ordered(a[rows]).tolist(), _ordered(b[rows]).tolist()     # Python ints: no overflow
    out[rows] = [float(abs(x - y)) for x, y in zip(oa, ob)]
    return out


@dataclass(frozen=True)
class Difference:
    """The largest difference of one output over one run's rows."""
    ulps: float                 # largest distance in ulps (integers: their largest difference)
    absolute: float             # largest |foreign - x86-64|
    relative: float             # largest |foreign - x86-64| / |x86-64| over the differing rows
    rows: int                   # rows that differ
    first_row: int              # the first one (-1: none)


def compare(reference: dict, got: dict) -> dict[str, Difference]:
    """output -> Difference, for every output of one run (the time column included). The two
    runs must hold the same outputs over the same rows: a foreign run that lost a column or a
    row is a failure, not a difference of the rows both have."""
    assert set(got) == set(reference), f"outputs differ: {sorted(set(got) ^ set(reference))}"
    out = {}
    for name, ref in reference.items():
        value = got[name]
        assert np.shape(value) == np.shape(ref), f"{name}: {np.shape(value)} rows, not {np.shape(ref)}"
        ulps = ulp_distance(ref, value)
        differing = np.flatnonzero(ulps > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            absolute = np.abs(np.asarray(value, dtype=np.float64) - np.asarray(ref, np.float64))
            relative = absolute[differing] / np.abs(np.asarray(ref, np.float64)[differing])
        out[name] = Difference(float(ulps.max(initial=0.0)),
                               float(np.nanmax(absolute[differing], initial=0.0)),
                               float(np.nanmax(relative, initial=0.0)), int(differing.size),
                               int(differing[0]) if differing.size else -1)
    return out


def sweep(platform: Platform, reference: dict, cases: list[Case], fmus: dict, folder: Path):
    """case key -> output -> Difference of ``platform`` against ``reference`` (run_platform's
    result on linux x86-64)."""
    got = run_platform(platform, cases, fmus, folder)
    return {case.key: compare(reference[case.key], got[case.key]) for case in cases}


def table(results: dict[str, dict], only_differing: bool = True, markdown: bool = False) -> str:
    """platform -> sweep result, as the lines "platform scenario.FMU output: ulps, abs, rel,
    rows"; the outputs that are bit-identical in every run are summed up in one line each."""
    lines = []
    if markdown:
        lines += ["| platform | scenario | FMU | output | max ulps | max abs | max rel | rows |",
                  "|---|---|---|---|---|---|---|---|"]
    for tuple_, result in results.items():
        total = sum(len(d) for d in result.values())
        differing = [(key, name, d) for key, diffs in result.items()
                     for name, d in diffs.items() if d.rows]
        if not markdown:
            lines.append(f"{tuple_}: {len(result)} runs, {total} output columns, "
                         f"{len(differing)} not bit-identical")
        for key, name, d in differing:
            scenario, fmu = key.split(".", 1)
            if markdown:
                lines.append(f"| {tuple_} | {scenario} | {fmu} | {name} | {d.ulps:g} | "
                             f"{d.absolute:.3g} | {d.relative:.3g} | {d.rows} |")
            else:
                lines.append(f"  {scenario:22s} {fmu:24s} {name:22s} {d.ulps:4g} ulp  "
                             f"abs {d.absolute:.3g}  rel {d.relative:.3g}  "
                             f"{d.rows} row(s) from row {d.first_row}")
        if not only_differing and not differing:
            lines.append(f"| {tuple_} | every one | every one | every one | 0 | 0 | 0 | 0 |"
                         if markdown else "  every output of every run bit-identical")
    return "\n".join(lines)


def scenario_table(tuple_: str, result: dict[str, dict], markdown: bool = False) -> str:
    """scenario x output -> the largest difference in ulps over the four FMUs, for the outputs
    that differ in some scenario (the others: bit-identical everywhere, said in the title)."""
    scenarios = sorted({key.split(".", 1)[0] for key in result})
    names = sorted(largest_per_output(result))
    n_outputs = len({name for diffs in result.values() for name in diffs})
    if not names:
        return (f"{tuple_}: all {n_outputs} outputs (the time column included) bit-identical "
                f"in every scenario, through the {len(NATIVE)} native FMUs")
    title = (f"{tuple_}: largest difference in ulps, scenario x output (over the "
             f"{len(NATIVE)} native FMUs); the {n_outputs - len(names)} other outputs of "
             f"{n_outputs} (the time column included) bit-identical in every scenario")
    cell = {}
    for key, diffs in result.items():
        scenario = key.split(".", 1)[0]
        for name in names:
            if name in diffs:
                cell[scenario, name] = max(cell.get((scenario, name), 0.0), diffs[name].ulps)
    if markdown:
        rows = [f"| scenario | {' | '.join(names)} |", "|---" * (len(names) + 1) + "|"]
        rows += [f"| {sc} | " + " | ".join(f"{cell.get((sc, n), 0):g}" for n in names) + " |"
                 for sc in scenarios]
    else:
        rows = ["  " + f"{'scenario':22s}" + "".join(f"{n:>16s}" for n in names)]
        rows += ["  " + f"{sc:22s}" + "".join(f"{cell.get((sc, n), 0):>16g}" for n in names)
                 for sc in scenarios]
    return "\n".join([title, *rows])


def largest_per_output(result: dict[str, dict]) -> dict[str, float]:
    """output -> the largest ulps over every run of one platform's sweep (differing only)."""
    out: dict[str, float] = {}
    for diffs in result.values():
        for name, d in diffs.items():
            if d.rows:
                out[name] = max(out.get(name, 0.0), d.ulps)
    return out


# ---------------------------------------------------------------------------------- the CLI

def main(argv: list[str] | None = None) -> int:
    import argparse
    import tempfile
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dist", type=Path, help="a build.py --dest folder (with native/); "
                        "default: build the FMUs into a temporary folder")
    parser.add_argument("--markdown", action="store_true", help="the table in Markdown")
    parser.add_argument("--scenario", action="append", help="only these (default: every one)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="cross_platform_") as tmp:
        work = Path(tmp)
        dist = args.dist
        if dist is None:
            from fmu_src.build.dist import run_build
            dist = work / "dist"
            print(f"building the FMUs into {dist} ...", file=sys.stderr)
            run_build(dist)
        native_dir = dist / "native"
        fmus = unpack_all(native_dir, work / "fmus")
        cases = closed_loop_cases(native_dir, args.scenario)
        x86 = build_platform(LINUX_X86_64, work / "hosts")
        reference = run_platform(x86, cases, fmus, work / "runs")
        results, missing = {}, []
        for target in FOREIGN:
            try:
                platform = build_platform(target, work / "hosts")
            except Unavailable as exc:
                missing.append(f"NOT CHECKED {exc}")
                continue
            results[target.tuple] = sweep(platform, reference, cases, fmus, work / "runs")
        print(f"{len(cases)} runs ({len(cases) // len(NATIVE)} scenarios x {len(NATIVE)} native "
              "FMUs), each foreign output against the linux x86-64 binary's, every row:")
        for tuple_, result in results.items():
            print(scenario_table(tuple_, result, markdown=args.markdown) + "\n")
        print("Every run that is not bit-identical, output by output:")
        print(table(results, only_differing=False, markdown=args.markdown))
        for line in missing:
            print(line)
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())

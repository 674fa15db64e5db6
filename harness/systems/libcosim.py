"""Run an SSP system (harness.systems.ssp) in libcosim, the Open Simulation Platform's master, through
libcosimpy: the independent check of our own master (harness.systems.master), the same table out.

libcosim loads the .ssp itself (CosimExecution.from_ssp_file): its components, connections and
parameter sets; we only pass the step in integer nanoseconds (harness.systems.master.to_ns, as libcosim
reads the file's baseStepSize) and observe the outputs with a time-series observer, whose first
sample is the values after initialisation. The file is read with harness.systems.ssp_read.read_ssp first, so a
bad system is refused with our message before libcosim sees it (libcosim only logs a warning for
a parameter it cannot set, and aborts the whole process when an FMU fails initialisation:
check parameters with our master first, or pass ``isolated=True``: the run then happens in a child
process, and an abort there is a MasterError here). libcosim 0.11 runs FMI 2.0 FMUs only.

libcosim hands a String parameter to the FMU as written, so a profile packed in the .ssp
("resources/profiles/...", relative to the .ssd) reaches the FMU as that relative path, which our
FMUs look up in their own resources/ and then in the working directory: the run therefore
happens with the working directory a temporary folder the packed files are unpacked into
(harness.systems.ssp_read.unpack_files), and restored after.

libcosimpy is an optional (test) dependency, imported only when a run is asked for.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
from ctypes import POINTER, c_double, c_int, c_int64, c_size_t, c_uint32
from pathlib import Path
from typing import Sequence

import numpy as np

from harness.systems.master import (MasterError, Result, check_outputs, default_outputs, report_failure, steps_for,
                     time_grid, to_ns)
from harness.systems.ssp import LoadedSystem, SspError, packed_member, split_name, ssp_type, unit_of
from harness.systems.ssp_read import read_ssp, unpack_files

__all__ = ["LibcosimMissing", "run_libcosim"]


class LibcosimMissing(ImportError):
    """libcosimpy is not installed."""


def _libcosim():
    try:
        from libcosimpy import CosimExecution, CosimLogging, CosimObserver, _internal
        from libcosimpy.CosimEnums import CosimVariableType
    except ImportError as e:
        raise LibcosimMissing(f"running a system in libcosim needs libcosimpy (pip install libcosimpy, "
                              f"or the project's [test] extra): {e}") from None
    return CosimExecution, CosimLogging, CosimObserver, CosimVariableType, _internal


def _check_prefixes(system: LoadedSystem) -> None:
    """libcosim looks elements up by their prefixed names (ssd:System, ssc:Real, ssv:Parameter):
    a valid SSD with other namespace prefixes would load as an empty or partial system there."""
    import zipfile
    from harness.systems.ssp import NS, SSD_NAME
    with zipfile.ZipFile(system.path) as z:
        head = z.read(SSD_NAME)[:4000].decode("utf-8", "replace")
    for prefix in ("ssd", "ssc"):
        if f'xmlns:{prefix}="{NS[prefix]}"' not in head:
            raise SspError(f"{system.path}: {SSD_NAME}: libcosim reads the namespace prefix '{prefix}:' "
                           f"literally; declare xmlns:{prefix}=\"{NS[prefix]}\" on the root element")


def _samples(internal, observer, index: int, vr: int, typ: str, n: int):
    """All n + 1 samples of one variable from step 0 (libcosimc's own call: libcosimpy's
    time_series_*_samples drops the last sample of a read that starts at step 0)."""
    c_type = c_double if typ == "Real" else c_int
    fn = internal.wrap_function(
        lib=internal.libcosimc(),
        funcname="cosim_observer_slave_get_real_samples" if typ == "Real" else
        "cosim_observer_slave_get_integer_samples",
        argtypes=[POINTER(type(observer)), c_int, c_uint32, c_int64, c_size_t, c_type * (n + 1),
                  c_int64 * (n + 1), c_int64 * (n + 1)],
        restype=c_int64)
    values, steps, times = (c_type * (n + 1))(), (c_int64 * (n + 1))(), (c_int64 * (n + 1))()
    got = fn(observer.ptr(), index, vr, 0, n + 1, values, steps, times)
    return got, list(values[:max(got, 0)]), list(steps[:max(got, 0)]), list(times[:max(got, 0)])


def run_libcosim(system: LoadedSystem | str | Path, stop_time: float | None = None,
                 n_steps: int | None = None, outputs: Sequence[str] | None = None,
                 log_level: str = "WARNING", isolated: bool = False) -> Result:
    """Run the .ssp in libcosim and return ``outputs`` (default every Real and Integer output:
    libcosim's time series hold no others) over time, the same table as
    harness.systems.master.run_system. ``isolated``: run libcosim in a child process (an FMU failing
    initialisation aborts libcosim's process)."""
    if not isinstance(system, LoadedSystem):
        system = read_ssp(system)
    spec = system.spec
    n = steps_for(system, stop_time, n_steps)
    if outputs is None:
        outputs = [o for o in default_outputs(system) if ssp_type(system.variable(o)) in ("Real", "Integer")]
    outputs = check_outputs(system, outputs)
    if spec.step_order:
        raise SspError(f"{system.path}: the system steps its components in an order "
                       f"({' then '.join(spec.step_order)}, Gauss-Seidel); libcosim steps them all at "
                       f"once (Jacobi): run it with our master, or build it with --jacobi")
    for c in spec.components:
        if not system.models[c.name].fmiVersion.startswith("2"):
            raise SspError(f"{system.path}: component '{c.name}' is an FMI {system.models[c.name].fmiVersion} "
                           f"FMU; libcosim 0.11 runs FMI 2.0 only (harness.systems.master runs both)")
    for full in outputs:
        if ssp_type(system.variable(full)) not in ("Real", "Integer"):
            raise SspError(f"{system.path}: output '{full}': libcosim's time series hold Real and "
                           f"Integer variables only")
    _check_prefixes(system)
    if isolated:
        return _run_isolated(system, n, outputs, log_level)
    CosimExecution, CosimLogging, CosimObserver, CosimVariableType, internal = _libcosim()
    CosimLogging.log_output_level(getattr(CosimLogging.CosimLogLevel, log_level))
    if any(md.coSimulation.needsExecutionTool for md in system.models.values()):
        try:
            import pythonfmu  # noqa: F401
        except ImportError:
            pass
    ssp_file = Path(system.path).resolve()        # before the run's working directory changes
    with _packed_files_here(system):
        return _run(system, ssp_file, n, outputs, CosimExecution, CosimObserver, CosimVariableType, internal)


@contextlib.contextmanager
def _packed_files_here(system: LoadedSystem):
    """The working directory a temporary folder holding the package's packed files at their paths
    in the package (the module's text says why), for the time of the run."""
    if not any(packed_member(v) for c in system.spec.components for v in c.parameters.values()):
        yield
        return
    was = os.getcwd()
    with tempfile.TemporaryDirectory(prefix="railcar-libcosim-files-") as folder:
        unpack_files(system, folder)
        os.chdir(folder)
        try:
            yield
        finally:
            os.chdir(was)


def _run(system: LoadedSystem, ssp_file: Path, n: int, outputs: list[str], CosimExecution, CosimObserver,
         CosimVariableType, internal) -> Result:
    spec = system.spec
    step_ns = to_ns(spec.step)
    try:
        execution = CosimExecution.CosimExecution.from_ssp_file(str(ssp_file), step_ns)
    except AssertionError:
        raise MasterError(f"{system.path}: libcosim could not load the system: "
                          f"{internal.get_last_error_message()}") from None
    index = {}
    for info in execution.slave_infos():
        index[info.name.decode()] = info.index
    missing = [c.name for c in spec.components if c.name not in index]
    if missing:
        raise MasterError(f"{system.path}: libcosim did not load components {missing}")
    observer = CosimObserver.CosimObserver.create_time_series(n + 1)
    if not execution.add_observer(observer):
        raise MasterError(f"libcosim: adding the observer failed: {internal.get_last_error_message()}")
    watched = []
    for full in outputs:
        comp, name = split_name(full)
        v = system.variable(full)
        typ = ssp_type(v)
        kind = CosimVariableType.REAL if typ == "Real" else CosimVariableType.INTEGER
        if not observer.start_time_series(index[comp], v.valueReference, kind):
            raise MasterError(f"libcosim: observing {full} failed: {internal.get_last_error_message()}")
        watched.append((full, index[comp], v.valueReference, typ))
    if not execution.step(n):
        status = execution.status()
        raise MasterError(f"{spec.name}: libcosim stopped at t = {status.current_time / 1e9!r} s: "
                          f"{internal.get_last_error_message()}")
    status = execution.status()
    end_ns = to_ns(spec.start) + n * step_ns
    if status.current_time != end_ns:
        raise MasterError(f"{spec.name}: libcosim ended at {status.current_time} ns, not {end_ns} ns")
    grid = time_grid(spec.start, spec.step, n)
    signals, units = {}, {}
    for full, idx, vr, typ in watched:
        got, values, steps, times = _samples(internal, observer, idx, vr, typ, n)
        if got != n + 1 or steps != list(range(n + 1)) or \
                times != [to_ns(spec.start) + k * step_ns for k in range(n + 1)]:
            raise MasterError(f"libcosim: {full}: {got} samples at steps {steps[:3]}..., not steps 0..{n}")
        signals[full] = np.array(values, dtype=np.float64 if typ == "Real" else np.int64)
        units[full] = unit_of(system.variable(full))
    del execution, observer
    return Result(grid, signals, units, "libcosim")


# ------------------------------------------------------------------ in a child process

def _run_isolated(system: LoadedSystem, n: int, outputs: list[str], log_level: str) -> Result:
    _libcosim()                                   # LibcosimMissing here, not in the child
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory(prefix="railcar-libcosim-") as tmp:
        # libcosim unpacks the FMUs below TMPDIR; an aborted process leaves them there: ours
        env = dict(os.environ, TMPDIR=tmp,
                   PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
        out = Path(tmp) / "result.npz"
        request = json.dumps({"n_steps": n, "outputs": outputs, "log_level": log_level})
        proc = subprocess.run([sys.executable, "-m", "harness.systems.libcosim", str(system.path), request,
                               str(out)], capture_output=True, text=True, env=env)
        if proc.returncode == 0:
            data = np.load(out, allow_pickle=False)
            signals = {name: data[f"s{j}"] for j, name in enumerate(outputs)}
            return Result(data["time"], signals, {o: unit_of(system.variable(o)) for o in outputs},
                          "libcosim")
    tail = "\n".join(proc.stderr.strip().splitlines()[-12:])
    if proc.returncode == 2:
        raise SspError(tail.removeprefix("error: "))
    if proc.returncode < 0:
        try:
            what = f"was killed by {signal.Signals(-proc.returncode).name}"
        except ValueError:
            what = f"was killed by signal {-proc.returncode}"
        raise MasterError(f"{system.spec.name}: libcosim's process {what} (an FMU failing "
                          f"initialisation aborts libcosim)", tail.splitlines())
    raise MasterError(f"{system.spec.name}: libcosim's process failed (exit code {proc.returncode})",
                      tail.splitlines())


def _child(argv: list[str]) -> int:
    path, request, out = argv
    req = json.loads(request)
    try:
        r = run_libcosim(path, n_steps=req["n_steps"], outputs=req["outputs"], log_level=req["log_level"])
    except (SspError, MasterError) as e:
        return report_failure(e)
    np.savez(out, time=r.time, **{f"s{j}": r.signals[o] for j, o in enumerate(req["outputs"])})
    return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))

"""Memory per FMU instance: RSS growth over instantiate/free cycles and failed initialisations.

    python benchmarks/instance_cycles.py [--fmu dist/RailCar.fmu] [--cycles 1000] [--json]
    python benchmarks/instance_cycles.py --fmu OLD/RailCar.fmu --leak-failed   # pythonfmu's binary

Two phases, each in its own process (a crash is reported, not fatal to the benchmark), each one
process through fmpy's FMU2Slave with the library loaded once (as libcosim or a sweep worker):

  cycles  instantiate + fmi2FreeInstance, N times
  failed  instantiate, setupExperiment, enterInitializationMode, car.mass = 0 (RailCar;
          est.batch_size = 2 for RailCarEstimator), exitInitializationMode (must fail), then
          fmi2FreeInstance (--leak-failed: never freed, the only way with pythonfmu's binary,
          which crashes when such an instance is freed)

After a warm-up of 20 cycles (imports, allocator arenas), the growth per cycle is
(VmRSS after N cycles - VmRSS after the warm-up) / N, from /proc/self/status, and over the second
half alone; RSS is sampled at each quarter, to tell a steady leak from one-off growth. (With our
binary RSS grows ~1.5 MB over the first few hundred cycles, then not at all: CPython's type
attribute cache, 4096 entries, fills with attribute-name strings; bounded.) Build a pythonfmu-binary FMU for
the comparison with ``python build.py --dest OLD --pythonfmu-binary``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WARMUP = 20
MARKER = b"railcar-fmu fmi2 binary 1"
BAD = {"RailCar": ("car.mass", 0.0), "RailCarEstimator": ("est.batch_size", 2)}


def rss_kb() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise RuntimeError("no VmRSS in /proc/self/status")


def which_binary(fmu: Path) -> str:
    with zipfile.ZipFile(fmu) as z:
        sos = [n for n in z.namelist() if n.startswith("binaries/linux64/") and n.endswith(".so")]
        return "ours (fmu_src/c)" if sos and MARKER in z.read(sos[0]) else "pythonfmu's"


def phase(fmu_path: str, kind: str, cycles: int, leak_failed: bool) -> None:
    """One phase in this process; prints one JSON line per quarter and at the end."""
    import pythonfmu  # noqa: F401  (before the FMU is loaded)
    import gc
    from ctypes import byref
    from fmpy import calloc, extract, free, read_model_description
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                           fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
    from fmpy.logging import addLoggerProxy

    md = read_model_description(fmu_path)
    unzipdir = extract(fmu_path, unzipdir=tempfile.mkdtemp(prefix="cycles_"))
    counts = {"messages": 0, "init_status": None}

    def logger(_env, _name, _status, _category, _message):
        counts["messages"] += 1                   # count only: storing would grow RSS

    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(logger)
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(byref(cb))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="cycle")
    name, value = BAD[md.modelName]
    var = next(v for v in md.modelVariables if v.name == name)
    setter = fmu.setReal if var.type == "Real" else fmu.setInteger
    leaked = []

    def one() -> None:
        fmu.instantiate(callbacks=cb, loggingOn=False)
        if kind == "failed":
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            setter([var.valueReference], [value])
            try:
                fmu.exitInitializationMode()
                raise SystemExit(f"exitInitializationMode accepted {name} = {value}")
            except FMICallException as e:
                counts["init_status"] = e.status
            if leak_failed:
                leaked.append(fmu.component)
                return
        fmu.fmi2FreeInstance(fmu.component)       # not fmu.freeInstance(): keep the library

    for _ in range(WARMUP):
        one()
    gc.collect()
    start = rss_kb()
    samples = []
    for k in range(1, cycles + 1):
        one()
        if k % max(1, cycles // 4) == 0 or k == cycles:
            gc.collect()
            samples.append((k, rss_kb()))
            print(json.dumps({"progress": k, "rss_kb": samples[-1][1]}), flush=True)
    end = rss_kb()
    half_k, half_rss = min(samples, key=lambda s: abs(s[0] - cycles / 2))
    steady = (end - half_rss) / (cycles - half_k) if cycles > half_k else float("nan")
    print(json.dumps({"kind": kind, "cycles": cycles, "rss_start_kb": start, "rss_end_kb": end,
                      "growth_kb_per_cycle": (end - start) / cycles,
                      "second_half_kb_per_cycle": steady, "samples": samples,
                      "messages": counts["messages"], "init_status": counts["init_status"],
                      "leaked": len(leaked)}), flush=True)


def measure(fmu: Path, kind: str, cycles: int, leak_failed: bool) -> dict:
    """Run one phase in a child process; its result, or how it died."""
    cmd = [sys.executable, __file__, "--phase", kind, "--fmu", str(fmu), "--cycles", str(cycles)]
    if leak_failed:
        cmd.append("--leak-failed")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}   # the FMU's own modules
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    lines = [json.loads(x) for x in proc.stdout.splitlines() if x.startswith("{")]
    result = next((x for x in lines if "kind" in x), None)
    how = (f"killed by signal {-proc.returncode}" if proc.returncode < 0
           else f"exit code {proc.returncode}")
    if result is None:
        done = max([x["progress"] for x in lines if "progress" in x], default=0)
        return {"kind": kind, "cycles": cycles, "crashed": how, "after_cycles": done,
                "stderr": proc.stderr[-2000:]}
    if proc.returncode != 0:          # all cycles measured, then the process died on its way out
        result["died_at_exit"] = how
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fmu", default=str(ROOT / "dist" / "RailCar.fmu"))
    ap.add_argument("--cycles", type=int, default=1000)
    ap.add_argument("--leak-failed", action="store_true",
                    help="never free a failed instance (pythonfmu's binary crashes when it is freed)")
    ap.add_argument("--json", action="store_true", help="print the results as one JSON line")
    ap.add_argument("--phase", choices=("cycles", "failed"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.phase:
        phase(args.fmu, args.phase, args.cycles, args.leak_failed)
        return 0
    fmu = Path(args.fmu)
    if not fmu.is_file():
        raise SystemExit(f"{fmu} not found (python build.py)")
    results = {"fmu": str(fmu), "binary": which_binary(fmu),
               "phases": [measure(fmu, k, args.cycles, args.leak_failed) for k in ("cycles", "failed")]}
    if args.json:
        print(json.dumps(results))
        return 0
    print(f"{fmu} -- linux64 binary: {results['binary']}; {args.cycles} cycles after {WARMUP} "
          "warm-up cycles; VmRSS")
    labels = {"cycles": "instantiate + free",
              "failed": "failed init + " + ("leak (never freed)" if args.leak_failed else "free")}
    print(f"  {'phase':32s} {'RSS start':>10s} {'RSS end':>10s} {'growth/cycle':>13s} "
          f"{'2nd half':>11s}   quarters (kB)")
    for r in results["phases"]:
        if "crashed" in r:
            print(f"  {labels[r['kind']]:32s} CRASHED ({r['crashed']}) after {r['after_cycles']} "
                  f"measured cycles (+{WARMUP} warm-up)")
            continue
        quarters = " ".join(str(kb) for _, kb in r["samples"])
        print(f"  {labels[r['kind']]:32s} {r['rss_start_kb']:>7d} kB {r['rss_end_kb']:>7d} kB "
              f"{r['growth_kb_per_cycle']:>10.2f} kB {r['second_half_kb_per_cycle']:>8.2f} kB   "
              f"{quarters}" + (f"   (then {r['died_at_exit']} at exit)" if "died_at_exit" in r else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())

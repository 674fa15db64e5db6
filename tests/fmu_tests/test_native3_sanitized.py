"""The native FMI 3.0 glue (fmu_src/c/fmi3_glue.c) on BOTH backends (native_railcar.c,
native_estimator.c) under ASan/UBSan/LSan, with no Python in the process: a plain C host
(tests/fmu_cases/native3_cycles.c) linked with the glue, the backend and models/core/*.c (the
sources fmu_src.build.native_fmi3.c_sources lists), all built with -fsanitize=address,undefined
-fno-sanitize-recover=all and run with LeakSanitizer on. The FMI 2 twin of this file is
tests/fmu_tests/test_native_sanitized.py. The native AtoController (native_ato.c, issue 30)
behind the same glue gets its own host on a short span (tests/fmu_cases/native_ato_cycles.c
with -DATO_FMI3: a bad input, a discarded step, reset, failed initialisations, 200 cycles).

What the host checks (it exits 1 naming the failed line otherwise), per backend:
- the bad-input catalogue: NaN, +inf and -inf forces, negative traction and brake forces, a step
  of 0 and < 0, a time that jumps ahead or goes back -> fmi3Discard with "step discarded: "
  naming the variable (the step size, the time), terminateSimulation false,
  lastSuccessfulTime = currentCommunicationPoint, the outputs and "time" unchanged; the next
  good step fmi3OK and bit-identical (every output, float64 bit patterns) to a clean run;
- fmi3Reset after a run with another parameter, a grade profile and a discard gives outputs
  bit-identical to a fresh instance over 200 steps; one input one ulp off does differ;
- 100 failed initialisations (a bad parameter, a missing profile file, a profile with a bad
  line 3) -> fmi3ExitInitializationMode fmi3Error naming the parameter (file and line); in
  the error state get works and doStep / set / enter- and exitInitializationMode are refused;
  then (terminate and) reset, a good initialisation, a step, free;
- the glue's refusals on a live instance, in each state (instantiated, initialization mode,
  step mode, terminated): calls in the wrong state (getFloat64 / doStep before initialisation,
  terminate before step mode, a fixed parameter set in step mode, anything after terminate
  but get and reset), non-finite startTime and stopTime < startTime, unknown value references
  (n+1, 100000, 2^32-1), wrong type accessors (Int32 <-> Float64 <-> String, and every FMI 3
  type we have no variable of: Float32 ... UInt64, Boolean, Binary, Clock), nValues !=
  nValueReferences, NULL arrays, a NULL string, bad UTF-8, setting an output or "time", unknown
  or NULL log categories, NULL doStep out-arguments, a multi-variable set with one bad
  reference (sets none), and every function the FMU does not provide (FMU state, serialisation,
  derivatives, dependencies, configuration / event / step mode, model exchange, scheduled
  execution, clocks) -> fmi3Error with the reason logged (status Error, category
  logStatusError, the host's instanceEnvironment); out-arguments untouched. A twin instance
  gets the same good calls only: after the refusals every good step is fmi3OK and bit-identical
  to the twin's (the "twin_control" run, one input one ulp off, proves that comparison fails);
- instantiation: model exchange and scheduled execution, a wrong and a NULL token, relative /
  http / empty resource paths (and a 3,000-character one with '%' in it, logged unchanged),
  a NULL or empty name, eventModeUsed, required intermediate variables -> NULL with the reason
  logged (or nothing called without a logger); accepted: no trailing '/', file:, file:// and
  file://localhost forms, a resources folder with no modelDescription.xml beside it (the glue
  then cannot check the token and takes any, as it documents); loggingOn; an instance without
  a logger; fmi3FreeInstance(NULL), a double free, and 13 calls each on NULL, a freed instance,
  a 1-byte heap block and a stack address -> fmi3Error, the logger never called, the pointer
  never read (ASan would report the read);
- 1,000 cycles instantiate / initialise with a grade profile (its path in a 4 KB host buffer) /
  20 steps / a refused set / terminate / free, plus a refused instantiation per cycle.

Memory is judged as in the FMI 2 test: LeakSanitizer at exit; ASan's live heap bytes
(__sanitizer_get_current_allocated_bytes, quarantine excluded) after cycles 100 and 1000,
exactly equal; the RSS growth over cycles 100..1000 with quarantine_size_mb=1 below 1 MB
(measured over six runs: +64 KB RailCar every time, +156..368 KB RailCarEstimator; why 1 MB:
see tests/fmu_tests/test_native_sanitized.py). Two leak controls prove these checks can fail:
- the host not freeing its 4 KB path buffer each cycle: LeakSanitizer reports it at
  native3_cycles.c, live bytes grow by 900 x 4096 exactly, RSS by ~5 MB;
- the host not calling fmi3FreeInstance: LeakSanitizer sees NOTHING (the glue's registry of
  live instances keeps every one reachable), but live bytes grow ~12 KB a cycle and RSS ~16 MB:
  the live-byte equality is the check that catches a leaked instance.

FMI 3.0 lets a host pass resourcePath = NULL ("resourcePath must be NULL, if no resource path
can be provided to the FMU"; "If the FMU cannot work without content of the resources folder,
fmi3Instantiate must return NULL" -- FMI 3.0.2, section 2.3.1). Ours works without it (no
profile by default; a relative profile is then looked up in the working directory,
fmu_src/c/native_common.c resolve_profile_path), so it instantiates.

The runs take well under a second each; the parallel compilation dominates.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from conftest import ROOT
from sanitizer_runs import (ASAN_DEFAULT, ASAN_SMALL_QUARANTINE, RSS_GROWTH_LIMIT_KB, check_ato_host,
                            clean, no_sanitizer_report, run_host)
from fmu_src.build import native_fmi3, toolchain

# conftest.layer_of marks modules named test_native_* as "core"; this one (test_native3_*) is
# not matched there, so it says so itself (slow: it compiles C).
pytestmark = [pytest.mark.core, pytest.mark.slow]

HOST = ROOT / "tests" / "fmu_cases" / "native3_cycles.c"
ATO_HOST = ROOT / "tests" / "fmu_cases" / "native_ato_cycles.c"
TOKEN = "{native3-cycles-test}"
BACKENDS = {"railcar": native_fmi3.RAILCAR_SPEC, "estimator": native_fmi3.ESTIMATOR_SPEC}
CYCLES = 900                       # cycles between the two measurements (100 -> 1000)


def _compile_all(out: Path) -> dict[str, Path]:
    """Every source to an object once (in parallel), then one executable per backend and the
    two leaking controls (RailCar)."""
    cc = toolchain.find_compiler()
    assert cc, "no C compiler"
    flags = ["-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-pedantic",
             "-Werror", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-pthread",
             "-I", str(toolchain.C_DIR), "-I", str(toolchain.CORE_DIR),
             "-I", str(toolchain.fmi_headers())]
    backends = {spec.backend for spec in BACKENDS.values()}
    shared = sorted({s for spec in BACKENDS.values() for s in native_fmi3.c_sources(spec)
                     if s.name not in backends})
    assert any(s.name == native_fmi3.GLUE3_SOURCE for s in shared)
    assert not any(s.name == "fmi2_glue.c" for s in shared)
    jobs = {s.stem: (s, []) for s in shared}
    for spec in BACKENDS.values():
        jobs[Path(spec.backend).stem] = (toolchain.C_DIR / spec.backend, [])
    jobs["host_railcar"] = (HOST, [])
    jobs["host_estimator"] = (HOST, ["-DNATIVE_ESTIMATOR"])
    jobs["host_leak_host"] = (HOST, ["-DNATIVE3_LEAK_HOST"])
    jobs["host_leak_instance"] = (HOST, ["-DNATIVE3_LEAK_INSTANCE"])
    for s in native_fmi3.ato_c_sources():        # the AtoController's own files, however many
        jobs.setdefault(s.stem, (s, []))
    jobs["host_ato"] = (ATO_HOST, ["-DATO_FMI3"])

    def compile_one(item):
        stem, (src, defs) = item
        obj = out / f"{stem}.o"
        proc = subprocess.run([*cc, *flags, *defs, "-c", str(src), "-o", str(obj)],
                              capture_output=True, text=True)
        assert proc.returncode == 0, f"{stem}: {proc.stderr}"
        return stem, obj

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        objs = dict(pool.map(compile_one, jobs.items()))

    def link(item):
        name, (host, backend) = item
        exe = out / f"native3_cycles_{name}"
        # the AtoController links its own sources (no native_common.c, native_state.c)
        rest = ([s for s in native_fmi3.ato_c_sources() if s.stem != backend] if name == "ato"
                else shared)
        proc = subprocess.run([*cc, "-fsanitize=address,undefined", "-pthread", str(objs[host]),
                               str(objs[backend]), *[str(objs[s.stem]) for s in rest],
                               "-o", str(exe), "-lm"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        return name, exe

    links = {"railcar": ("host_railcar", "native_railcar"),
             "estimator": ("host_estimator", "native_estimator"),
             "leak_host": ("host_leak_host", "native_railcar"),
             "leak_instance": ("host_leak_instance", "native_railcar"),
             "ato": ("host_ato", "native_ato")}
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        return dict(pool.map(link, links.items()))


@pytest.fixture(scope="module")
def hosts(tmp_path_factory) -> dict:
    """The executables, and their arguments: a resources folder (with profiles/steep_grades.csv)
    beside a modelDescription.xml carrying TOKEN, a grade profile whose line 3 is bad, and a
    resources folder with no modelDescription.xml beside it."""
    tmp = tmp_path_factory.mktemp("native3_cycles")
    fmu, bare = tmp / "fmu", tmp / "bare"
    for folder in (fmu, bare):
        (folder / "resources" / "profiles").mkdir(parents=True)
        shutil.copy(ROOT / "scenarios" / "profiles" / "steep_grades.csv",
                    folder / "resources" / "profiles" / "steep_grades.csv")
    (fmu / "modelDescription.xml").write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="3.0" '
        f'modelName="cycles3" instantiationToken="{TOKEN}">\n</fmiModelDescription>\n',
        encoding="utf-8")
    bad = tmp / "bad_grades.csv"
    bad.write_text("distance_m,grade_permille\n0,0\n200,abc\n700,0\n", encoding="utf-8")
    return {"exes": _compile_all(tmp),
            "args": [f"{(fmu / 'resources').resolve()}/", TOKEN, str(bad.resolve()),
                     f"{(bare / 'resources').resolve()}/"]}


def _run(hosts, name: str, mode: str = "main", asan_options: str = ASAN_DEFAULT):
    return run_host(hosts["exes"][name], [mode, *hosts["args"]], asan_options)


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_catalogue_refusals_and_cycles_clean_under_sanitizers(hosts, backend):
    proc, figures = _run(hosts, backend)
    clean(proc)
    out = proc.stdout
    assert "bad_inputs 9 discarded, each followed by a good step bit-identical" in out, out
    assert re.search(r"^reset 200 steps x \d+ outputs bit-identical to a fresh instance; "
                     r"one ulp off differs from step \d+$", out, re.M), out
    assert "failed_inits 100 refused naming the parameter or file and line" in out, out
    refusals = re.search(r"^refusals (\d+) on a live instance.*; (\d+) good steps", out, re.M)
    assert refusals and int(refusals[1]) >= 700 and int(refusals[2]) == 50, out
    dead = re.search(r"^instantiation_and_dead (\d+) refusals", out, re.M)
    assert dead and int(dead[1]) >= 4 * 13 + 12, out   # 13 calls x 4 dead pointers + 12 NULLs
    assert "cycles 1000" in out, out
    live = figures["live_bytes"]
    assert set(live) == {100, 1000}, out
    assert live[1000] == live[100], f"live heap bytes after cycle 100 / 1000: {live}"
    print(f"{backend}: {refusals[1]} refusals on live instances, {dead[1]} at instantiation or "
          f"on dead ones; live heap bytes after cycles 100/1000 {live[100]}/{live[1000]}")


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_rss_flat_over_1000_cycles(hosts, backend):
    proc, figures = _run(hosts, backend, asan_options=ASAN_SMALL_QUARANTINE)
    clean(proc)
    rss = figures["rss_kb"]
    assert set(rss) == {100, 1000}, proc.stdout
    growth = rss[1000] - rss[100]
    print(f"{backend}: RSS after cycle 100 {rss[100]} KB, after cycle 1000 {rss[1000]} KB "
          f"(+{growth} KB)")
    assert growth < RSS_GROWTH_LIMIT_KB, f"RSS grew {growth} KB over cycles 100..1000: {rss}"


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_the_twin_comparison_sees_one_ulp(hosts, backend):
    """Negative control for the refusal runs: the same run with the first input one ulp off on
    one twin must fail its bit-identity check (so 'a refused call changed nothing' is tested)."""
    proc, _ = _run(hosts, backend, mode="twin_control")
    no_sanitizer_report(proc)
    assert proc.returncode == 1, proc.stdout[-2000:]
    assert re.search(r"^FAILED line \d+: after refused calls, step \d+ differs from the twin",
                     proc.stdout, re.M), proc.stdout[-2000:]


def test_a_leaked_host_buffer_is_caught(hosts):
    """Negative control: 4 KB a cycle the host does not free is reported by LeakSanitizer at
    the leaking line, and seen by the live-byte count and the RSS bound."""
    proc, figures = _run(hosts, "leak_host", asan_options=ASAN_SMALL_QUARANTINE)
    assert proc.returncode != 0
    assert "LeakSanitizer: detected memory leaks" in proc.stderr, proc.stderr[-3000:]
    assert re.search(r"in cycles .*native3_cycles\.c:\d+", proc.stderr), proc.stderr[-3000:]
    live, rss = figures["live_bytes"], figures["rss_kb"]
    assert live[1000] - live[100] == CYCLES * 4096, live
    assert rss[1000] - rss[100] >= RSS_GROWTH_LIMIT_KB, rss


def test_a_leaked_instance_is_caught_by_the_live_byte_count(hosts):
    """Negative control: the host never calling fmi3FreeInstance. LeakSanitizer cannot see it
    (the glue's registry keeps every live instance reachable), so this is what the live-byte
    equality is for; the RSS bound sees it too."""
    proc, figures = _run(hosts, "leak_instance", asan_options=ASAN_SMALL_QUARANTINE)
    no_sanitizer_report(proc)            # LeakSanitizer is blind to it, as said
    assert proc.stdout.rstrip().endswith("ok"), proc.stdout[-2000:]
    live, rss = figures["live_bytes"], figures["rss_kb"]
    per_cycle = (live[1000] - live[100]) / CYCLES
    print(f"leaked instance: {per_cycle:.0f} live bytes a cycle, RSS +{rss[1000] - rss[100]} KB")
    assert per_cycle >= 4096, live        # an instance: its table of 84 variables, the chain...
    assert rss[1000] - rss[100] >= RSS_GROWTH_LIMIT_KB, rss


def test_a_null_resource_path_is_accepted(hosts):
    """FMI 3.0: resourcePath may be NULL; the FMU must then instantiate unless it cannot work
    without its resources (ours can)."""
    proc, _ = _run(hosts, "railcar", mode="null_resources")
    no_sanitizer_report(proc)
    clean(proc)
    assert "null_resources instantiated, 20 steps" in proc.stdout, proc.stdout


def test_the_atocontroller_on_a_short_span_clean_under_sanitizers(hosts):
    """native_ato.c behind the FMI 3 glue (tests/fmu_cases/native_ato_cycles.c -DATO_FMI3,
    fmi3GetBoolean / fmi3SetBoolean included): a clean run, a bad input (the safe brake, a
    warning naming it), a discarded step, reset bit-identical to a fresh instance (and one ulp
    off differing), 20 refused initialisations, 200 cycles; no sanitizer report, no leak, the
    live heap bytes equal after cycles 20 and 200."""
    check_ato_host(*run_host(hosts["exes"]["ato"], hosts["args"][:2], ASAN_DEFAULT))

"""Issue 18's bad-input catalogue, Reset and 1,000 instantiate/free cycles on BOTH native FMI 2.0
backends (native_railcar.c, native_estimator.c), with no Python in the process: a plain C host
(tests/fmu_cases/native_cycles.c) linked with the glue, the backend and models/core/*.c, all
built with -fsanitize=address,undefined -fno-sanitize-recover=all, run with LeakSanitizer on.
The native AtoController (native_ato.c, issue 30) gets its own host on a short span
(tests/fmu_cases/native_ato_cycles.c: a bad input, a discarded step, reset, failed
initialisations, 200 cycles; see its header), from the same objects.

What the host checks (it exits 1 naming the failed line otherwise), per backend:
- NaN, +inf and -inf forces, negative traction and brake forces, a step of 0, a negative step,
  a time that jumps ahead or goes back -> fmi2Discard with "step discarded: " naming the variable
  (the step size, the time), the outputs unchanged, the next good step fmi2OK, and after every
  good step the outputs are bit-identical to a run that never saw a bad input;
- fmi2Reset after a run with another parameter (and a grade profile, a discard) gives outputs
  bit-identical to a fresh instance over 200 steps; one input one ulp off does differ;
- 100 failed initialisations (a bad parameter, a missing profile file, a profile file with a
  bad line 3) -> fmi2Error naming the parameter (file and line), then reset, a good
  initialisation (some with a grade profile), a step, free;
- 1,000 cycles instantiate (GUID checked against a modelDescription.xml) / setup / enter + exit
  initialisation with a grade profile / 20 steps / terminate / free.

Memory is judged three ways:
- LeakSanitizer at exit (ASAN_OPTIONS=detect_leaks=1): no leak report at all;
- ASan's count of live heap bytes (__sanitizer_get_current_allocated_bytes, quarantine
  excluded) after cycle 100 and after cycle 1000: exactly equal;
- the resident set size (/proc/self/statm) after cycle 100 and after cycle 1000 grows by less
  than 1 MB. Why 1 MB: one cycle allocates and frees about 40 KB (an instance, its variable
  table, the chain, the profile; measured through ASan's quarantine, which keeps freed memory
  resident: with the default 256 MB quarantine the RSS grows ~38 MB over those 900 cycles
  without any leak). So the RSS run sets quarantine_size_mb=1, and then the RSS moves by a
  steady 64 KB (RailCar) / 324 KB (RailCarEstimator) (allocator size classes, the stack depot;
  the same figure on every run) -- the bound is 3x that noise, while leaking any
  one instance or chain per cycle would add >= 36 MB over 900 cycles, and leaking just 4 KB a
  cycle adds 3.6 MB (the negative control below shows it is caught by all three). Smaller leaks
  (a string) are below any RSS bound; the live-byte equality and LeakSanitizer catch those.

The runs use the default quarantine for the catalogue (use-after-free found at full strength)
and are each well under a second; the parallel compilation dominates (the file takes ~8 s).
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
                            clean, run_host)
from fmu_src.build import native, toolchain

HOST = ROOT / "tests" / "fmu_cases" / "native_cycles.c"
ATO_HOST = ROOT / "tests" / "fmu_cases" / "native_ato_cycles.c"
GUID = "{native-cycles-test}"
BACKENDS = {"railcar": native.RAILCAR_SPEC, "estimator": native.ESTIMATOR_SPEC}


def _compile_all(out: Path) -> dict[str, Path]:
    """Every source to an object once (in parallel), then one executable per backend and the
    leaking control (RailCar)."""
    cc = toolchain.find_compiler()
    assert cc, "no C compiler"
    flags = ["-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-pedantic",
             "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-pthread",
             "-I", str(native.C_DIR), "-I", str(native.CORE_DIR), "-I", str(toolchain.fmi_headers())]
    shared = sorted({s for spec in BACKENDS.values() for s in native.c_sources(spec)
                     if s.name not in {spec.backend for spec in BACKENDS.values()}})
    jobs = {s.stem: ([str(s)], []) for s in shared}
    for name, spec in BACKENDS.items():
        jobs[Path(spec.backend).stem] = ([str(native.C_DIR / spec.backend)], [])
    jobs["host_railcar"] = ([str(HOST)], [])
    jobs["host_estimator"] = ([str(HOST)], ["-DNATIVE_ESTIMATOR"])
    jobs["host_leak"] = ([str(HOST)], ["-DNATIVE_CYCLES_LEAK"])
    for s in native.ato_c_sources():             # the AtoController's own files, however many
        jobs.setdefault(s.stem, ([str(s)], []))
    jobs["host_ato"] = ([str(ATO_HOST)], [])

    def compile_one(item):
        stem, (src, defs) = item
        obj = out / f"{stem}.o"
        proc = subprocess.run([*cc, *flags, *defs, "-c", *src, "-o", str(obj)],
                              capture_output=True, text=True)
        assert proc.returncode == 0, f"{stem}: {proc.stderr}"
        return stem, obj

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 4) as pool:
        objs = dict(pool.map(compile_one, jobs.items()))
    exes = {}
    for name, host, backend in (("railcar", "host_railcar", "native_railcar"),
                                ("estimator", "host_estimator", "native_estimator"),
                                ("leak", "host_leak", "native_railcar")):
        exe = out / f"native_cycles_{name}"
        proc = subprocess.run([*cc, "-fsanitize=address,undefined", "-pthread", str(objs[host]),
                               str(objs[backend]), *[str(objs[s.stem]) for s in shared],
                               "-o", str(exe), "-lm"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        exes[name] = exe
    # the AtoController: its own sources (the glue, glue_common.c, native_ato.c, the core)
    ato = [objs[s.stem] for s in native.ato_c_sources()]
    exe = out / "native_ato_cycles"
    proc = subprocess.run([*cc, "-fsanitize=address,undefined", "-pthread", str(objs["host_ato"]),
                           *[str(o) for o in ato], "-o", str(exe), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    exes["ato"] = exe
    return exes


@pytest.fixture(scope="module")
def hosts(tmp_path_factory) -> dict:
    """The executables, and the arguments: a resources folder beside a modelDescription.xml
    carrying GUID, profiles/steep_grades.csv in it, and a grade profile whose line 3 is bad."""
    tmp = tmp_path_factory.mktemp("native_cycles")
    fmu = tmp / "fmu"
    (fmu / "resources" / "profiles").mkdir(parents=True)
    shutil.copy(ROOT / "scenarios" / "profiles" / "steep_grades.csv",
                fmu / "resources" / "profiles" / "steep_grades.csv")
    (fmu / "modelDescription.xml").write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n<fmiModelDescription fmiVersion="2.0" '
        f'modelName="cycles" guid="{GUID}">\n</fmiModelDescription>\n', encoding="utf-8")
    bad = tmp / "bad_grades.csv"
    bad.write_text("distance_m,grade_permille\n0,0\n200,abc\n700,0\n", encoding="utf-8")
    exes = _compile_all(tmp)
    return {"exes": exes, "args": [(fmu / "resources").resolve().as_uri(), GUID, str(bad)]}


def _run(hosts, name: str, asan_options: str):
    return run_host(hosts["exes"][name], hosts["args"], asan_options)


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_catalogue_reset_failed_inits_and_cycles_clean_under_sanitizers(hosts, backend):
    proc, figures = _run(hosts, backend, ASAN_DEFAULT)
    clean(proc)
    out = proc.stdout
    assert "bad_inputs 9 discarded, each followed by a good step" in out, out
    assert re.search(r"^reset 200 steps x \d+ outputs bit-identical to a fresh instance; "
                     r"one ulp off differs from step \d+$", out, re.M), out
    assert "failed_inits 100 refused naming the parameter or file and line" in out, out
    assert "cycles 1000" in out
    live = figures["live_bytes"]
    assert set(live) == {100, 1000}, out
    assert live[1000] == live[100], f"live heap bytes after cycle 100 / 1000: {live}"
    print(f"{backend}: live heap bytes after cycles 100/1000 {live[100]}/{live[1000]}; "
          f"RSS (default quarantine) {figures['rss_kb']} KB")


@pytest.mark.parametrize("backend", sorted(BACKENDS))
def test_rss_flat_over_1000_cycles(hosts, backend):
    proc, figures = _run(hosts, backend, ASAN_SMALL_QUARANTINE)
    clean(proc)
    rss = figures["rss_kb"]
    assert set(rss) == {100, 1000}, proc.stdout
    growth = rss[1000] - rss[100]
    print(f"{backend}: RSS after cycle 100 {rss[100]} KB, after cycle 1000 {rss[1000]} KB "
          f"(+{growth} KB)")
    assert growth < RSS_GROWTH_LIMIT_KB, f"RSS grew {growth} KB over cycles 100..1000: {rss}"


def test_the_checks_see_a_leak_of_4_kb_a_cycle(hosts):
    """Negative control: the host leaking 4 KB a cycle is caught by LeakSanitizer, by the
    live-byte count and by the RSS bound (so the three checks above are not vacuous)."""
    proc, figures = _run(hosts, "leak", ASAN_SMALL_QUARANTINE)
    assert proc.returncode != 0
    assert "LeakSanitizer: detected memory leaks" in proc.stderr, proc.stderr[-3000:]
    assert "native_cycles.c" in proc.stderr           # the report points at the leaking line
    live, rss = figures["live_bytes"], figures["rss_kb"]
    assert live[1000] - live[100] >= 900 * 4096, live
    assert rss[1000] - rss[100] >= RSS_GROWTH_LIMIT_KB, rss


def test_the_atocontroller_on_a_short_span_clean_under_sanitizers(hosts):
    """native_ato.c behind the FMI 2 glue (tests/fmu_cases/native_ato_cycles.c): a clean run, a
    bad input (the safe brake, a warning naming it), a discarded step, reset bit-identical to a
    fresh instance (and one ulp off differing), 20 refused initialisations, 200 cycles; no
    sanitizer report, no leak, the live heap bytes equal after cycles 20 and 200."""
    check_ato_host(*run_host(hosts["exes"]["ato"], hosts["args"][:2], ASAN_DEFAULT))

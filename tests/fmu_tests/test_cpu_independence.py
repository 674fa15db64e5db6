"""The outputs do not depend on the CPU: station_day through the native RailCar and the pythonfmu
RailCar gives the same bytes whichever libm variant glibc picks (it chooses exp/log/pow per CPU:
``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA`` makes this machine take the variant of a CPU
without FMA and AVX2). The model computes squares as x * x and exp/expm1/log with models.fpmath,
from IEEE operations only; what stays on libm is stated in the README's "Randomness" paragraph
(the noise's rare tail draws, equal to numpy's generator)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

OTHER_CPU = {**os.environ, "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA"}
SCENARIO = ROOT / "scenarios" / "library" / "station_day.toml"
LIBM_PROBE = ("import math, hashlib; print(hashlib.sha256(repr([math.exp(-i / 977.0)"
              " for i in range(1, 200000)]).encode()).hexdigest())")


def libm_switches() -> bool:
    """Does the tunable change libm's results on this CPU (else the comparison proves nothing)?"""
    runs = [subprocess.run([sys.executable, "-c", LIBM_PROBE], capture_output=True, text=True,
                           check=True, env=env).stdout for env in (os.environ, OTHER_CPU)]
    return runs[0] != runs[1]


def run_csv(fmu: str, dist, out, env) -> bytes:
    proc = subprocess.run([sys.executable, "-m", "harness", "run", str(SCENARIO), "--fmu", fmu,
                           "--dist", str(dist), "--out", str(out)],
                          capture_output=True, text=True, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    return (out / "station_day_result.csv").read_bytes()


@pytest.mark.parametrize("fmu", ["native", "python"])
def test_station_day_is_bit_identical_under_the_other_libm_variant(built_fmus, tmp_path, fmu):
    if not libm_switches():
        pytest.skip("not checked on this machine: its CPU has one libm variant (no FMA/AVX2), "
                    "GLIBC_TUNABLES switches nothing")
    dist = built_fmus["RailCar"].parent
    here = run_csv(fmu, dist, tmp_path / "here", os.environ)
    other = run_csv(fmu, dist, tmp_path / "other", OTHER_CPU)
    assert len(here.splitlines()) > 1000                       # the whole day, full precision
    assert here == other

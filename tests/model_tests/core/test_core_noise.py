"""The C noise streams (models/core/noise.c) against numpy, draw for draw.

First piece of the C model core: the chain's noise streams, SeedSequence(seed).spawn(4)[child]
-> PCG64 -> standard normal, must give the very doubles models/plant/noise.py gives, so that the C
chain can be bit-identical to the Python reference. Compiled here with gcc (-Werror, no FMA).
"""
from __future__ import annotations

import ctypes
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from models.plant.noise import noise_streams

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
STREAMS = ("process", "speed_sensor", "position_sensor", "track_sensor")   # models/chain.py's
N = 10 ** 6


@pytest.fixture(scope="module")
def noise_lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core (it is on every machine we support)"
    lib = tmp_path_factory.mktemp("core") / "libnoise.so"
    subprocess.run([gcc, "-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-pedantic", "-fPIC", "-shared", str(CORE / "noise.c"), "-o", str(lib), "-lm"],
                   check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(lib))
    dll.rc_stream_seed.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint32]
    dll.rc_stream_normal.argtypes = [ctypes.c_void_p]
    dll.rc_stream_normal.restype = ctypes.c_double
    dll.rc_stream_fill.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long]
    return dll


class CStream:
    """A rc_stream in a 16-byte-aligned buffer (the struct holds 128-bit integers)."""

    def __init__(self, lib, seed: int, child: int):
        self._buf = ctypes.create_string_buffer(32 + 16)
        self.ptr = (ctypes.addressof(self._buf) + 15) & ~15
        self.lib = lib
        lib.rc_stream_seed(self.ptr, seed, child)

    def draws(self, n: int) -> np.ndarray:
        out = np.empty(n)
        self.lib.rc_stream_fill(self.ptr, out.ctypes.data, n)
        return out


def test_the_ziggurat_header_is_what_the_generator_computes():
    proc = subprocess.run([sys.executable, str(CORE / "gen_ziggurat.py"), "--check"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize("seed", [0, 1, 17, 2 ** 31 - 1])
def test_every_stream_of_the_chain_equals_numpy_for_a_million_draws(noise_lib, seed):
    streams = noise_streams(seed, STREAMS)
    for child, name in enumerate(STREAMS):
        ours = CStream(noise_lib, seed, child).draws(N)
        theirs = streams[name]._rng.standard_normal(N)          # the stream's own generator
        assert np.array_equal(ours.view(np.uint64), theirs.view(np.uint64)), (seed, name)


def test_single_draws_continue_the_stream_as_numpys_blocks_do(noise_lib):
    """models/plant/noise.py draws in blocks of 4096; the C stream draw by draw gives the same."""
    stream = noise_streams(5, STREAMS)["speed_sensor"]
    c = CStream(noise_lib, 5, 1)
    for _ in range(10_000):
        assert noise_lib.rc_stream_normal(c.ptr) == stream()


SANITIZED_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include "noise.h"
int main(int argc, char **argv)
{
    rc_stream s;                       /* on the stack: any alignment bug shows */
    if (argc != 4) return 2;
    long n = atol(argv[3]);
    rc_stream_seed(&s, strtoull(argv[1], NULL, 10), (unsigned)atoi(argv[2]));
    double *out = malloc((size_t)n * sizeof *out);
    if (!out) return 2;
    rc_stream_fill(&s, out, n);
    fwrite(out, sizeof *out, (size_t)n, stdout);
    free(out);
    return 0;
}
"""


def test_the_streams_run_clean_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    """noise.c under -fsanitize=address,undefined (any report aborts): 10^5 draws of a stream,
    still equal to numpy's."""
    gcc = shutil.which("gcc")
    assert gcc
    (tmp_path / "main.c").write_text(SANITIZED_MAIN)
    exe = tmp_path / "draws"
    subprocess.run([gcc, "-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", f"-I{CORE}",
                    str(tmp_path / "main.c"), str(CORE / "noise.c"), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    proc = subprocess.run([str(exe), "17", "2", "100000"], capture_output=True,
                          env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    ours = np.frombuffer(proc.stdout, dtype=np.float64)
    theirs = noise_streams(17, STREAMS)["position_sensor"]._rng.standard_normal(100_000)
    assert np.array_equal(ours.view(np.uint64), theirs.view(np.uint64))

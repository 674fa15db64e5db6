"""The optional C model core (models/core/*.c) and its binding (models/_railcar.c), issue 17.

Everything else is configured in pyproject.toml. ``optional=True``: without a C compiler the
install still succeeds and the Python reference runs (same results, slower; models/compiled.py).
-ffp-contract=off: no fused multiply-add, so the C arithmetic rounds exactly like Python's (also
at link time: -flto optimises across the core's files there, +15 % steps/s; -O3 another +5 %,
neither changes a rounding: the bit-identity tests run on this build).
"""
from glob import glob

from setuptools import Extension, setup

CORE = sorted(glob("models/core/*.c"))
FLAGS = ["-O3", "-flto", "-ffp-contract=off", "-fno-fast-math"]

setup(ext_modules=[
    Extension("models._railcar", ["models/_railcar.c", *CORE], optional=True,
              extra_compile_args=["-std=c99", *FLAGS], extra_link_args=FLAGS),
    Extension("models._batch", ["models/_batch.c", *CORE], optional=True, extra_compile_args=["-std=c99", *FLAGS], extra_link_args=FLAGS),
])

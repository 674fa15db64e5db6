"""The optional C model core (models/core/*.c) and its binding (models/_railcar.c), issue 17.

Everything else is configured in pyproject.toml. ``optional=True``: without a C compiler the
install still succeeds and the Python reference runs (same results, slower; models/compiled.py).
-ffp-contract=off: no fused multiply-add, so the C arithmetic rounds exactly like Python's.
"""
from glob import glob

from setuptools import Extension, setup

CORE = sorted(glob("models/core/*.c"))

setup(ext_modules=[
    Extension("models._railcar", ["models/_railcar.c", *CORE], optional=True,
              extra_compile_args=["-std=c99", "-O2", "-ffp-contract=off", "-fno-fast-math"]),
])

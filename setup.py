"""The optional C kernels of the per-step path (models/_fastcore.c, issue 7).

Everything else is configured in pyproject.toml. ``optional=True``: without a C compiler the
install still succeeds and the pure-Python code runs (same results, slower).
-ffp-contract=off: no fused multiply-add, so the C arithmetic rounds exactly like Python's.
"""
from setuptools import Extension, setup

setup(ext_modules=[Extension("models._fastcore", ["models/_fastcore.c"], optional=True,
                             extra_compile_args=["-O2", "-ffp-contract=off", "-fno-fast-math"])])

"""The optional compiled per-step kernels (``models/_fastcore.c``), or None.

``core`` is the compiled module when it was built (``pip install -e .`` compiles it; a missing
compiler leaves it out and everything runs in Python). The Python code stays the reference:
each kernel is the body of one method, computing the same expressions in the same order, and
``tests/test_fastcore.py`` checks that every output of whole runs is bit-identical both ways.
Set the environment variable ``RAILCAR_PURE_PYTHON=1`` to run the Python code only.
"""
from __future__ import annotations

import os

from .units import G

core = None
if not os.environ.get("RAILCAR_PURE_PYTHON"):
    try:
        from . import _fastcore as core
        core.set_constants(G)
    except ImportError:      # not compiled (no compiler, or another Python): pure Python
        core = None

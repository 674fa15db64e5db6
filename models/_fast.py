"""The optional compiled per-step kernels (``models/_fastcore.c``), or None.

``core`` is the compiled module when it was built (``pip install -e .`` compiles it; a missing
compiler leaves it out and everything runs in Python). The Python code stays the reference:
each kernel is the body of one method, computing the same expressions in the same order, and
``tests/test_fastcore.py`` checks that every output of whole runs is bit-identical both ways.
Set the environment variable ``RAILCAR_PURE_PYTHON=1`` to run the Python code only.

A method replaced on an instance or a class is honoured (the Python code then runs: the core
checks, see ``guard_ok`` in the C source); so is a module-level function of these modules
replaced before the object using it is built (``core_for_new_object``: objects bind the core
when they are built; replacing a module function later is not seen).
"""
from __future__ import annotations

import inspect
import os
import sys

from .units import G

core = None
if not os.environ.get("RAILCAR_PURE_PYTHON"):
    try:
        from . import _fastcore as core
        core.set_constants(G)
    except ImportError:      # not compiled (no compiler, or another Python): pure Python
        core = None


_ORIGINALS: dict[str, dict[str, object]] = {}   # module -> its functions and classes at import


def remember(module_name: str) -> None:
    """Note the module's functions and classes as imported (the first call wins): the compiled
    kernels replicate them, so a later replacement must send the work to Python."""
    if module_name in _ORIGINALS:
        return
    names = {k: v for k, v in vars(sys.modules[module_name]).items()
             if (inspect.isfunction(v) or inspect.isclass(v)) and v.__module__ == module_name}
    _ORIGINALS[module_name] = names
    if core is not None:
        core.remember_classes(*(v for v in names.values() if inspect.isclass(v)))


def unpatched() -> bool:
    """True when no remembered function or class was replaced in its module."""
    return all(vars(sys.modules[m]).get(k) is v for m, names in _ORIGINALS.items() for k, v in names.items())


def core_for_new_object():
    """The core for an object being built now: None when it is off or a function or class of
    these modules was replaced (then the object runs Python)."""
    return core if core is not None and unpatched() else None

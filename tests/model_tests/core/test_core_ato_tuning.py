"""The C interface of the ATO (models/core/ato_tuning.c) against models/ato/interface.py:
INPUTS / STATED_INPUTS in order with their priors, the AtoMode codes, AtoTuning's fields in
order with their kinds and defaults (bit for bit), and AtoTuning.__post_init__'s refusals,
message for message.

Every field is set, alone, to values at and one ulp beyond each of its bounds (>= 0, > 0,
UPPER_BOUNDS, mass_band's [1, 5], est_gate >= 1, time_reserve <= 0.2, the shares <= 1, the
integers' [1, 32] and >= 1, the bools' 0/1) and to NaN, +-inf, +-0, subnormals and random
values; then seeded random tunings with several bad fields (the first in AtoTuning's order
must be named). Python's ValueError text and C's message must be equal, with "tuning." and with
the FMU's "ato." (fmu_src.adapter._fmu_names). Compiled here with gcc (-Werror, no FMA) through
tests/core_cases/ato_tuning_shim.c; the shim as a program under -fsanitize=address,undefined
checks every case again.
"""
from __future__ import annotations

import ctypes
import math
import random
import shutil
import struct
import subprocess
from dataclasses import fields
from pathlib import Path

import pytest

from fmu_src.adapter import _fmu_names
from models.ato.interface import (INPUTS, MAX_EP_STAGES, STATED_INPUTS, UPPER_BOUNDS, AtoMode,
                                  AtoTuning)

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_tuning_shim.c"
SOURCES = [CORE / "ato_tuning.c", CORE / "repr.c"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
         "-fPIC"]
SANITIZE = ["-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
RC_OK, RC_BAD_CONFIG = 0, 2
KINDS = {"bool": 0, "int": 1, "float": 2}
FIELDS = fields(AtoTuning)
NAMES = [f.name for f in FIELDS]
MSG = 256


def build(out: Path, extra: list[str]) -> None:
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    proc = subprocess.run([gcc, *FLAGS, *extra, f"-I{CORE}", *map(str, SOURCES), str(SHIM), "-o",
                           str(out), "-lm"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    out = tmp_path_factory.mktemp("core") / "libato_tuning.so"
    build(out, ["-shared"])
    dll = ctypes.CDLL(str(out))
    dll.shim_input_name.restype = ctypes.c_char_p
    dll.shim_input_name.argtypes = [ctypes.c_int]
    dll.shim_stated_prior.restype = ctypes.c_double
    dll.shim_stated_prior.argtypes = [ctypes.c_int]
    dll.shim_field.restype = ctypes.c_char_p
    dll.shim_field.argtypes = [ctypes.c_int, ctypes.POINTER(ctypes.c_int),
                               ctypes.POINTER(ctypes.c_long)]
    dll.shim_field_named.argtypes = [ctypes.c_char_p]
    dll.shim_defaults.argtypes = [ctypes.POINTER(ctypes.c_double)]
    dll.shim_validate.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_char_p,
                                  ctypes.c_char_p, ctypes.c_int]
    return dll


def bits(x: float) -> bytes:
    return struct.pack("<d", float(x))


def c_validate(lib, values: list[float], prefix: str | None) -> tuple[int, str]:
    arr = (ctypes.c_double * len(values))(*values)
    buf = ctypes.create_string_buffer(MSG)
    st = lib.shim_validate(arr, prefix.encode() if prefix else None, buf, MSG)
    assert st in (RC_OK, RC_BAD_CONFIG), f"shim status {st}"
    return st, buf.value.decode()


def python_value(field, x: float):
    """The value an FMU host gives AtoTuning for this field: a bool for 0/1 bool fields (an
    int otherwise), an int for int fields, a float else."""
    if field.type == "bool":
        return bool(x) if x in (0.0, 1.0) else int(x)
    if field.type == "int":
        return int(x)
    return float(x)


def python_message(changes: dict[str, float]) -> str | None:
    by_name = {f.name: f for f in FIELDS}
    try:
        AtoTuning(**{n: python_value(by_name[n], x) for n, x in changes.items()})
    except ValueError as e:
        return str(e)
    return None


def c_values(changes: dict[str, float]) -> list[float]:
    defaults = AtoTuning()
    return [float(changes.get(f.name, getattr(defaults, f.name))) for f in FIELDS]


def assert_same(lib, changes: dict[str, float]) -> str | None:
    """C's verdict and message equal Python's, under both prefixes; Python's message."""
    py = python_message(changes)
    values = c_values(changes)
    for prefix, want in ((None, py), ("tuning.", py),
                         ("ato.", None if py is None else _fmu_names(py, False))):
        st, msg = c_validate(lib, values, prefix)
        if want is None:
            assert (st, msg) == (RC_OK, ""), f"{changes}: Python accepts, C says {msg!r}"
        else:
            assert st == RC_BAD_CONFIG, f"{changes}: Python refuses ({want!r}), C accepts"
            assert msg == want, f"{changes}:\n  Python {want!r}\n  C      {msg!r}"
    return py


def test_inputs_and_modes_are_python_s(lib):
    n_all = ctypes.c_int()
    n = lib.shim_n_inputs(ctypes.byref(n_all))
    assert (n, n_all.value) == (len(INPUTS), len(INPUTS) + len(STATED_INPUTS))
    names = [lib.shim_input_name(k).decode() for k in range(n_all.value)]
    assert names == [*INPUTS, *(name for name, _ in STATED_INPUTS)]
    assert lib.shim_input_name(n_all.value) is None and lib.shim_input_name(-1) is None
    priors = [lib.shim_stated_prior(k) for k in range(n, n_all.value)]
    assert [bits(p) for p in priors] == [bits(p) for _, p in STATED_INPUTS]
    assert math.isnan(lib.shim_stated_prior(0))
    header = (CORE / "ato_tuning.h").read_text()
    for mode in AtoMode:
        assert f"ATO_MODE_{mode.name} = {mode.value}," in header or \
            f"ATO_MODE_{mode.name} = {mode.value} " in header, mode
    for k, name in enumerate(INPUTS):
        assert f"= {k}," in header.split(f"/* {name} ")[0].rsplit("\n", 1)[-1], name


def test_fields_kinds_and_defaults_are_python_s(lib):
    assert lib.shim_n_fields() == len(FIELDS)
    kind, offset = ctypes.c_int(), ctypes.c_long()
    offsets = []
    for k, f in enumerate(FIELDS):
        name = lib.shim_field(k, ctypes.byref(kind), ctypes.byref(offset))
        assert (name.decode(), kind.value) == (f.name, KINDS[f.type])
        assert lib.shim_field_named(f.name.encode()) == k
        offsets.append(offset.value)
    assert offsets == sorted(offsets) and len(set(offsets)) == len(offsets)
    assert lib.shim_field(len(FIELDS), ctypes.byref(kind), ctypes.byref(offset)) is None
    assert lib.shim_field_named(b"no_such_field") == -1
    out = (ctypes.c_double * len(FIELDS))()
    lib.shim_defaults(out)
    defaults = AtoTuning()
    assert [bits(x) for x in out] == [bits(float(getattr(defaults, n))) for n in NAMES]
    assert c_validate(lib, list(out), None) == (RC_OK, "")


def up(x: float) -> float:
    return math.nextafter(x, math.inf)


def down(x: float) -> float:
    return math.nextafter(x, -math.inf)


def field_values(field) -> list[float]:
    """Values at and around every bound the field has, and hostile ones."""
    if field.type == "bool":
        return [0.0, 1.0, 2.0, -1.0, 2147483647.0]
    if field.type == "int":
        return [1.0, 0.0, -1.0, 2.0, float(MAX_EP_STAGES), MAX_EP_STAGES + 1.0, 100.0,
                2147483647.0, -2147483648.0]
    name = field.name
    out = [0.0, -0.0, 5e-324, -5e-324, -1.0, math.nan, -math.nan, math.inf, -math.inf, 1e300,
           1.7976931348623157e308, 0.5, 1.0, float(getattr(AtoTuning(), name))]
    if name in UPPER_BOUNDS:
        high = UPPER_BOUNDS[name][0]
        out += [high, up(high), down(high)]
    bounds = {"mass_band": (1.0, 5.0), "est_gate": (1.0,), "time_reserve": (0.2,),
              "brake_share": (1.0,), "safe_brake": (1.0,), "hold_brake": (1.0,)}
    for b in bounds.get(name, ()):
        out += [b, up(b), down(b)]
    rng = random.Random(name)
    out += [rng.uniform(0, 2) for _ in range(5)] + [10 ** rng.uniform(-10, 10) for _ in range(5)]
    return out


@pytest.mark.parametrize("name", NAMES)
def test_each_field_at_and_beyond_its_bounds(lib, name):
    field = next(f for f in FIELDS if f.name == name)
    refused = accepted = 0
    for x in field_values(field):
        if assert_same(lib, {name: x}) is None:
            accepted += 1
        else:
            refused += 1
    assert refused and accepted, (refused, accepted)


def test_the_first_bad_field_in_python_s_order_is_named(lib):
    """Seeded random tunings with 1-4 fields changed, many of them bad: the same first refusal."""
    rng = random.Random(30)
    pools = {f.name: field_values(f) for f in FIELDS}
    refused = 0
    for _ in range(3000):
        changes = {n: rng.choice(pools[n]) for n in rng.sample(NAMES, rng.randint(1, 4))}
        refused += assert_same(lib, changes) is not None
    assert 1000 < refused < 3000


def test_the_refusals_a_user_sees_today():
    """The catalogue of tests/model_tests/ato (test_supervision, test_tuning_bounds) in C words:
    each message starts as those tests expect."""
    for changes, words in (({"safe_brake": 0.0}, "tuning.safe_brake must be > 0"),
                           ({"ep_stages": 33}, "tuning.ep_stages must be in [1, 32]"),
                           ({"mass_band": 5.5}, "tuning.mass_band must be in [1, 5]"),
                           ({"time_tol": 1e300}, "tuning.time_tol must be <= ")):
        assert python_message(changes).startswith(words)


def cases_for_the_program() -> list[dict[str, float]]:
    out = [{n: x} for f in FIELDS for n in (f.name,) for x in field_values(f)]
    rng = random.Random(5)
    pools = {f.name: field_values(f) for f in FIELDS}
    out += [{n: rng.choice(pools[n]) for n in rng.sample(NAMES, 3)} for _ in range(500)]
    return out


def test_the_shim_program_under_sanitizers(lib, tmp_path):
    exe = tmp_path / "ato_tuning"
    build(exe, [*SANITIZE, "-DATO_TUNING_MAIN"])
    cases = cases_for_the_program()
    lines, want = [], []
    for changes in cases:
        values = c_values(changes)
        for prefix in ("-", "ato."):
            lines.append(f"{prefix} " + " ".join(repr(v) if math.isfinite(v) else
                                                 ("nan" if math.isnan(v) else
                                                  ("inf" if v > 0 else "-inf"))
                                                 for v in values))
            st, msg = c_validate(lib, values, None if prefix == "-" else prefix)
            want.append(f"{st} {msg}")
    proc = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[-3000:]
    assert proc.stdout.splitlines() == want


MUTATIONS = {
    # time_reserve's bound one ulp wider
    "time_reserve": ("x > 0.2)", "x > 0.2 * (1.0 + 2.220446049250313e-16))"),
    # every UPPER_BOUNDS bound one ulp wider
    "upper_bounds": ("x > upper_bounds[k].high)",
                     "x > upper_bounds[k].high * (1.0 + 2.220446049250313e-16))"),
    # the mass band's lower end one ulp lower
    "mass_band": ("!(1.0 <= x &&", "!(1.0 * (1.0 - 1.1102230246251565e-16) <= x &&"),
}


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_one_ulp_mutation_of_a_bound_fails_the_comparison(mutation, tmp_path):
    target, replacement = MUTATIONS[mutation]
    text = (CORE / "ato_tuning.c").read_text()
    assert text.count(target) == 1, f"the mutation's target occurs {text.count(target)} times"
    mutated = tmp_path / "ato_tuning.c"
    mutated.write_text(text.replace(target, replacement))
    so = tmp_path / "libmutant.so"
    gcc = shutil.which("gcc")
    proc = subprocess.run([gcc, *FLAGS, "-shared", f"-I{CORE}", str(mutated), str(CORE / "repr.c"),
                           str(SHIM), "-o", str(so), "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    dll = ctypes.CDLL(str(so))
    dll.shim_validate.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_char_p,
                                  ctypes.c_char_p, ctypes.c_int]
    caught = []
    for f in FIELDS:
        for x in field_values(f):
            changes = {f.name: x}
            py = python_message(changes)
            st, msg = c_validate(dll, c_values(changes), None)
            if (st, msg) != ((RC_OK, "") if py is None else (RC_BAD_CONFIG, py)):
                caught.append((f.name, x))
    assert caught, f"{mutation}: every case still equals Python's"

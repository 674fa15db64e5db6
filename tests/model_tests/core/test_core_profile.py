"""The C profile reader (models/core/profile.c) against models/plant/track.py, text for text.

The native FMUs read the track profiles without Python; they must accept the same files, give the
same doubles bit for bit and refuse a bad file with Python's message byte for byte (source, line,
the float as repr() writes it). Each text below goes through GradeProfile/SpeedProfile.from_csv_text
and through the C reader (tests/core_cases/profile_shim.c, ctypes); the file reading is compared
with the harness's (harness/textio.py read_text) and the FMU's (fmu_src/adapter.py load_profiles).
"""
from __future__ import annotations

import ctypes
import math
import os
import random
import re
import shutil
import struct
import subprocess
import unicodedata
from pathlib import Path

import pytest

from conftest import fifo_released
from fmu_src.adapter import PROFILE_MAX_BYTES, ParameterError, load_profiles
from harness.textio import read_text
from models.plant.track import GradeProfile, ProfileError, SpeedProfile, parse_profile_csv

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "profile_shim.c"
SOURCES = [CORE / "profile.c", CORE / "repr.c"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fPIC"]
GRADE, SPEED = 0, 1
CLS = {GRADE: GradeProfile, SPEED: SpeedProfile}
PARAM = {GRADE: "track.grade_profile", SPEED: "track.speed_profile"}
GH = "distance_m,grade_permille\n"
SH = "distance_m,speed_mps\n"


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    so = tmp_path_factory.mktemp("core") / "libprofile.so"
    subprocess.run([gcc, *FLAGS, "-shared", f"-I{CORE}", str(SHIM), *map(str, SOURCES), "-o", str(so),
                    "-lm"], check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(so))
    p, L, i, d = ctypes.c_char_p, ctypes.c_long, ctypes.c_int, ctypes.c_double
    vp = ctypes.c_void_p
    dll.shim_parse.argtypes = [i, p, L, p, p, p, i, d, vp, vp, L, vp, vp, L, vp, vp]
    dll.shim_read_file.argtypes = [p, p, p, i, vp, vp, L, vp, vp, L, vp, vp]
    return dll


def _outcome(lib, call, cap: int, msgcap: int):
    cap = max(cap, 1)
    dist, vals = (ctypes.c_double * cap)(), (ctypes.c_double * cap)()
    n, msglen = ctypes.c_long(), ctypes.c_long()
    msg = ctypes.create_string_buffer(msgcap)
    err = ctypes.create_string_buffer(lib.shim_msg_size())
    status = call(dist, vals, cap, ctypes.byref(n), msg, msgcap, ctypes.byref(msglen), err)
    if status == 0:
        assert err.value == b"" and msglen.value == -1
        return ("ok", list(dist[:n.value]), list(vals[:n.value]))
    assert n.value == 0 and msglen.value >= len(msg.value)
    message = msg.raw[:msglen.value]
    cut = err.value                   # the rc_error copy: the message's head, whole characters
    assert message.startswith(cut) and len(cut) < lib.shim_msg_size()
    assert cut == message or len(message) >= lib.shim_msg_size() - 4 or b"\0" in message
    cut.decode("utf-8")
    return ("error", message.decode("utf-8"))


def c_parse(lib, kind: int, text: str, source: str = "src.csv", columns=None, nonnegative=False,
            max_abs=math.inf):
    data = text.encode("utf-8")
    cap = len(data.splitlines()) + 2
    col0, col1 = (columns or ("", ""))
    return _outcome(lib, lambda *a: lib.shim_parse(
        2 if columns else kind, data, len(data), source.encode(), col0.encode(), col1.encode(),
        nonnegative, max_abs, *a), cap, 2 * len(data) + len(source.encode()) + 512)


def py_parse(kind: int, text: str, source: str = "src.csv"):
    try:
        prof = CLS[kind].from_csv_text(text, source)
    except ProfileError as e:
        return ("error", str(e))
    return ("ok", list(prof.distances), list(prof.grades if kind == GRADE else prof.speeds))


def same(a, b) -> bool:
    """Equal outcomes: the same message, or the same doubles bit for bit (signed zeros too)."""
    if a[0] != b[0]:
        return False
    if a[0] == "error":
        return a[1] == b[1]
    bits = lambda xs: [struct.pack("<d", x) for x in xs]
    return bits(a[1]) == bits(b[1]) and bits(a[2]) == bits(b[2])


def check(lib, kind: int, text: str, source: str = "src.csv"):
    ours, theirs = c_parse(lib, kind, text, source), py_parse(kind, text, source)
    assert same(ours, theirs), (text[:300], ours if ours[0] == "error" else ours[:1],
                                theirs if theirs[0] == "error" else theirs[:1])
    return theirs


# (name, kind, text, what Python says: "ok" or a piece of its message), each rule at least once
CATALOGUE = [
    ("plain grade", GRADE, GH + "0,0\n300,15\n800,-10\n1100,0\n", "ok"),
    ("plain speed", SPEED, SH + "0,0\n100,12.5\n900,12.5\n1000,0\n", "ok"),
    ("no final newline", GRADE, GH + "0,1\n10,2", "ok"),
    ("CRLF", GRADE, GH.replace("\n", "\r\n") + "0,1\r\n10,2\r\n", "ok"),
    ("CR only", GRADE, "distance_m,grade_permille\r0,1\r10,2\r", "ok"),
    ("BOM", GRADE, "\ufeff" + GH + "0,1\n", "ok"),
    ("two BOMs", GRADE, "\ufeff\ufeff" + GH + "0,1\n", "header must be"),
    ("BOM after a blank line", GRADE, "\n\ufeff" + GH + "0,1\n", "line 2: header"),
    ("trailing spaces and tabs", GRADE, GH.replace("\n", "  \t\n") + " 0 , 1 \t\n10,2   \n", "ok"),
    ("quotes", GRADE, '"distance_m","grade_permille"\n"0","1.5"\n""10"",  "2" \n', "ok"),
    ("quotes around spaces", GRADE, GH + '" 0 ","\t1 "\n', "ok"),
    ("a lone quote cell", GRADE, GH + '0,"\n', "not a number"),
    ("comments and blank lines", GRADE, "# grade\n\n   \n" + GH + "# x\n0,1\n\n#1,2\n5,3\n", "ok"),
    ("an indented comment", GRADE, GH + "   # note\n0,1\n", "ok"),
    ("a comment after a value", GRADE, GH + "0,1 # note\n", "not a number"),
    ("empty file", GRADE, "", "line 1: empty file"),
    ("only blank lines and comments", SPEED, "\n\n# c\n  \n", "line 1: empty file"),
    ("header only", GRADE, GH, "no data rows"),
    ("header only, speed", SPEED, SH + "# nothing\n\n", "no data rows"),
    ("wrong header", GRADE, "distance,grade\n0,1\n", "line 1: header must be"),
    ("speed header for grade", GRADE, SH + "0,1\n", "header must be"),
    ("header with a third column", GRADE, "distance_m,grade_permille,x\n0,1\n", "header must be"),
    ("header case", GRADE, "Distance_m,grade_permille\n0,1\n", "header must be"),
    ("header with a space inside", GRADE, "distance_m , grade_permille\n0,1\n", "ok"),
    ("three values", GRADE, GH + "0,1,2\n", "expected 2 values, got 3"),
    ("one value", GRADE, GH + "0\n", "expected 2 values, got 1"),
    ("trailing comma", GRADE, GH + "0,1,\n", "got 3"),
    ("semicolons", GRADE, GH + "0;1\n", "expected 2 values, got 1"),
    ("decimal comma", GRADE, GH + "0,1,5\n", "got 3"),
    ("non-number", GRADE, GH + "0,abc\n", "not a number"),
    ("empty cell", GRADE, GH + "0,\n", "not a number"),
    ("nan", GRADE, GH + "0,nan\n", "non-finite"),
    ("NaN distance", GRADE, GH + "NaN,1\n", "non-finite"),
    ("-nan", GRADE, GH + "0,-nan\n", "non-finite"),
    ("inf", SPEED, SH + "0,inf\n", "non-finite"),
    ("-Infinity", GRADE, GH + "0,-Infinity\n", "non-finite"),
    ("infinit", GRADE, GH + "0,infinit\n", "not a number"),
    ("nan(1)", GRADE, GH + "0,nan(1)\n", "not a number"),
    ("1e309", GRADE, GH + "1e309,1\n", "non-finite"),
    ("-1e309", GRADE, GH + "0,-1e309\n", "non-finite"),
    ("1e-400", GRADE, GH + "1e-400,1\n1,1e-400\n", "ok"),
    ("-1e-400 is -0.0", GRADE, GH + "-1e-400,-1e-400\n", "ok"),
    ("denormals", GRADE, GH + "0,4.9e-324\n1,2.4703282292062328e-324\n2,2.4703282292062327e-324\n", "ok"),
    ("negative distance", GRADE, GH + "-5,1\n", "distance_m must be >= 0, got -5.0"),
    ("-0 distance", GRADE, GH + "-0,1\n", "ok"),
    ("-0 after 0", GRADE, GH + "0,1\n-0.0,1\n", "must increase (-0.0 after 0.0)"),
    ("negative tiny distance", GRADE, GH + "-1e-300,1\n", "got -1e-300"),
    ("non-increasing", GRADE, GH + "0,1\n10,2\n10,3\n", "must increase (10.0 after 10.0)"),
    ("decreasing", SPEED, SH + "0,1\n10,2\n9.5,3\n", "must increase (9.5 after 10.0)"),
    ("increasing by one ulp", GRADE, GH + "0,1\n0.1,2\n0.10000000000000002,3\n", "ok"),
    ("negative speed", SPEED, SH + "0,1\n10,-0.5\n", "speed_mps must be >= 0, got -0.5"),
    ("negative zero speed", SPEED, SH + "0,-0\n", "ok"),
    ("negative grade", GRADE, GH + "0,-199.99\n", "ok"),
    ("too steep", GRADE, GH + "0,1\n10,250\n", "grade_permille must be within +-200, got 250.0"),
    ("too steep downhill", GRADE, GH + "0,-200.00000000000003\n", "within +-200, got -200.00000000000003"),
    ("exactly 200", GRADE, GH + "0,200\n1,-200\n", "ok"),
    ("too fast", SPEED, SH + "0,1e3\n", "speed_mps must be within +-200, got 1000.0"),
    ("too fast and big", SPEED, SH + "0,1e17\n", "got 1e+17"),
    ("hex", GRADE, GH + "0x10,1\n", "not a number"),
    ("underscores", GRADE, GH + "1_0,2_5.5_0\n1_000,1e1_0\n", "got 10000000000.0"),
    ("underscore doubled", GRADE, GH + "1__0,1\n", "not a number"),
    ("underscore leading", GRADE, GH + "_1,1\n", "not a number"),
    ("underscore trailing", GRADE, GH + "1_,1\n", "not a number"),
    ("underscore before point", GRADE, GH + "1_.5,1\n", "not a number"),
    ("underscore after point", GRADE, GH + "1._5,1\n", "not a number"),
    ("underscore before e", GRADE, GH + "1_e1,1\n", "not a number"),
    ("leading plus", GRADE, GH + "+0,+1.5\n+1e1,+.5\n", "ok"),
    ("double sign", GRADE, GH + "+-1,1\n", "not a number"),
    ("point forms", GRADE, GH + "0.,.5\n1.,5.\n", "ok"),
    ("lone point", GRADE, GH + ".,1\n", "not a number"),
    ("exponent forms", GRADE, GH + "1E2,1e+1\n2e2,1e-1\n3E+02,0E0\n", "ok"),
    ("exponent without digits", GRADE, GH + "1e,1\n", "not a number"),
    ("exponent sign only", GRADE, GH + "1e+,1\n", "not a number"),
    ("space inside a number", GRADE, GH + "1 0,1\n", "not a number"),
    ("Unicode digits", GRADE, GH + "\u0661\u0660,\uff11\uff12.\u0665\n", "ok"),
    ("Unicode spaces", GRADE, GH + "\u00a00\u2003,\u30001\u205f\n", "ok"),
    ("Unicode space inside quotes", GRADE, GH + '"\u00a00","1\u2003"\n', "ok"),
    ("x1f inside quotes", GRADE, GH + '"\x1f0",1\n', "not a number"),
    ("x1f outside quotes", GRADE, GH + "\x1f0\x1f,1\n", "ok"),
    ("superscript two", GRADE, GH + "0,\u00b2\n", "not a number"),
    ("NUL in a cell", GRADE, GH + "0,1\x00\n", "not a number"),
    ("form feed and vertical tab lines", GRADE, GH + "0,1\x0c5,2\x0b6,3\n", "ok"),
    ("x1c x1d x1e lines", GRADE, GH + "0,1\x1c5,2\x1d6,3\x1e7,4\n", "ok"),
    ("x85 line", GRADE, GH + "0,1\x855,x\n", "line 3: not a number"),
    ("u2028 u2029 lines", GRADE, GH + "0,1\u20285,2\u20296,y\n", "line 4: not a number"),
    ("line numbers count blank lines", SPEED, "\n\n" + SH + "\r\n0,1\r\n\r\n1,-1\r\n", "line 7:"),
    ("CR LF CR", GRADE, GH + "0,1\r\n\r5,x\n", "line 4:"),
    ("non-ASCII in a message", GRADE, GH + "0,\u00e9t\u00e9 \u20ac\n", "not a number: '0,\u00e9t\u00e9 \u20ac'"),
    ("repr of floats", GRADE, GH + "0.1,1\n0.1,2\n", "(0.1 after 0.1)"),
    ("repr large", GRADE, GH + "1e16,1\n1e16,2\n", "(1e+16 after 1e+16)"),
    ("repr below 1e16", GRADE, GH + "1234567890123456,1\n1234567890123456,2\n", "(1234567890123456.0 after"),
    ("repr small", GRADE, GH + "0.0001,1\n0.0001,2\n", "(0.0001 after 0.0001)"),
    ("repr smaller", GRADE, GH + "0.00001,1\n0.00001,2\n", "(1e-05 after 1e-05)"),
    ("halfway rounds to even", GRADE, GH + "9007199254740993,1\n9007199254740992.5,2\n", "must increase"),
    ("long halfway", GRADE, GH + "9007199254740993" + "0" * 600 + "1e-600,1\n", "ok"),
    ("many leading zeros", GRADE, GH + "0" * 3000 + "1,0." + "0" * 3000 + "1\n", "ok"),
    ("very long line", GRADE, GH + "0,1\n1," + "1" * 100_000 + "\n", "non-finite value: '1,111"),
    ("very long bad line", SPEED, SH + "0," + "x" * 50_000 + "\n", "not a number: '0,xxx"),
    ("very long header", GRADE, "d" * 20_000 + "\n0,1\n", "header must be"),
    ("many columns", GRADE, GH + ",".join(["1"] * 5000) + "\n", "got 5000"),
    ("huge exponent", GRADE, GH + "0,1e99999999999999999999\n", "non-finite"),
    ("huge negative exponent", GRADE, GH + "1e-99999999999999999999,0\n", "ok"),
    ("zero with huge exponent", GRADE, GH + "0e99999999999999999999,0\n", "ok"),
    ("source with spaces", GRADE, GH + "0,x\n", "not a number"),
]


@pytest.mark.parametrize("name,kind,text,expected", CATALOGUE, ids=[c[0] for c in CATALOGUE])
def test_the_catalogue_gives_pythons_values_or_message(lib, name, kind, text, expected):
    theirs = check(lib, kind, text, source="profiles/ü grade.csv" if "source" in name else "src.csv")
    assert len(CATALOGUE) >= 40
    if expected == "ok":                        # the catalogue says what each case shows
        assert theirs[0] == "ok", theirs
    else:
        assert theirs[0] == "error" and expected in theirs[1], theirs


def test_every_refusal_names_source_and_line(lib):
    ours = c_parse(lib, SPEED, "# c\n" + SH + "0,1\n1,-2\n", "a/b.csv")
    assert ours == ("error", "a/b.csv: line 4: speed_mps must be >= 0, got -2.0")


def test_the_generic_parser_takes_any_columns_and_limits(lib):
    for max_abs in (math.inf, 0.5, 1e-7, 123456789.0, 1e300, 0.0):
        for text in ("a,b\n0,0.3\n1,-0.7\n", "a,b\n0,1e-8\n", "a,b\n0,2e300\n", "a,b\n0,-0.0\n"):
            for nonneg in (False, True):
                ours = c_parse(lib, 0, text, columns=("a", "b"), nonnegative=nonneg, max_abs=max_abs)
                try:
                    d, v = parse_profile_csv(text, "s", ("a", "b"), nonnegative_values=nonneg,
                                             max_abs_value=max_abs)
                    theirs = ("ok", d, v)
                except ProfileError as e:
                    theirs = ("error", str(e).replace("s: ", "src.csv: ", 1))
                assert same(ours, theirs), (max_abs, text, ours, theirs)


def test_numbers_as_python_writes_and_reads_them_are_the_same_doubles(lib):
    """Seeded random doubles in many spellings (repr, %.17g, %e, few digits, underscores,
    quotes, spaces, signs), one profile each: the same doubles or the same message."""
    rng = random.Random(17)
    rows = []
    for k in range(4000):
        x = rng.choice([rng.uniform(0, 300), 10 ** rng.uniform(-320, 308), rng.uniform(-1, 1),
                        struct.unpack("<d", struct.pack("<Q", rng.getrandbits(63)))[0]])
        form = rng.choice([repr(x), f"{x:.17g}", f"{x:.3e}", f"{x:.6f}", f"{x:.25e}", f"{x:g}",
                           f"{x:_.4f}", f"{x:E}", f'" {x!r} "', f"+{x!r}", f"\t{x:.1f} "])
        rows.append(form)
    for k in range(0, len(rows), 2):
        text = GH + f"{k},{rows[k]}\n{k + 1},{rows[k + 1]}\n"
        check(lib, GRADE, text)
    # and increasing distances: one long profile of random spellings
    xs = sorted({rng.uniform(0, 1e6) for _ in range(3000)})
    text = SH + "".join(f"{rng.choice([repr(x), f'{x:.9g}', f'{x:_}'])},{rng.uniform(0, 200)!r}\n"
                        for x in xs)
    assert check(lib, SPEED, text)[0] == "ok"


def test_random_texts_from_a_tricky_alphabet(lib):
    """Seeded fuzz: short texts over the characters the rules turn on."""
    rng = random.Random(5)
    pieces = ["0", "1", "9", ".", "e", "E", "+", "-", "_", " ", "\t", ",", '"', "#", "\n", "\r",
              "\r\n", "\x0b", "\x0c", "\x1c", "\x1f", "\x85", "\u2028", "\xa0", "\u0661", "inf",
              "nan", "x", "\ufeff", "\x00", "distance_m,grade_permille\n", "distance_m,speed_mps\n",
              "2e2", "1e309", "-0", "200", "0x1"]
    for _ in range(3000):
        kind = rng.choice([GRADE, SPEED])
        head = rng.choice([GH if kind == GRADE else SH, "", "\ufeff" + (GH if kind == GRADE else SH)])
        text = head + "".join(rng.choice(pieces) for _ in range(rng.randint(0, 30)))
        check(lib, kind, text)


def test_every_unicode_digit_and_space_as_python_reads_it(lib):
    """float() turns Unicode decimal digits and spaces into ASCII; str.strip and splitlines know
    the Unicode spaces and breaks: every such character and every character below U+3100."""
    special = [c for c in range(0x110000) if not 0xD800 <= c < 0xE000
               and (unicodedata.decimal(chr(c), None) is not None or chr(c).isspace())]
    for c in sorted(set(special) | set(range(0x3100)) - set(range(0xD800, 0xE000))):
        ch = chr(c)
        check(lib, GRADE, GH + f"0,{ch}1\n1,1{ch}\n2,{ch}\n3,'{ch}'\n")


def test_the_decimal_table_is_this_pythons_unicode():
    """profile.c's DECIMAL_ZEROS is unicodedata's (Unicode 14.0 for Python 3.11): a newer Python
    with new digits needs the table regenerated (the list of code points c with decimal(c) == 0)."""
    src = (CORE / "profile.c").read_text()
    table = re.search(r"DECIMAL_ZEROS\[\] = \{(.*?)\};", src, re.S).group(1)
    ours = [int(x, 16) for x in re.findall(r"0x[0-9A-Fa-f]+", table)]
    theirs = [c for c in range(0x110000) if unicodedata.decimal(chr(c), None) == 0]
    assert ours == theirs, f"regenerate DECIMAL_ZEROS for Unicode {unicodedata.unidata_version}"
    assert all(unicodedata.decimal(chr(z + k), None) == k for z in theirs for k in range(10))


def test_the_library_profiles_parse_to_the_same_doubles(lib):
    """Every grade and speed profile the scenarios ship (the speed-limit profiles are the
    AtoController's, which reads them in Python: fmu_src.adapter.open_ato)."""
    files = sorted((ROOT / "scenarios" / "profiles").glob("*.csv"))
    limits = [f for f in files if "distance_m,speed_limit_mps" in f.read_text(encoding="utf-8")]
    files = [f for f in files if f not in limits]
    assert len(files) >= 5 and [f.name for f in limits] == ["ato_span_limits.csv"]
    for f in files:
        text = f.read_text(encoding="utf-8")
        kind = SPEED if text.lstrip("\ufeff").startswith("distance_m,speed_mps") else GRADE
        theirs = check(lib, kind, text, str(f))
        assert theirs[0] == "ok" and len(theirs[1]) >= 1, f
        assert same(c_read(lib, str(f), kind), theirs)
        assert same(c_read(lib, str(f), kind, param=PARAM[kind], raw=str(f)), theirs)


def test_the_comparison_can_fail(lib):
    """One ulp off, one character of a message off: the comparison sees it."""
    ours = c_parse(lib, GRADE, GH + "0,0.1\n")
    theirs = py_parse(GRADE, GH + "0,0.1\n")
    assert same(ours, theirs)
    assert not same(ours, ("ok", theirs[1], [math.nextafter(0.1, 1.0)]))
    assert not same(ours, ("ok", theirs[1], [0.1, 0.1]))
    assert not same(("ok", [0.0], [0.0]), ("ok", [-0.0], [0.0]))
    bad = c_parse(lib, GRADE, GH + "0,x\n")
    assert bad == py_parse(GRADE, GH + "0,x\n")
    assert not same(bad, ("error", bad[1] + " "))


def test_a_long_message_is_whole_and_its_cut_copy_ends_on_a_character(lib):
    text = GH + "0," + "é" * 400 + "\n"
    ours = c_parse(lib, GRADE, text)               # _outcome checks the cut copy
    assert ours == py_parse(GRADE, text) and len(ours[1].encode()) > 800


# ---- files ------------------------------------------------------------------------------------

def c_read(lib, path: str, kind: int, param: str | None = None, raw: str | None = None):
    cap = 1 << 16
    return _outcome(lib, lambda *a: lib.shim_read_file(
        path.encode(), param.encode() if param else None, raw.encode() if raw else None, kind, *a), cap, 1 << 20)


def py_harness(path: str, kind: int):
    """harness/run/scenario.py read_profile's reading: textio.read_text, then from_csv_text"""
    try:
        prof = CLS[kind].from_csv_text(read_text(Path(path), reader="the FMU"), str(Path(path)))
    except ValueError as e:
        return ("error", str(e))
    return ("ok", list(prof.distances), list(prof.grades if kind == GRADE else prof.speeds))


def py_fmu(raw: str, kind: int):
    """fmu_src/adapter.py load_profiles (no resources: a relative raw is looked for in the cwd)"""
    values = {PARAM[GRADE]: "", PARAM[SPEED]: ""}
    values[PARAM[kind]] = raw
    try:
        grade, speed = load_profiles(values, None)
    except ParameterError as e:
        return ("error", str(e))
    prof = grade if kind == GRADE else speed
    return ("ok", list(prof.distances), list(prof.grades if kind == GRADE else prof.speeds))


def file_cases(tmp: Path) -> list[tuple[str, int]]:
    """(path, kind): files good and bad, folders, missing files, odd spellings of a path"""
    (tmp / "sub").mkdir(exist_ok=True)
    files = {
        "good.csv": (GH + "0,1\n10,2\n").encode(),
        "speed.csv": (SH + "0,1\r\n10,2\r\n").encode(),
        "bom.csv": ("\ufeff" + GH + "0,1\n").encode(),
        "two_boms.csv": ("\ufeff\ufeff" + GH + "0,1\n").encode(),
        "latin1.csv": (GH + "0,1 # caf").encode() + b"\xe9\n",
        "utf16.csv": ("\ufeff" + GH + "0,1\n").encode("utf-16"),
        "utf16be.csv": ("\ufeff" + GH + "0,1\n").encode("utf-16-be"),
        "nul.csv": (GH + "0,1\n").encode() + b"\x00\n",
        "nul_then_bad.csv": b"ab\x00cd\xff",
        "bad_then_nul.csv": b"ab\xffcd\x00",
        "truncated.csv": (GH + "0,1\n").encode() + b"\xe2\x82",
        "overlong.csv": GH.encode() + b"0,\xc0\xb1\n",
        "surrogate.csv": GH.encode() + b"0,\xed\xa0\x80\n",
        "above_max.csv": GH.encode() + b"0,\xf4\x90\x80\x80\n",
        "four_bytes.csv": GH.encode() + "0,1 # \U0001F682\n".encode(),
        "empty.csv": b"",
        "bad_line.csv": (GH + "0,1\n5,1\n").encode(),
        "sub/inner.csv": (SH + "0,3\n").encode(),
        "big.csv": (GH + "".join(f"{k},{(k * 7919) % 400 / 2 - 100}\n" for k in range(20000))).encode(),
    }
    for name, data in files.items():
        (tmp / name).write_bytes(data)
    cases = []
    for name in files:
        for kind in (GRADE, SPEED):
            cases.append((str(tmp / name), kind))
    t = str(tmp)
    cases += [(t + "/missing.csv", GRADE), (t + "/sub", GRADE), (t + "/sub/", SPEED),
              (t + "//sub/./inner.csv", SPEED), (t + "/sub/inner.csv/", SPEED),
              (t + "/good.csv/x.csv", GRADE), (t + "/nodir/x.csv", GRADE)]
    return cases


def test_files_are_read_as_the_harness_and_the_fmu_read_them(lib, tmp_path):
    for path, kind in file_cases(tmp_path):
        assert same(c_read(lib, path, kind), py_harness(path, kind)), path
        ours = c_read(lib, path, kind, param=PARAM[kind], raw=path)
        assert same(ours, py_fmu(path, kind)), (path, ours, py_fmu(path, kind))
    # a relative parameter the FMU looks for in the working directory: raw and path differ
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        for raw in ("good.csv", "missing.csv", "sub/inner.csv", "./sub//inner.csv", "latin1.csv"):
            ours = c_read(lib, os.getcwd() + "/" + raw, SPEED, param=PARAM[SPEED], raw=raw)
            assert same(ours, py_fmu(raw, SPEED)), (raw, ours, py_fmu(raw, SPEED))
        assert same(c_read(lib, "", GRADE), py_harness("", GRADE))      # Path("") is "."
    finally:
        os.chdir(cwd)




def unfit_files(tmp: Path) -> dict[str, tuple[str, str]]:
    """name -> (path, a piece of the FMU's refusal): files a profile parameter may not name,
    and one exactly at the size bound, which it may. The big ones are sparse: no byte written."""
    os.mkfifo(tmp / "fifo.csv")
    (tmp / "folder").mkdir()
    with open(tmp / "too_big.csv", "wb") as f:
        f.truncate(PROFILE_MAX_BYTES + 1)
    at_bound = (GH + "0,1\n10,2\n#").encode()
    with open(tmp / "at_bound.csv", "wb") as f:       # a comment line fills it to the byte
        f.write(at_bound + b"x" * (PROFILE_MAX_BYTES - len(at_bound) - 1) + b"\n")
    t = str(tmp)
    return {"fifo": (t + "/fifo.csv", "it is a FIFO, not a regular file"),
            "zero": ("/dev/zero", "it is a device, not a regular file"),
            "null": ("/dev/null", "it is a device, not a regular file"),
            "folder": (t + "/folder", "it is a folder, not a regular file"),
            "too_big": (t + "/too_big.csv", f"it has {PROFILE_MAX_BYTES + 1} bytes, more than the "
                        f"16777216 bytes (16 MiB) a profile may have"),
            "at_bound": (t + "/at_bound.csv", "")}


def test_a_profile_parameter_names_a_regular_file_of_bounded_size(lib, tmp_path):
    """A FIFO (whose opening would wait for ever), a device (/dev/zero never ends), a folder
    and a file over PROFILE_MAX_BYTES are refused before they are opened, naming the parameter,
    the file and why, the same words in C and Python; a file at the bound is read."""
    files = unfit_files(tmp_path)
    with fifo_released(tmp_path / "fifo.csv") as opened:
        for name, (path, says) in files.items():
            for kind in (GRADE, SPEED):
                ours, theirs = c_read(lib, path, kind, param=PARAM[kind], raw=path), py_fmu(path, kind)
                assert same(ours, theirs), (name, ours[:2], theirs[:2])
                if says:
                    assert ours == ("error", f"{PARAM[kind]}: cannot read '{path}' "
                                             f"(looked for {path}): {says}")
    assert opened == []
    assert c_read(lib, files["at_bound"][0], GRADE, PARAM[GRADE], files["at_bound"][0]) == \
        ("ok", [0.0, 10.0], [1.0, 2.0])


def test_a_relative_profile_names_the_file_it_looked_for(lib, tmp_path):
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        os.mkfifo("fifo.csv")
        with fifo_released(tmp_path / "fifo.csv") as opened:
            ours = c_read(lib, os.getcwd() + "/fifo.csv", SPEED, param=PARAM[SPEED], raw="fifo.csv")
        assert opened == []
        assert ours == py_fmu("fifo.csv", SPEED) == (
            "error", f"track.speed_profile: cannot read 'fifo.csv' (looked for {tmp_path}/fifo.csv): "
                     f"it is a FIFO, not a regular file")
    finally:
        os.chdir(cwd)


# ---- sanitizers ---------------------------------------------------------------------------------

def test_the_catalogue_runs_clean_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    """profile.c + repr.c under -fsanitize=address,undefined (any report aborts, leaks
    included): every catalogue text and every file case, with the same outcomes as Python."""
    gcc = shutil.which("gcc")
    assert gcc
    exe = tmp_path / "profiles"
    subprocess.run([gcc, "-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-DPROFILE_SHIM_MAIN",
                    f"-I{CORE}", str(SHIM), *map(str, SOURCES), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    jobs = [(kind, text.encode(), py_parse(kind, text)) for _, kind, text, _ in CATALOGUE]
    (tmp_path / "files").mkdir()
    for path, kind in file_cases(tmp_path / "files"):
        jobs.append((2 + kind, path.encode(), py_harness(path, kind)))
        jobs.append((4 + kind, path.encode(), py_fmu(path, kind)))
    (tmp_path / "unfit").mkdir()
    for path, _ in unfit_files(tmp_path / "unfit").values():
        jobs.append((4 + GRADE, path.encode(), py_fmu(path, GRADE)))
    stdin = b"".join(struct.pack("<iq", op, len(data)) + data for op, data, _ in jobs)
    with fifo_released(tmp_path / "unfit" / "fifo.csv") as opened:
        proc = subprocess.run([str(exe)], input=stdin, capture_output=True, timeout=120,
                              env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
    assert opened == []
    assert proc.returncode == 0, proc.stderr.decode(errors="replace")
    out, at = proc.stdout, 0
    for op, data, theirs in jobs:
        status, n = struct.unpack_from("<iq", out, at)
        at += 12
        d = list(struct.unpack_from(f"<{n}d", out, at))
        v = list(struct.unpack_from(f"<{n}d", out, at + 8 * n))
        at += 16 * n
        (mlen,) = struct.unpack_from("<q", out, at)
        at += 8
        msg = out[at:at + max(mlen, 0)].decode("utf-8")
        at += max(mlen, 0)
        ours = ("ok", d, v) if status == 0 else ("error", msg)
        assert same(ours, theirs), (op, data[:200])
    assert at == len(out)

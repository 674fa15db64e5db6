"""Reading the harness's input text files (TOML, CSV, JSON) with one set of checks.

Every reader of the harness goes through ``read_text``: the file must be UTF-8 text; a binary
file (a NUL byte) or bytes that are not UTF-8 are refused with ``FILE: not UTF-8 text (byte
offset N)``; a UTF-8 byte order mark (BOM, which spreadsheet programs write) is stripped, or
refused with a message that says so where the text goes on to a reader that cannot skip it.
Errors are ``InputError`` (or the caller's subclass of it): invalid input, exit code 2.

Before a file is opened, os.stat must show a regular file of at most ``limit`` bytes (default
``MAX_INPUT_BYTES``; a track profile: the FMU's own 16 MiB): opening a FIFO a user names would
wait for a writer for ever, /dev/zero never ends. Such a file is refused by name ("FILE: it is a
FIFO, not a regular file"), as the FMUs refuse a profile (fmu_src/adapter.py read_profile_text).
"""
from __future__ import annotations

import difflib
import os
import stat
from pathlib import Path

MAX_INPUT_BYTES = 256 * 1024 * 1024
"""The most bytes an input file of the harness may have (256 MiB): a replay log of ten hours at
10 Hz is about 30 MB; the bound stops a wrong file (a disc image, a device) filling the memory."""

_NOT_A_FILE = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a device"),
               (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))


BOM = "\ufeff"
_BOM_BYTES = BOM.encode("utf-8")


class InputError(ValueError):
    """Invalid input (a file, a key, a command-line value); the message names the file and the key
    or line. The command line exits with code 2 on it."""


def _mib(n: int) -> str:
    return f"{n} bytes ({n / 1024 / 1024:g} MiB)"


def read_bytes(path: str | Path, error: type[Exception] = InputError, limit: int = MAX_INPUT_BYTES,
               where: str | None = None) -> bytes:
    """The bytes of ``path``, which os.stat must show to be a regular file of at most ``limit``
    bytes before it is opened (module docstring); ``error`` names ``where`` (default the path)."""
    where = str(path) if where is None else where
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = next((k for test, k in _NOT_A_FILE if test(st.st_mode)), None)
            if kind == "a folder":
                raise error(f"{where}: is a folder, not a file")
            raise error(f"{where}: it is {kind or 'not a regular file'}"
                        f"{', not a regular file' if kind else ''}")
        if st.st_size > limit:
            raise error(f"{where}: it has {st.st_size} bytes, more than the {_mib(limit)} the harness reads")
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as e:
        raise error(f"{where}: cannot read: {e.strerror or e}") from None
    if len(data) > limit:
        raise error(f"{where}: it grew past the {_mib(limit)} the harness reads while it was read")
    return data


def decode_text(data: bytes, where: str, error: type[Exception] = InputError, bom: str = "strip",
                reader: str = "") -> str:
    """``data`` as text; ``where`` names the file in errors.

    ``bom``: "strip" drops a leading UTF-8 BOM; "reject" refuses it (``reader`` names what cannot
    read it, for the message)."""
    nul = data.find(b"\x00")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        offset = e.start if nul < 0 else min(e.start, nul)
        hint = " (UTF-16? save it as UTF-8)" if data[:2] in (b"\xff\xfe", b"\xfe\xff") else \
            " (a binary file?)" if nul >= 0 else ""
        raise error(f"{where}: not UTF-8 text (byte offset {offset}){hint}") from None
    if nul >= 0:
        raise error(f"{where}: not UTF-8 text (byte offset {nul}) (a NUL byte: a binary file?)")
    if text.startswith(BOM):
        if bom == "reject":
            raise error(f"{where}: starts with a UTF-8 BOM (byte order mark), which {reader or 'its reader'} "
                        f"does not accept: save the file as UTF-8 without BOM")
        text = text[1:]
    return text


def read_text(path: str | Path, error: type[Exception] = InputError, bom: str = "strip",
              reader: str = "", limit: int = MAX_INPUT_BYTES) -> str:
    """The text of ``path`` (see ``decode_text``): a regular file of at most ``limit`` bytes
    (``read_bytes``); an unreadable file raises ``error`` naming it."""
    path = Path(path)
    return decode_text(read_bytes(path, error, limit), str(path), error, bom, reader)


def check_text_file(path: str | Path, error: type[Exception] = InputError, reader: str = "",
                    limit: int = MAX_INPUT_BYTES) -> None:
    """Check that a file another reader will open (the FMU, ``harness.run.driver``) is UTF-8 text without
    a BOM, so that a bad file is reported here, naming it, rather than there."""
    read_text(path, error, bom="reject", reader=reader, limit=limit)


def check_out_dir(path: str | Path, option: str = "--out") -> None:
    """An output folder given on the command line must be a folder or not exist yet."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: exists and is not a folder")


def did_you_mean(name: str, known, n: int = 1, cutoff: float = 0.6, ignore_case: bool = False) -> str:
    """'; did you mean 'x'?' (or 'x' or 'y' for ``n`` = 2) naming the known names closest to a
    misspelt ``name`` (difflib ratio >= ``cutoff``; ``ignore_case``: car.a0 is car.A0), or '' when
    none is close: the tail of every "unknown name" message of the harness."""
    fold = str.lower if ignore_case else str
    by_key = {fold(k): k for k in sorted(known)}
    close = [by_key[c] for c in difflib.get_close_matches(fold(name), list(by_key), n=n, cutoff=cutoff)]
    return f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""

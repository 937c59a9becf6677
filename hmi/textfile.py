"""Reading a file that someone else wrote: regular files only, bounded, decoded strictly.

Every file plchmi reads by name (a project, an include, a component, a journal) goes through
:func:`open_regular`, so that one place refuses what is not a plain file before reading a
byte of it: a FIFO would block forever, ``/dev/zero`` or ``/dev/urandom`` never end, a
directory is not text. :func:`read_text` adds a size cap and strict UTF-8 decoding whose
errors say where the bad byte is (line and column, as an editor counts them), and refuses
the control characters no text file of ours holds (NUL, BEL, ...), also at their line and
column. The caller turns a :class:`FileProblem` into its own kind of error (a project
diagnostic, a usage error).
"""

from __future__ import annotations

import errno
import os
import re
import stat
import unicodedata
from dataclasses import dataclass
from pathlib import Path

from hmi.limits import describe_bytes

# What YAML 1.1 refuses anywhere in a stream (PyYAML's Reader.NON_PRINTABLE) less the BOM
# and the surrogates, which strict UTF-8 decoding already refuses: every character but
# \x09 \x0a \x0d \x20-\x7e \x85 \xa0-\ud7ff \ue000-\ufffd \U00010000-\U0010ffff, written as
# that set's complement (the same characters; compiled in a sixth of the time, at every
# start: tests/test_startup.py checks every code point).
_NOT_TEXT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x84\x86-\x9f\ud800-\udfff\ufffe\uffff]")


@dataclass
class FileProblem(Exception):
    """A file could not be read as text: what is wrong, and where when it is inside it."""

    message: str
    line: int = 0
    col: int = 0
    expected: str | None = None

    def __str__(self) -> str:
        return self.message


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def os_reason(exc: OSError) -> str:
    """An OSError in plain words (its strerror, or its errno name)."""
    if exc.strerror:
        return exc.strerror[0].lower() + exc.strerror[1:]
    return errno.errorcode.get(exc.errno or 0, str(exc))


def open_regular(path: Path) -> int:
    """A read-only descriptor on `path`, which must be a regular file; else FileProblem.

    Opened without blocking (a FIFO with no writer would otherwise hang here) and checked
    with fstat on the descriptor itself, so what is read is what was checked.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except FileNotFoundError:
        raise FileProblem("file not found") from None
    except IsADirectoryError:
        raise FileProblem("this is a folder, not a file", expected="a file") from None
    except OSError as exc:
        raise FileProblem(f"cannot read: {os_reason(exc)}") from None
    except ValueError as exc:  # a NUL in the name
        raise FileProblem(f"cannot read: {exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise FileProblem(f"not a regular file: this is {_kind(mode)}"
                              if not stat.S_ISDIR(mode) else "this is a folder, not a file",
                              expected="a regular file")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_bytes(path: Path, max_bytes: int) -> bytes:
    """The whole content of a regular file of at most `max_bytes` bytes."""
    fd = open_regular(path)
    try:
        size = os.fstat(fd).st_size
        if size > max_bytes:
            raise _too_big(size, max_bytes)
        chunks = []
        total = 0
        while True:  # read to the end, in case it grew since fstat, but never past the cap
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise _too_big(total, max_bytes)
    except OSError as exc:
        raise FileProblem(f"cannot read: {os_reason(exc)}") from None
    finally:
        os.close(fd)
    return b"".join(chunks)


def _too_big(size: int, limit: int) -> FileProblem:
    return FileProblem(f"the file is too large ({describe_bytes(size)} or more; the limit is "
                       f"{describe_bytes(limit)})", expected=f"a file of at most "
                       f"{describe_bytes(limit)}")


def read_text(path: Path, max_bytes: int) -> str:
    """A regular file's text: UTF-8, at most `max_bytes`, no control characters but tab
    and newlines. A problem inside the file is a FileProblem with its line and column."""
    return decode_text(read_bytes(path, max_bytes))


def decode_text(data: bytes) -> str:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = line_col(data[:exc.start].decode("utf-8", errors="replace"), None)
        hint = ""
        if data.startswith((b"\xff\xfe", b"\xfe\xff")):
            hint = " (it looks like UTF-16: save it as UTF-8)"
        raise FileProblem(f"not UTF-8 text: byte 0x{data[exc.start]:02x} cannot start or "
                          f"continue a character{hint}", line, col,
                          "a UTF-8 text file") from None
    if text.startswith("\ufeff"):
        text = text[1:]  # a UTF-8 byte-order mark: harmless, and editors on Windows add it
    bad = _NOT_TEXT.search(text)
    if bad is not None:
        line, col = line_col(text, bad.start())
        raise FileProblem(f"the file holds the control character {char_name(bad.group())}",
                          line, col, "text: letters, digits, punctuation, spaces, tabs and "
                          "line breaks")
    return text


def line_col(text: str, index: int | None) -> tuple[int, int]:
    """Line and column (from 1) of character `index` of `text` (None: just after the end)."""
    if index is None:
        index = len(text)
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


def char_name(char: str) -> str:
    """U+0007 (BEL), U+FF39 FULLWIDTH LATIN CAPITAL LETTER Y: a character named for a reader
    who cannot see it."""
    code = f"U+{ord(char):04X}"
    names = {"\x00": "NUL", "\x07": "BEL", "\x08": "backspace", "\x1b": "ESC", "\x7f": "DEL",
             "\x0b": "vertical tab", "\x0c": "form feed"}
    if char in names:
        return f"{code} ({names[char]})"
    name = unicodedata.name(char, "")
    if 0xD800 <= ord(char) <= 0xDFFF:
        name = "a lone surrogate"
    return f"{code} ({name})" if name else code

"""Code compiled from generated text, compiled once and kept like bytecode; and the file
rules of every cache the HMI's start keeps (docs/performance.md).

Python writes each module's bytecode to ``__pycache__`` so that a new process does not compile
it again, but a dataclass's methods (``__init__``, ``__repr__``, ``__eq__``, ``__hash__``,
the frozen ``__setattr__``...) are generated as source text and compiled at every import:
on the HMI's start path some 160 dataclasses (ours and Textual's), about three quarters of
each one's cost and a fifth of the whole start (docs/performance.md). Inside
:func:`dataclass_code`, the ``exec`` that the ``dataclasses`` module runs on that text gets
the code object compiled from the very same text in an earlier process, if any: the methods
are the same functions, built the same way, from the same source; only the compiling is
skipped. New texts are compiled as usual and the cache file is written at the end. The
same holds for the two other texts the standard library compiles at import: a named tuple's
``__new__`` (``collections.namedtuple``'s ``eval``, for each ``typing.NamedTuple`` too) and
each string annotation a ``typing.NamedTuple`` checks (``typing.ForwardRef``'s ``compile``):
some 400 small compilations on the start path. :func:`kept_codes` does the same for a table
of code by text that a module keeps itself (the compiled scan's, hmi.engine.codegen).

The files live beside hmi's bytecode, are written under the same rule (not when bytecode
writing is off: ``PYTHONDONTWRITEBYTECODE``, ``python -B``), atomically, and read only when
written by this interpreter version (its bytecode magic number) in the same format for the
same inputs (a header), and whole (the body's CRC-32: a damaged file is never taken);
anything unreadable is ignored and rebuilt. They are trusted as the
``.pyc`` files beside them are.
"""

from __future__ import annotations

import builtins
import collections
import contextlib
import dataclasses
import importlib.util
import marshal
import os
import sys
import typing
import zlib
from collections.abc import Iterator
from pathlib import Path
from types import CodeType, ModuleType
from typing import Any

try:  # hashlib's own blake2b, without hashlib importing OpenSSL's bindings (~3 ms at a start)
    from _blake2 import blake2b as blake2b
except ImportError:  # an interpreter built without it
    from hashlib import blake2b as blake2b

DEFAULT_PATH = (Path(__file__).resolve().parent / "__pycache__"
                / f"generated-code.{sys.implementation.cache_tag}.marshal")
# this interpreter, format 2 (texts for eval keyed apart)
HEADER = importlib.util.MAGIC_NUMBER + b"generated code 2\n"
MAX_ENTRIES = 20_000  # past this (texts of classes long gone), the file starts afresh


class CodeCache:
    """Source text -> code compiled from it, read from and written to one file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.codes: dict[str, CodeType] = _read(path)
        self.hits = 0
        self.compiled = 0

    def code(self, source: str, mode: str = "exec") -> CodeType:
        """The code of `source` compiled as `mode` ("exec" or "eval") from "<string>"."""
        key = source if mode == "exec" else f"{mode}\0{source}"  # no text starts with NUL
        code = self.codes.get(key)
        if code is None:
            # dont_inherit: compiled as the standard library's own exec, eval and compile
            # compile it there (none of those modules has a `from __future__` import), not
            # with this module's `from __future__ import annotations` (which would leave
            # the methods' annotations as the names of dataclasses' local variables)
            code = self.codes[key] = compile(source, "<string>", mode, dont_inherit=True)
            self.compiled += 1
        else:
            self.hits += 1
        return code

    def run(self, source: str | CodeType, scope: dict[str, Any] | None = None,
            namespace: dict[str, Any] | None = None) -> None:
        """The ``exec(text, globals, ns)`` of dataclasses, with the text's cached code;
        a code object goes through unchanged."""
        builtins.exec(self.code(source) if isinstance(source, str) else source, scope,
                      namespace)

    def eval(self, source: str | CodeType, scope: dict[str, Any] | None = None,
             namespace: dict[str, Any] | None = None) -> Any:
        """The ``eval(text, namespace)`` of collections.namedtuple (its ``__new__``), with
        the text's cached code (eval strips leading spaces and tabs before compiling)."""
        if isinstance(source, str):
            source = self.code(source.lstrip(" \t"), "eval")
        return builtins.eval(source, scope, namespace)

    def compile(self, source: Any, filename: str, mode: str, flags: int = 0,
                dont_inherit: bool = False, optimize: int = -1) -> Any:
        """The ``compile(text, '<string>', 'eval')`` of typing.ForwardRef (a string
        annotation of a NamedTuple or a generic), with the text's cached code; any other
        compile goes through unchanged."""
        if (isinstance(source, str) and filename == "<string>" and mode == "eval"
                and not flags and optimize == -1):
            return self.code(source, "eval")
        return builtins.compile(source, filename, mode, flags, dont_inherit, optimize)

    def save(self) -> None:
        """Write the file if something new was compiled."""
        if not self.compiled:
            return
        codes = self.codes if len(self.codes) <= MAX_ENTRIES else {}
        write_file(self.path, HEADER, marshal.dumps(codes))


def _digest(body: bytes) -> bytes:
    """The line after a cache file's header: the body's CRC-32 (8 hex digits), so that a
    file damaged on disk (flipped bits, a cut, a tail added) is never taken: code
    unmarshalled or objects unpickled from it would run unchecked (the project's constraints
    too). A check against damage, not against someone writing the file (trusted as the
    ``.pyc`` beside it): ~0.25 ms for the 780 KB of generated code at a start, blake2b 1 ms."""
    return b"%08x\n" % zlib.crc32(body)


def read_file(path: Path, header: bytes) -> bytes | None:
    """What follows `header` and the body's digest in the file at `path`, or None (missing,
    unreadable, another header: another interpreter, another format, other inputs; or
    damaged: the digest does not match)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if not data.startswith(header):
        return None
    start = len(header) + 9  # 8 hex digits and a newline
    body = data[start:]
    return body if data[len(header):start] == _digest(body) else None


def write_file(path: Path, header: bytes, body: bytes) -> None:
    """`header`, the body's digest, then `body` to `path`, atomically (a reader sees the old
    file or the new one, whole); errors ignored, as Python ignores a ``__pycache__`` it
    cannot write."""
    temp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    with contextlib.suppress(OSError, ValueError):
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            with open(temp, "wb") as file:
                file.write(header)
                file.write(_digest(body))
                file.write(body)
            os.replace(temp, path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(temp)


def writing(write: bool | None = None) -> bool:
    """Whether a cache is written: as asked, else under the rule of the ``.pyc`` files."""
    return (not sys.dont_write_bytecode) if write is None else write


def source_fingerprint(module: ModuleType) -> bytes:
    """A digest of a module's source file (what a cache written under another version of it
    must not be taken for)."""
    source = module.__file__
    if source is None:
        raise ValueError(f"{module.__name__} has no source file")
    return blake2b(Path(source).read_bytes(), digest_size=16).hexdigest().encode()


def _codes(body: bytes | None) -> dict[Any, CodeType]:
    """The table a cache file holds (empty if it holds anything else)."""
    if body is None:
        return {}
    try:
        codes = marshal.loads(body)
    except Exception:  # (marshal raises SystemError too on some damage)
        return {}
    if not isinstance(codes, dict):
        return {}
    return {k: v for k, v in codes.items() if isinstance(v, CodeType)}


def _read(path: Path) -> dict[str, CodeType]:
    return {k: v for k, v in _codes(read_file(path, HEADER)).items() if isinstance(k, str)}


@contextlib.contextmanager
def dataclass_code(path: Path = DEFAULT_PATH, write: bool | None = None
                   ) -> Iterator[CodeCache | None]:
    """Dataclasses, named tuples and string annotations of typing's classes created inside
    take their generated code from the cache at `path`. `write`: save what was compiled
    (default: unless bytecode writing is off). Does nothing (yields None) if something else
    already replaced the builtin one of those modules sees."""
    shadowed = ((dataclasses, "exec"), (collections, "eval"), (typing, "compile"))
    if any(name in vars(module) for module, name in shadowed):  # nested, or someone else's
        yield None
        return
    cache = CodeCache(path)
    for module, name in shadowed:  # a module global shadows the builtin in that module
        setattr(module, name, getattr(cache, "run" if name == "exec" else name))
    try:
        yield cache
    finally:
        for module, name in shadowed:
            delattr(module, name)
        if writing(write):
            cache.save()


@contextlib.contextmanager
def kept_codes(table: dict[Any, CodeType], path: Path, fingerprint: bytes,
               write: bool | None = None) -> Iterator[int]:
    """A module's own table of compiled code by text (each key holds the very text the code
    was compiled from) gets the entries an earlier process kept at `path`; what was added
    meanwhile is kept at the end. `fingerprint` names what else decided that a text may be
    compiled (hmi.engine.codegen: its checker): a file written under another one is
    ignored. Yields how many entries were taken from the file."""
    header = importlib.util.MAGIC_NUMBER + b"kept codes 1 " + fingerprint + b"\n"
    kept = _codes(read_file(path, header))
    taken = {key: code for key, code in kept.items() if key not in table}
    table.update(taken)
    try:
        yield len(taken)
    finally:
        new = {key: code for key, code in table.items() if key not in kept}
        if new and writing(write):
            codes = {**kept, **new} if len(kept) + len(new) <= MAX_ENTRIES else dict(table)
            write_file(path, header, marshal.dumps(codes))

"""The code of generated dataclass methods, compiled once and kept like bytecode.

Python writes each module's bytecode to ``__pycache__`` so that a new process does not compile
it again, but a dataclass's methods (``__init__``, ``__repr__``, ``__eq__``, ``__hash__``,
the frozen ``__setattr__``...) are generated as source text and compiled at every import:
on the HMI's start path some 160 dataclasses (ours and Textual's), about three quarters of
each one's cost and a fifth of the whole start (docs/performance.md). Inside
:func:`dataclass_code`, the ``exec`` that the ``dataclasses`` module runs on that text gets
the code object compiled from the very same text in an earlier process, if any: the methods
are the same functions, built the same way, from the same source; only the compiling is
skipped. New texts are compiled as usual and the cache file is written at the end.

The file lives beside hmi's bytecode, is written under the same rule (not when bytecode
writing is off: ``PYTHONDONTWRITEBYTECODE``, ``python -B``), atomically, and read only when
it was written by this interpreter version (its bytecode magic number); anything unreadable
is ignored and rebuilt. It holds source text and the code compiled from it, nothing else: it
is trusted as the ``.pyc`` files beside it are.
"""

from __future__ import annotations

import builtins
import contextlib
import dataclasses
import importlib.util
import marshal
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from types import CodeType
from typing import Any

DEFAULT_PATH = (Path(__file__).resolve().parent / "__pycache__"
                / f"dataclass-methods.{sys.implementation.cache_tag}.marshal")
HEADER = importlib.util.MAGIC_NUMBER + b"dataclass methods 1\n"  # this interpreter, format 1
MAX_ENTRIES = 20_000  # past this (texts of classes long gone), the file starts afresh


class CodeCache:
    """Source text -> code compiled from it, read from and written to one file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.codes: dict[str, CodeType] = _read(path)
        self.hits = 0
        self.compiled = 0

    def code(self, source: str) -> CodeType:
        code = self.codes.get(source)
        if code is None:
            # dont_inherit: compiled as dataclasses' own exec compiles it, without this
            # module's `from __future__ import annotations` (which would leave the
            # methods' annotations as the names of dataclasses' local variables)
            code = self.codes[source] = compile(source, "<string>", "exec", dont_inherit=True)
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

    def save(self) -> None:
        """Write the file if something new was compiled (atomically; errors ignored, as
        Python ignores a ``__pycache__`` it cannot write)."""
        if not self.compiled:
            return
        codes = self.codes if len(self.codes) <= MAX_ENTRIES else {}
        temp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
        with contextlib.suppress(OSError, ValueError):
            self.path.parent.mkdir(parents=True, exist_ok=True)
            try:
                with open(temp, "wb") as file:
                    file.write(HEADER)
                    marshal.dump(codes, file)
                os.replace(temp, self.path)  # readers see the old file or the new, whole
            finally:
                with contextlib.suppress(OSError):
                    os.unlink(temp)


def _read(path: Path) -> dict[str, CodeType]:
    try:
        data = path.read_bytes()
    except OSError:
        return {}
    if not data.startswith(HEADER):
        return {}
    try:
        codes = marshal.loads(data[len(HEADER):])
    except (EOFError, ValueError, TypeError):
        return {}
    if not isinstance(codes, dict):
        return {}
    return {k: v for k, v in codes.items() if isinstance(k, str) and isinstance(v, CodeType)}


@contextlib.contextmanager
def dataclass_code(path: Path = DEFAULT_PATH, write: bool | None = None
                   ) -> Iterator[CodeCache | None]:
    """Dataclasses created inside take their methods' code from the cache at `path`.
    `write`: save what was compiled (default: unless bytecode writing is off). Does nothing
    (yields None) if something else already replaced the ``exec`` dataclasses sees."""
    if "exec" in vars(dataclasses):  # nested, or someone else's: leave it alone
        yield None
        return
    cache = CodeCache(path)
    dataclasses.exec = cache.run  # type: ignore[attr-defined]  # shadows the builtin
    try:
        yield cache
    finally:
        del dataclasses.exec  # type: ignore[attr-defined]
        if (not sys.dont_write_bytecode) if write is None else write:
            cache.save()

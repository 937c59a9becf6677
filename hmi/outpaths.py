"""Files a command writes may not be files it reads or another of its outputs.

`plchmi run P --trace <data>/P/journal.jsonl` truncated the journal to write the trace (48
entries became one), `--trace X --journal X` lost entries to the trace's writes, and a
journal given as the project's own file would have appended JSON to it. Before anything is
opened for writing, every output is compared with every other output and with every file
the project was read from: the same path once resolved (symlinks, `..`), or the same inode
(a hard link, a bind mount). A clash is a usage error naming both.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from hmi.errors import UsageError


def _identity(path: Path) -> tuple[str, tuple[int, int] | None]:
    """The resolved path and, if it exists, its (device, inode)."""
    try:
        resolved = path.resolve()
    except (OSError, RuntimeError, ValueError):
        resolved = path.absolute()
    try:
        st = os.stat(resolved)
        return str(resolved), (st.st_dev, st.st_ino)
    except (OSError, ValueError):
        return str(resolved), None


def check_outputs(outputs: Sequence[tuple[str, str, Path | None]],
                  read: Sequence[tuple[str, Path]]) -> None:
    """UsageError if an output ((option, what it holds, path); path None: not asked) is
    another output or a file the command reads ((what, path))."""
    seen = [(what, path, _identity(path)) for what, path in read]
    for option, noun, path in outputs:
        if path is None:
            continue
        ident = _identity(path)
        for other, other_path, other_ident in seen:
            if ident[0] == other_ident[0] or (ident[1] is not None and ident[1] == other_ident[1]):
                raise UsageError(f"{option} {path}: this is {other} ({other_path}); {noun} "
                                 "would be written over it. Give another file")
        seen.append((noun, path, ident))

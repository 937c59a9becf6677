"""Errors that point at the place in a project file that caused them.

Every problem found in a project is a :class:`Diagnostic` with a file, a line and a column, a
statement of what is wrong and, when it helps, what was expected. Loading collects as many
diagnostics as it can before giving up, so an engineer fixes a file in one pass rather than
one error per run.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True, order=True)
class SourcePos:
    """A position in a project file; line and column count from 1, as editors show them.

    `context` says through what the file was reached when one file serves several times: a
    component file instantiated by a project ("in component V1 of project.yaml:20:5"). It is
    not part of ``str(pos)`` (messages quote positions inline) but every diagnostic at such a
    position ends with it, so the engineer knows which instance a component error is about.
    """

    file: str
    line: int = 0
    col: int = 0
    context: str = ""
    # The start of a text written over several lines (a YAML block, or a folded plain or
    # quoted scalar): where each line's part of the text is, as (offset in the text, line,
    # column, length), so that a position inside the text lands on its own line
    # (hmi.project.yamlnodes.text_start). Empty for a text on one line.
    lines: tuple[tuple[int, int, int, int], ...] = field(default=(), compare=False,
                                                         repr=False)

    def __str__(self) -> str:
        if self.line <= 0:
            return self.file
        return f"{self.file}:{self.line}:{self.col}"

    def shifted(self, columns: int) -> SourcePos:
        """The position `columns` characters further on in a text that starts here: on the
        same line, or on the line that holds that character for a text over several lines
        (never past the end of that line's part of the text)."""
        if not self.lines:
            return SourcePos(self.file, self.line, self.col + columns, self.context)
        offset, line, col, length = self.lines[0]
        for part in self.lines[1:]:
            if part[0] > columns:
                break
            offset, line, col, length = part
        inside = min(max(0, columns - offset), max(0, length - 1))
        return SourcePos(self.file, line, col + inside, self.context)


MAX_MESSAGE_CHARS = 600
"""The longest message a diagnostic says: a text it quotes from a file is cut to an excerpt
(:func:`excerpt`), and a message longer than this anyway is cut here, so that no project file
(a 3.5 MB text where a mapping belongs, a file that is not ours) is printed back whole."""


def excerpt(text: str, limit: int = 60) -> str:
    """`text` quoted for a message, cut to its first `limit` characters with its length said:
    a value from a file is shown so the engineer finds it, never copied out whole."""
    if len(text) <= limit:
        return repr(text)
    return f"{text[:limit]!r}… ({len(text):,} characters)"


def _cut(text: str) -> str:
    if len(text) <= MAX_MESSAGE_CHARS:
        return text
    return text[:MAX_MESSAGE_CHARS] + f"… ({len(text) - MAX_MESSAGE_CHARS:,} characters cut)"


@dataclass(frozen=True)
class Diagnostic:
    pos: SourcePos
    message: str
    expected: str | None = None
    severity: str = "error"  # "error" or "warning"

    def __post_init__(self) -> None:
        object.__setattr__(self, "message", _cut(self.message))
        if self.expected is not None:
            object.__setattr__(self, "expected", _cut(self.expected))

    def __str__(self) -> str:
        text = f"{self.pos}: {self.severity}: {self.message}"
        if self.expected:
            text += f" (expected {self.expected})"
        if self.pos.context:
            text += f" ({self.pos.context})"
        return text


@dataclass
class Diagnostics:
    """An accumulator of diagnostics shared by the loader's passes."""

    items: list[Diagnostic] = field(default_factory=list)

    def error(self, pos: SourcePos, message: str, expected: str | None = None) -> None:
        self.items.append(Diagnostic(pos, message, expected, "error"))

    def warning(self, pos: SourcePos, message: str, expected: str | None = None) -> None:
        self.items.append(Diagnostic(pos, message, expected, "warning"))

    @property
    def errors(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "error"]

    @property
    def warnings(self) -> list[Diagnostic]:
        return [d for d in self.items if d.severity == "warning"]

    def raise_if_errors(self) -> None:
        if self.errors:
            raise ProjectError(self.errors, self.warnings)


class ProjectError(Exception):
    """A project could not be loaded; carries every error found, in file order."""

    def __init__(self, errors: list[Diagnostic], warnings: list[Diagnostic] | None = None):
        self.errors = sorted(errors, key=lambda d: d.pos)
        self.warnings = warnings or []
        super().__init__("\n".join(str(d) for d in self.errors))

    @classmethod
    def single(cls, pos: SourcePos, message: str, expected: str | None = None) -> ProjectError:
        return cls([Diagnostic(pos, message, expected)])


class UsageError(Exception):
    """A command-line argument is wrong (a bad duration, an unknown fault...): exit status 2."""


def display_path(path: Path) -> str:
    """A path as the user most likely typed it: relative to the working directory if inside it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


# errno values that say the path given is not a usable file name (a folder, a missing
# folder): a bad argument. Any other failure (a full disk, no permission, an I/O error) is
# the system refusing at run time.
_BAD_PATH_ERRNOS = {errno.EISDIR, errno.ENOENT, errno.ENOTDIR, errno.ENAMETOOLONG, errno.ELOOP}


class OutputError(Exception):
    """Writing an output file (a trace, the journal) failed.

    `bad_path` is true when the path itself is unusable (a folder, a missing folder): a bad
    argument, exit status 2. Otherwise the system refused the write (a full disk, no
    permission, an I/O error): a failure at run time, exit status 1, after which a run stops
    with the plant's outputs written safe.
    """

    def __init__(self, what: str, path: Path, exc: OSError | str, bad_path: bool = False):
        if isinstance(exc, OSError):
            reason = exc.strerror or exc.__class__.__name__
            reason = reason[0].lower() + reason[1:]
            bad_path = bad_path or exc.errno in _BAD_PATH_ERRNOS
        else:
            reason = exc
        super().__init__(f"cannot write {what} {path}: {reason}")
        self.path = path
        self.bad_path = bad_path

"""What every command shares: loading the project, printing its errors, a failure at run
time and why a session ended."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Callable, Iterator
from types import FrameType
from typing import TYPE_CHECKING, TypeAlias

from hmi.errors import ProjectError, UsageError

if TYPE_CHECKING:
    import argparse

    from hmi.project.model import Project

    # What `add_parser(s)` of a command's module is given (argparse's own type for it).
    Subparsers: TypeAlias = argparse._SubParsersAction[argparse.ArgumentParser]

MAX_ERRORS_SHOWN = 25


def print_project_error(exc: ProjectError) -> None:
    shown = exc.errors[:MAX_ERRORS_SHOWN]
    for diagnostic in shown:
        print(diagnostic, file=sys.stderr)
    if len(exc.errors) > len(shown):
        print(f"... and {len(exc.errors) - len(shown)} more errors", file=sys.stderr)
    count = len(exc.errors)
    print(f"plchmi: the project has {count} error{'s' if count != 1 else ''}; nothing was run",
          file=sys.stderr)


def load(path: str, diagnoser: str | None = None) -> Project:
    from hmi.project.loader import load_project
    return load_project(path, diagnoser)


class RunFailure(Exception):
    """A failure at run time (exit status 1), with a message for the operator."""


def ended_by(exc: BaseException | None) -> str | None:
    """Why a session is ending, for the journal's last entry (None: it ended as asked).
    Called in a `finally`, with the exception on its way out, if any."""
    if exc is None:
        return None
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (SIGINT)"
    if isinstance(exc, RunFailure | UsageError):
        return str(exc)
    return f"internal error: {type(exc).__name__}: {exc}"


_CONTROL = str.maketrans({
    **{c: f"\\x{c:02x}" for c in [*range(0x20), *range(0x7f, 0xa0)] if c != 0x09},
    # the line and paragraph separators (an entry must stay one line for whoever splits the
    # output into lines) and the bidirectional controls (they reorder what a terminal shows)
    **{c: f"\\u{c:04x}" for c in [0x061C, 0x200E, 0x200F, 0x2028, 0x2029,
                                   *range(0x202A, 0x202F), *range(0x2066, 0x206A)]}})


def printable(value: object) -> str:
    """A text read from a file or a database, for the terminal: control characters (an ESC
    sequence written into a damaged or forged journal) shown as \\xNN, line separators and
    bidirectional controls as \\uNNNN, never sent to the terminal."""
    return str(value).translate(_CONTROL)


@contextlib.contextmanager
def on_termination(end: Callable[[str], None]) -> Iterator[None]:
    """Within the block, SIGTERM (a service manager) and SIGINT (Ctrl-C) call `end` with
    the signal's name instead of interrupting: the process then ends as asked."""
    def handler(signum: int, frame: FrameType | None) -> None:
        end(f"{signal.Signals(signum).name} received")
    previous = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)

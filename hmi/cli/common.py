"""What every command shares: loading the project, printing its errors, a failure at run
time and why a session ended."""

from __future__ import annotations

import sys

from hmi.errors import ProjectError, UsageError

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


def load(path: str, diagnoser: str | None = None):
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

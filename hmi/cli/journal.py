"""``plchmi journal PROJECT``: print or export the operator journal, damaged lines said on
stderr and skipped, control characters never sent to the terminal."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hmi.cli.common import printable as _printable
from hmi.cli.options import project_arg
from hmi.errors import UsageError
from hmi.timefmt import DurationError, parse_duration

JOURNAL_KINDS = ("action", "alarm", "recovery", "plant", "session")



def add_parser(sub) -> None:
    p = sub.add_parser(
        "journal", help="print or export a project's operator journal",
        description="Print or export a project's operator journal. A damaged line (an entry "
        "cut short by a killed process, or garbage) is skipped with a warning on stderr "
        "naming file:line and what is wrong; every readable entry is still printed and the "
        "exit status is 0. Exit status 1 only when there is no journal to read.")
    project_arg(p)
    p.add_argument("--since", metavar="WHEN",
                   help="only entries since WHEN: an ISO date/time, or a duration ago (2h)")
    p.add_argument("--csv", action="store_true", help="export as CSV")
    p.add_argument("--kind", action="append", default=[], metavar="KIND",
                   help="only entries of this kind (repeatable, or comma-separated): "
                   + ", ".join(JOURNAL_KINDS) + "; --kind alarm is the alarm history")
    p.add_argument("--path", type=Path, metavar="FILE", help="journal file to read")


def cmd_journal(args: argparse.Namespace) -> int:
    import csv

    from hmi.explain.journal import (
        JournalError,
        JournalPathError,
        default_path,
        read,
        since_filter,
    )
    from hmi.project.loader import load_project
    path = args.path or default_path(load_project(args.project).name)
    since = parse_since(args.since) if args.since else None
    try:
        result = read(path)
    except JournalError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    except JournalPathError as exc:
        raise UsageError(f"--path {exc}" if args.path else str(exc)) from None
    kinds = {k.strip() for text in args.kind for k in text.split(",") if k.strip()}
    unknown = sorted(kinds - set(JOURNAL_KINDS))
    if unknown:
        raise UsageError(f"--kind {', '.join(unknown)}: expected "
                         + ", ".join(JOURNAL_KINDS))
    entries = [e for e in since_filter(result.entries, since)
               if not kinds or e.get("type") in kinds]
    columns = ("wall", "scan", "t", "type", "event", "key", "state", "severity", "text",
               "message", "by")
    if args.csv:
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(columns)
        for entry in entries:
            writer.writerow([_printable(_field(entry, c)) for c in columns])
    else:
        for entry in entries:
            text = _field(entry, "text") or _field(entry, "message") or _field(entry, "project")
            key = f" {entry['key']}" if entry.get("key") else ""
            if isinstance(entry.get("by"), str):  # sent by an OPC UA client
                text = f"{text} [by {entry['by']}]"
            print(_printable(f"{_field(entry, 'wall')}  scan {_field(entry, 'scan'):>6}  "
                             f"t={_field(entry, 't')}  {_field(entry, 'type'):<7} "
                             f"{_field(entry, 'event')}{key}: {text}"))
    # Exit status 0 even with damaged lines: the readable entries are what the operator
    # needs; each damaged line is a warning on stderr (docs/journal.md).
    for bad in result.damaged:
        print(f"plchmi: warning: {path}:{bad.line}: damaged journal entry skipped: {bad.reason}",
              file=sys.stderr)
    if result.truncated:
        print(f"plchmi: the last entry of {path} was cut short (the process was killed while "
              "writing it); it is ignored", file=sys.stderr)
    return 0


def parse_since(text: str):
    """--since: a duration ago (2h) or an ISO date/time (local time unless it says its zone);
    anything else, or a time out of range, is a usage error."""
    from datetime import UTC, datetime, timedelta
    hint = "an ISO date/time (2026-11-22T15:00) or a duration ago (30m, 2h)"
    try:
        ago = parse_duration(text)
    except DurationError as exc:
        if "longer than" in exc.reason:
            raise UsageError(f"--since {text!r} {exc.reason}; give a date instead") from None
        ago = None
    if ago is not None:
        return datetime.now(UTC) - timedelta(microseconds=ago)
    try:
        if not text.isascii():
            raise ValueError(text)
        since = datetime.fromisoformat(text)
    except ValueError:
        raise UsageError(f"--since {text!r}: expected {hint}") from None
    if since.tzinfo is None:
        try:
            since = since.astimezone(UTC)  # as the operator's clock reads
        except (ValueError, OverflowError):  # at the very ends of the calendar
            since = since.replace(tzinfo=UTC)
    return since


def _field(entry: dict, name: str):
    """A field of a journal entry for display: "" when absent or null (the reader has checked
    the type of the fields it knows)."""
    value = entry.get(name)
    return "" if value is None else value

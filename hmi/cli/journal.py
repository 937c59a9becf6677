"""``plchmi journal PROJECT``: print or export the operator journal, damaged lines said on
stderr and skipped, control characters never sent to the terminal."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable, Iterator
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import printable as _printable
from hmi.cli.options import project_arg
from hmi.errors import UsageError
from hmi.limits import MAX_DAMAGED_SHOWN
from hmi.timefmt import DurationError, parse_duration

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers
    from hmi.explain.journal import Damaged, Entry

JOURNAL_KINDS = ("action", "alarm", "recovery", "plant", "session")



def add_parser(sub: Subparsers) -> None:
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


def add_verify_parser(sub: Subparsers) -> None:
    p = sub.add_parser(
        "journal-verify", help=argparse.SUPPRESS, prog="plchmi journal verify",
        description="Verify a journal's hash chain and anchor: every line must link to the "
        "one before it, and the end must be where the anchor says. Names the first broken "
        "link with its line. Exit status 0: intact; 1: broken, or no journal.")
    project_arg(p)
    p.add_argument("--path", type=Path, metavar="FILE", help="journal file to verify")


def cmd_verify(args: argparse.Namespace) -> int:
    from hmi.explain.chain import verify
    from hmi.explain.journal import JournalError, JournalPathError, default_path
    from hmi.project.loader import load_project
    path = args.path or default_path(load_project(args.project).name)
    try:
        verdict = verify(path)
    except JournalError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    except JournalPathError as exc:
        raise UsageError(f"--path {exc}" if args.path else str(exc)) from None
    for problem in verdict.breaks:
        where = f"{path}:{problem.line}" if problem.line else str(path)
        print(_printable(f"{where}: broken: {problem.what}"))
    for note in verdict.notes:
        print(_printable(f"{path}: note: {note}"))
    if verdict.crash_cuts:
        print(f"{path}: note: lines cut by a killed writer (declared by the session that "
              f"followed, or the last line): {', '.join(map(str, verdict.crash_cuts))}")
    if verdict.unchained:
        print(f"{path}: note: the first {verdict.unchained:,} lines were written before the "
              "journal carried a hash chain: they cannot be verified")
    if verdict.anchor:
        print(_printable(f"{path}: {verdict.anchor}"))
    if verdict.intact:
        print(f"{path}: {verdict.lines:,} lines, the chain intact")
        return 0
    more = verdict.break_count - len(verdict.breaks)
    print(f"{path}: NOT INTACT: {verdict.break_count:,} broken link"
          f"{'s' if verdict.break_count != 1 else ''} in {verdict.lines:,} lines, the first at "
          f"line {verdict.breaks[0].line}" + (f" ({more:,} more not listed)" if more else ""))
    return 1


def cmd_journal(args: argparse.Namespace) -> int:
    import csv

    from hmi.explain.journal import (
        JournalError,
        JournalPathError,
        default_path,
        since_filter,
        stream,
    )
    from hmi.project.loader import load_project
    path = args.path or default_path(load_project(args.project).name)
    since = parse_since(args.since) if args.since else None
    kinds = {k.strip() for text in args.kind for k in text.split(",") if k.strip()}
    unknown = sorted(kinds - set(JOURNAL_KINDS))
    if unknown:
        raise UsageError(f"--kind {', '.join(unknown)}: expected "
                         + ", ".join(JOURNAL_KINDS))
    try:
        items = stream(path)
    except JournalError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    except JournalPathError as exc:
        raise UsageError(f"--path {exc}" if args.path else str(exc)) from None
    damaged = DamagedLines(path)
    entries = (e for e in since_filter(damaged.skipped(items), since)
               if not kinds or e.get("type") in kinds)
    if args.csv:
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for entry in entries:
            writer.writerow([_printable(_csv_field(entry, c)) for c in CSV_COLUMNS])
    else:
        for entry in entries:
            text = _field(entry, "text") or _field(entry, "message") or started(entry)
            key = f" {entry['key']}" if entry.get("key") else ""
            if isinstance(entry.get("by"), str):  # sent by an OPC UA client
                text = f"{text} [by {entry['by']}]"
            print(_printable(f"{_field(entry, 'wall')}  scan {_field(entry, 'scan'):>6}  "
                             f"t={_field(entry, 't')}  {_field(entry, 'type'):<7} "
                             f"{_field(entry, 'event')}{key}: {text}"))
    damaged.finish()
    return 0


class DamagedLines:
    """The damaged lines of a journal being read, said on stderr as they are met: the first
    MAX_DAMAGED_SHOWN each with its line and reason, the rest counted and said once at the
    end (a file of a million lines of garbage is a few lines of warnings, not a million).
    Exit status 0 even with damaged lines: the readable entries are what the operator needs
    (docs/journal.md)."""

    def __init__(self, path: Path | str) -> None:
        self.path = path
        self.more = 0
        self.shown = 0
        self.truncated = False

    def skipped(self, items: Iterable[Entry | Damaged]) -> Iterator[Entry]:
        """The entries of `items`, each Damaged among them said (or counted) and left out."""
        from hmi.explain.journal import Damaged
        for item in items:
            if not isinstance(item, Damaged):
                yield item
                continue
            self.truncated = self.truncated or item.cut
            if self.shown < MAX_DAMAGED_SHOWN:
                self.shown += 1
                print(f"plchmi: warning: {self.path}:{item.line}: damaged journal entry "
                      f"skipped: {item.reason}", file=sys.stderr)
            else:
                self.more += 1

    def finish(self) -> None:
        if self.more:
            print(f"plchmi: warning: {self.path}: ... and {self.more:,} more damaged lines "
                  "skipped", file=sys.stderr)
        if self.truncated:
            print(f"plchmi: the last entry of {self.path} was cut short (the process was "
                  "killed while writing it); it is ignored", file=sys.stderr)


def parse_since(text: str) -> datetime:
    """--since: a duration ago (2h) or an ISO date/time (local time unless it says its zone);
    anything else, or a time out of range, is a usage error."""
    from datetime import UTC, timedelta
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


# The CSV's columns: the first eleven as they always were, then whether an action was accepted
# (true / false; blank for other entries) and the session the entry belongs to (its id,
# written into every entry; blank in journals written before it was).
CSV_COLUMNS = ("wall", "scan", "t", "type", "event", "key", "state", "severity", "text",
               "message", "by", "accepted", "session")


def started(entry: Entry) -> str:
    """A session's start in words: project, control program, filter policy, plant (what the
    JSON entry holds in fields of its own); "" for any other entry."""
    if entry.get("type") != "session" or entry.get("event") != "start":
        return ""
    parts = [f"{label} {entry[name]}" for name, label in (
        ("project", "project"), ("control", "control"), ("policy", "filter policy"),
        ("plant", "plant"), ("source", "from")) if isinstance(entry.get(name), str)]
    return "started: " + ", ".join(parts) if parts else ""


def _csv_field(entry: Entry, name: str) -> object:
    if name == "accepted":
        value = entry.get("accepted")
        return "" if not isinstance(value, bool) else ("true" if value else "false")
    if name == "message":
        return _field(entry, "message") or started(entry)
    return _field(entry, name)


def _field(entry: Entry, name: str) -> object:
    """A field of a journal entry for display: "" when absent or null (the reader has checked
    the type of the fields it knows)."""
    value = entry.get(name)
    return "" if value is None else value

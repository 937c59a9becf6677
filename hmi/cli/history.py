"""``plchmi history PROJECT``: a cell's history, as the trend screens read it: values over a
window (a table, or CSV), the signals it holds, the alarms and actions."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from hmi.cli.common import load, printable
from hmi.cli.options import project_arg
from hmi.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from hmi.cli.common import Subparsers
    from hmi.history.catalogue import Signal
    from hmi.history.query import HistoryReader


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser(
        "history", help="print or export a cell's history (values, alarms, actions)",
        description="Print or export what the historian kept of a cell: the values of "
        "chosen signals over a window (each row an instant where one changed; a value is "
        "empty where the history does not cover it), the signals it holds (--list), or "
        "the alarms and operator actions (--events). Exit status 1 when the cell has no "
        "history there.")
    project_arg(p)
    p.add_argument("--signals", metavar="NAMES", default="",
                   help="comma-separated signal names, e.g. fso,C,V1.state (--list shows "
                   "them; default: the inputs and outputs)")
    p.add_argument("--since", metavar="WHEN", default="1h",
                   help="start of the window: a length back from now (2h, 7d) or a date and "
                   "time (2026-11-18T03:00, local time unless it says its zone); "
                   "default 1h")
    p.add_argument("--until", metavar="WHEN", default="now",
                   help="end of the window, written as --since (default: now)")
    p.add_argument("--csv", action="store_true",
                   help="CSV: time (ISO 8601, UTC) then one column per signal")
    p.add_argument("--list", action="store_true", help="list the signals the history holds")
    p.add_argument("--events", action="store_true",
                   help="list the alarms and operator actions of the window")
    p.add_argument("--historian", metavar="TARGET",
                   help="where the history is: a SQLite file or a postgresql:// URL "
                   "(default: the cell's file in the data folder)")


def cmd_history(args: argparse.Namespace) -> int:
    import time

    from hmi.history.query import HistoryReader, local_time, write_csv
    from hmi.history.span import SpanError, parse_instant
    from hmi.history.store import StoreError
    from hmi.history.target import default_target, open_store, parse_target

    cell = load(args.project).name
    try:
        target = parse_target(args.historian) if args.historian else default_target(cell)
    except ValueError as exc:
        raise UsageError(f"--historian: {exc}") from None
    now = time.time_ns() // 1000
    try:
        start = parse_instant(args.since, now)
        end = parse_instant(args.until, now)
    except SpanError as exc:
        raise UsageError(str(exc)) from None
    if end <= start:
        raise UsageError(f"--until ({local_time(end)}) is not after --since "
                         f"({local_time(start)})")
    try:
        store = open_store(target, read_only=True)
    except StoreError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    try:
        reader = HistoryReader(store, cell)
        signals = reader.signals()
        if not signals:
            print(f"plchmi: no history of {cell} in {target.describe()}", file=sys.stderr)
            return 1
        if args.list:
            _list(signals)
            return 0
        if args.events:
            _events(reader, start, end, args.csv)
            return 0
        names = _names(args.signals, signals)
        if args.csv:
            write_csv(reader, names, start, end, sys.stdout)
        else:
            _table(reader, names, start, end)
    except StoreError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    finally:
        store.close()
    return 0


def _names(text: str, signals: Sequence[Signal]) -> list[str]:
    known = {s.name for s in signals}
    if not text.strip():
        return [s.name for s in signals if s.group == "io" and s.kind == "bool"][:8]
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown:
        import difflib
        hints = []
        for name in unknown:
            close = difflib.get_close_matches(name, sorted(known), n=3)
            hints.append(f"{name!r}" + (f" (did you mean {', '.join(close)}?)" if close
                                        else ""))
        raise UsageError(f"--signals: no signal {'; '.join(hints)} in this history "
                         "(--list shows them)")
    return names


def _list(signals: Sequence[Signal]) -> None:
    width = max(len(s.name) for s in signals)
    for s in signals:
        unit = f" ({s.unit})" if s.unit else ""
        labels = f" [{', '.join(s.labels)}]" if s.labels and len(s.labels) <= 6 else \
            (f" [{len(s.labels)} states]" if s.labels else "")
        print(printable(f"{s.name:<{width}}  {s.kind:<7} {s.group:<11} "
                        f"{s.description}{unit}{labels}"))


def _table(reader: HistoryReader, names: list[str], start: int, end: int) -> None:
    from hmi.history.query import export_rows, local_time
    signals = [reader.signal(n) for n in names]
    known = [s for s in signals if s is not None]
    assert len(known) == len(signals)  # _names keeps the known ones only
    widths = [max(len(n), 5) for n in names]
    print(printable("time                  " + "  ".join(
        n.rjust(w) for n, w in zip(names, widths, strict=True))))
    rows = 0
    for t, values in export_rows(reader, names, start, end):
        cells = [(s.text(v) if v is not None else "-").rjust(w)
                 for s, v, w in zip(known, values, widths, strict=True)]
        frac = f".{(t % 1_000_000) // 1000:03d}"
        print(printable(f"{local_time(t)}{frac}  " + "  ".join(cells)))
        rows += 1
    if not rows:
        print(f"(nothing recorded between {local_time(start)} and {local_time(end)})")


def _events(reader: HistoryReader, start: int, end: int, as_csv: bool) -> None:
    from hmi.history.query import iso, local_time
    events = reader.events(start, end)
    if as_csv:
        import csv
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(["time", "type", "event", "key", "severity", "text", "by"])
        for e in events:
            writer.writerow([iso(e.t_us), e.type, e.event, e.key, e.severity, e.text, e.by])
        return
    for e in events:
        key = f" {e.key}" if e.key else ""
        by = f" [by {e.by}]" if e.by else ""
        print(printable(f"{local_time(e.t_us)}  {e.type:<8} {e.event}{key}: {e.text}{by}"))
    if not events:
        print(f"(no alarm or action between {local_time(start)} and {local_time(end)})")

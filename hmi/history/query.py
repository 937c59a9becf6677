"""Reading a cell's history: values at an instant, a window in columns, the CSV export.

What a reader may state: a value is known at an instant only inside a segment (a stretch the
history covers) and from the segment's first sample on; outside, it is unknown (None), and
the trends draw nothing there rather than a guess. Everything here reads through a
:class:`~hmi.history.store.Store` (read-only is enough) and is the same on both back-ends.
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TextIO

from hmi.history.catalogue import BOOL, COUNTER, ENUM, NUMBER, Signal
from hmi.history.store import Event, Segment, Store


@dataclass(frozen=True)
class Column:
    """One column of a drawing: column c covers (start + c·span/n, start + (c+1)·span/n]."""

    known: bool  # some of the column is covered by the history
    before: float | None  # the value in force as the column begins (None: unknown)
    count: int = 0  # samples inside the column
    low: float = 0.0
    high: float = 0.0
    last: float | None = None  # the value as the column ends (None: unknown)
    opens: bool = False  # a segment starts inside it: its first samples are not changes


@dataclass(frozen=True)
class Drawn:
    """One signal over a window, in columns."""

    signal: Signal
    columns: tuple[Column, ...]


@dataclass(frozen=True)
class Window:
    """What a trend draws: its signals in columns, the alarms and actions, the segments."""

    start_us: int
    end_us: int
    width: int
    drawn: tuple[Drawn, ...]
    events: tuple[Event, ...]
    segments: tuple[Segment, ...]


class HistoryReader:
    """One cell's history, for reading."""

    def __init__(self, store: Store, cell: str):
        self.store = store
        self.cell = cell
        self._signals: dict[str, Signal] | None = None

    def signals(self) -> list[Signal]:
        if self._signals is None:
            self._signals = {s.name: s for s in self.store.signals(self.cell)}
        return list(self._signals.values())

    def signal(self, name: str) -> Signal | None:
        if self._signals is None:
            self.signals()
        assert self._signals is not None
        return self._signals.get(name)

    def span(self) -> tuple[int, int] | None:
        return self.store.span(self.cell)

    def segments(self, start_us: int, end_us: int) -> list[Segment]:
        return self.store.segments(self.cell, start_us, end_us)

    def events(self, start_us: int, end_us: int, types: Iterable[str] = ()) -> list[Event]:
        return self.store.events(self.cell, start_us, end_us, types)

    def value_at(self, name: str, t_us: int,
                 segments: Sequence[Segment] | None = None) -> float | None:
        """The value in force at `t_us`: the last sample at or before it, if a segment
        holds both; None (unknown) otherwise."""
        segs = self.segments(t_us, t_us) if segments is None else segments
        holding = next((s for s in reversed(segs) if s.start_us <= t_us <= s.end_us), None)
        if holding is None:
            return None
        sample = self.store.before(self.cell, name, t_us)
        if sample is None or sample.t_us < holding.start_us:
            return None
        return sample.value

    def values_at(self, names: Iterable[str], t_us: int) -> dict[str, float | None]:
        segments = self.segments(t_us, t_us)
        return {name: self.value_at(name, t_us, segments) for name in names}

    def window(self, names: Sequence[str], start_us: int, end_us: int, width: int,
               event_types: Iterable[str] = ("alarm", "action")) -> Window:
        """The signals `names` over (start, end] in `width` columns, with the events and
        segments of the window: what a trend draws, in a handful of queries per signal
        however long the window (the store groups the samples by column)."""
        width = max(1, width)
        segments = self.segments(start_us, end_us)
        drawn = []
        for name in names:
            signal = self.signal(name)
            if signal is None:
                continue
            drawn.append(Drawn(signal, self._columns(name, start_us, end_us, width, segments)))
        return Window(start_us, end_us, width, tuple(drawn),
                      tuple(self.events(start_us, end_us, event_types)), tuple(segments))

    def _columns(self, name: str, start_us: int, end_us: int, width: int,
                 segments: Sequence[Segment]) -> tuple[Column, ...]:
        span = end_us - start_us
        buckets = {b.column: b for b in self.store.buckets(self.cell, name, start_us, end_us,
                                                           width)}
        carry = self.value_at(name, start_us, segments)
        columns = []
        for c in range(width):
            a = start_us + c * span // width
            b = start_us + (c + 1) * span // width
            overlapping = [s for s in segments if s.start_us <= b and s.end_us > a]
            if not overlapping:
                carry = None
                columns.append(Column(False, None))
                continue
            opens = any(a < s.start_us <= b for s in overlapping)
            if opens:
                carry = None
            bucket = buckets.get(c)
            before = carry
            if bucket is not None:
                carry = bucket.last
                columns.append(Column(True, before, bucket.count, bucket.low, bucket.high,
                                      carry, opens))
            else:
                columns.append(Column(True, before, 0, 0.0, 0.0, carry, opens))
            if not any(s.end_us > b for s in overlapping):
                carry = None  # the covered time ends inside this column
        return tuple(columns)


# -- text ------------------------------------------------------------------------------------

def local_time(t_us: int, seconds: bool = True) -> str:
    """An instant in the machine's local time: 2026-11-18 03:12:05."""
    when = datetime.fromtimestamp(t_us / 1e6, UTC).astimezone()
    return when.strftime("%Y-%m-%d %H:%M:%S" if seconds else "%Y-%m-%d %H:%M")


def iso(t_us: int) -> str:
    """An instant as ISO 8601 in UTC, to the microsecond (the CSV's time column)."""
    return datetime.fromtimestamp(t_us // 1_000_000, UTC).replace(
        microsecond=t_us % 1_000_000).isoformat().replace("+00:00", "Z")


def cell_text(signal: Signal, value: float | None) -> str:
    """A value in a CSV cell: empty when unknown; 0/1; an enum's label; a number."""
    if value is None:
        return ""
    if signal.kind == BOOL:
        return "1" if value else "0"
    if signal.kind == ENUM:
        return signal.text(value)
    if signal.kind == COUNTER:
        return str(int(value))
    if signal.kind == NUMBER:
        return f"{value:.6g}"
    return str(value)


def export_rows(reader: HistoryReader, names: Sequence[str], start_us: int, end_us: int
                ) -> Iterable[tuple[int, list[float | None]]]:
    """(time, values) at every instant of (start, end] where a chosen signal has a sample,
    each value carried forward inside its segment. The first row is at `start` when the
    history covers it; where the history stops (a segment's end, then nothing until the
    next), a row of unknowns one microsecond after the last instant covered."""
    segments = reader.segments(start_us, end_us)
    times: dict[int, dict[int, float]] = {}
    for k, name in enumerate(names):
        for sample in reader.store.samples(reader.cell, name, start_us, end_us):
            times.setdefault(sample.t_us, {})[k] = sample.value
    starts = {s.start_us for s in segments}
    blanks = {s.end_us + 1 for s in segments
              if s.end_us < end_us and not any(o.start_us <= s.end_us + 1 <= o.end_us
                                               for o in segments)}
    for t in blanks:
        times.setdefault(t, {})
    current: list[float | None] = [reader.value_at(n, start_us, segments) for n in names]
    if any(v is not None for v in current):
        yield start_us, list(current)
    for t in sorted(times):
        if t in starts or t in blanks:
            current = [None] * len(names)
        for k, v in times[t].items():
            current[k] = v
        yield t, list(current)


def write_csv(reader: HistoryReader, names: Sequence[str], start_us: int, end_us: int,
              out: TextIO) -> int:
    """The export as CSV: ``time`` (ISO 8601, UTC) then one column per signal. Returns the
    rows written."""
    signals = [reader.signal(n) for n in names]
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["time", *names])
    rows = 0
    for t, values in export_rows(reader, names, start_us, end_us):
        writer.writerow([iso(t), *(cell_text(s, v) for s, v in zip(signals, values,
                                                                      strict=True) if s)])
        rows += 1
    return rows

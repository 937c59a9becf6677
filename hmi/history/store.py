"""The historian's store: one interface, two back-ends (sqlite.py, postgres.py).

What is stored, per cell (the project's name):

* **signals**: the catalogue's definitions (hmi.history.catalogue), kept across sessions; an
  enum's labels only grow, so a value stored under an older project keeps its meaning;
* **samples**: (signal, time, value), time in microseconds since the Unix epoch (UTC), one
  row per change (Booleans, enums, counters) or per deadband step (numbers); an enum's value
  is the index of its label;
* **events**: the journal's alarm transitions, operator actions and session entries, with
  their time;
* **segments**: the stretches of time the history covers (a session, or the part of it
  between two losses): outside them nothing is known, and a trend says so rather than
  drawing the last value across a night the cell did not run.

Both back-ends answer the same queries with the same rows (tests/test_history_store.py runs
each query on both). Times in a query are inclusive at the end and exclusive at the start
(a window (start, end]), as the chronogram's columns are.

Retention (:meth:`Store.delete_before`) deletes every sample, event and segment before the
cutoff, except that each signal's value in force at the cutoff is kept as a sample at the
cutoff itself: what a query reads at any instant from the cutoff on is the same before and
after.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from hmi.history.catalogue import KINDS, Signal

SCHEMA_VERSION = 1


class StoreError(Exception):
    """The store cannot be opened, read or written (disk full, server gone, not a history
    database); the message says what and where, in plain words."""


@dataclass(frozen=True)
class Sample:
    t_us: int
    value: float


@dataclass(frozen=True)
class Bucket:
    """The samples of one column of a drawing: column c covers (start + c·span/n,
    start + (c+1)·span/n]."""

    column: int
    count: int
    low: float
    high: float
    last: float


@dataclass(frozen=True)
class Event:
    t_us: int
    type: str  # alarm, action, session, recovery, plant
    event: str  # raised, acknowledged, ...; the action's words
    key: str  # the alarm's key ("" for others)
    severity: str
    text: str  # the alarm's text, or the entry's message
    by: str  # who sent the action ("" for the cell's operator)
    data: dict[str, Any]  # the whole journal entry


@dataclass(frozen=True)
class Segment:
    start_us: int
    end_us: int
    source: str  # hmi, run
    clock: str  # real (the wall clock) or virtual (a simulation's time)


# One write: samples as (signal id, time, value), events, and the segment bookkeeping.
Row = tuple[int, int, float]


@dataclass
class Batch:
    samples: list[Row]
    events: list[Event]
    segment: int | None = None  # the segment whose end moves to `covered`
    covered_us: int | None = None
    # a loss inside the batch: the segment ends at its start, a new one begins at its end
    gaps: tuple[tuple[int, int], ...] = ()


def signal_row(signal: Signal) -> tuple[str, str, str, str, str, str, str]:
    return (signal.name, signal.kind, signal.description, signal.group, signal.device,
            signal.unit, json.dumps(list(signal.labels), ensure_ascii=False))


def signal_from(row: Sequence[Any]) -> Signal:
    name, kind, description, group, device, unit, labels = row
    if kind not in KINDS:
        raise StoreError(f"signal {name!r} has an unknown kind {kind!r}")
    return Signal(name, kind, description, group, device, unit, labels_of(labels))


def labels_of(text: str) -> tuple[str, ...]:
    value = json.loads(text)
    return tuple(str(v) for v in value) if isinstance(value, list) else ()


def merged_labels(old: tuple[str, ...], new: tuple[str, ...]) -> tuple[str, ...]:
    """An enum's labels after a project change: the old ones in place, new ones after."""
    return (*old, *(label for label in new if label not in old))


def event_row(event: Event) -> tuple[int, str, str, str, str, str, str, str]:
    return (event.t_us, event.type, event.event, event.key, event.severity, event.text,
            event.by, json.dumps(event.data, ensure_ascii=False, default=str))


def event_from(row: Sequence[Any]) -> Event:
    t, type_, event, key, severity, text, by, data = row
    return Event(int(t), type_, event, key, severity, text, by, json.loads(data))


class Store(ABC):
    """A connection to a history database (read-only when opened for reading)."""

    where: str  # the file or the server, for messages

    # -- writing (the runtime's writer thread) --------------------------------------------
    @abstractmethod
    def prepare(self, cell: str, signals: Sequence[Signal]
                ) -> list[tuple[int, tuple[str, ...]]]:
        """The cell's signals defined (created or brought up to date): each one's id and
        labels as stored, in order. An enum keeps its stored labels first (merged_labels),
        so that stored values keep their meaning; the writer maps the catalogue's indices
        onto these."""

    @abstractmethod
    def begin_segment(self, cell: str, start_us: int, source: str, clock: str) -> int:
        """A new stretch of covered time starting at `start_us`; its id."""

    @abstractmethod
    def write(self, cell: str, batch: Batch) -> None:
        """Everything in `batch` in one transaction: all of it is stored, or none."""

    @abstractmethod
    def delete_before(self, cell: str, cutoff_us: int) -> int:
        """Retention: see the module's docstring. Returns the rows deleted."""

    @abstractmethod
    def close(self) -> None: ...

    # -- reading (the query API: hmi.history.query, trends, OPC UA) -------------------------
    @abstractmethod
    def cells(self) -> list[str]: ...

    @abstractmethod
    def signals(self, cell: str) -> list[Signal]:
        """The stored definitions of a cell's signals (what a reader can ask for)."""

    @abstractmethod
    def segments(self, cell: str, start_us: int, end_us: int) -> list[Segment]:
        """The segments that overlap [start, end], in time order."""

    @abstractmethod
    def samples(self, cell: str, name: str, start_us: int, end_us: int,
                limit: int | None = None) -> list[Sample]:
        """A signal's samples with start < t <= end, in time order (at most `limit`)."""

    @abstractmethod
    def before(self, cell: str, name: str, t_us: int) -> Sample | None:
        """A signal's last sample at or before `t_us`."""

    @abstractmethod
    def buckets(self, cell: str, name: str, start_us: int, end_us: int, count: int
                ) -> list[Bucket]:
        """The samples of (start, end] grouped into `count` columns (only the columns that
        have samples), for drawing a long window without reading every sample."""

    @abstractmethod
    def events(self, cell: str, start_us: int, end_us: int,
               types: Iterable[str] = ()) -> list[Event]:
        """Events with start < t <= end (of these types; all if none), in time order."""

    @abstractmethod
    def span(self, cell: str) -> tuple[int, int] | None:
        """The first and last instant the cell's history covers (None: nothing yet)."""


def describe_url(url: str) -> str:
    """A PostgreSQL URL for messages, without its password."""
    from urllib.parse import urlsplit
    parts = urlsplit(url)
    host = parts.hostname or "the local socket"
    port = f":{parts.port}" if parts.port else ""
    return f"PostgreSQL database {parts.path.lstrip('/') or '(default)'} on {host}{port}"

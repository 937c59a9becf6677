"""The SQL both stores share: one schema, one set of statements (hmi.history.sqlite and
hmi.history.postgres differ only in their connection, transactions, placeholders, the
per-column grouping of a drawing and PostgreSQL's partitions).

Statements are written with ``?`` placeholders; PostgreSQL's store turns them into ``%s``.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import replace
from typing import Any, TypeVar

from hmi.history.catalogue import Signal
from hmi.history.store import (
    SCHEMA_VERSION,
    Batch,
    Bucket,
    Event,
    Sample,
    Segment,
    Store,
    StoreError,
    event_from,
    event_row,
    labels_of,
    merged_labels,
    signal_from,
    signal_row,
)

T = TypeVar("T")
EVENT_COLUMNS = "t, type, event, key, severity, text, by, data"
SIGNAL_COLUMNS = "name, kind, description, grp, device, unit, labels"
MOVED = 1_000_000  # the position of a signal the project no longer has: listed after


class SqlStore(Store):
    """A store over one DB-API connection; subclasses open it and say their dialect."""

    db: Any
    errors: tuple[type[Exception], ...] = ()  # the driver's errors, told as StoreError
    # The samples of (start, end] grouped into columns: (column, count, least, greatest,
    # last) per column that has samples; its parameters start, count, span, span, signal,
    # start, end. Each dialect says how it takes a group's last value.
    bucket_sql = ""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # one connection, used from the caller's threads
        self._cells: dict[str, int] = {}

    # -- what a dialect provides -------------------------------------------------------------
    def sql(self, statement: str) -> str:
        return statement

    @contextlib.contextmanager
    def transaction(self, db: Any) -> Iterator[None]:
        raise NotImplementedError
        yield

    def words(self, exc: Exception) -> str:
        return " ".join(str(exc).split()) or type(exc).__name__

    def before_write(self, db: Any, times: Iterable[int]) -> None:
        """Called before a batch's transaction with the times it holds."""

    def after_delete(self, db: Any, cutoff_us: int) -> None:
        """Called after retention's transaction."""

    # -- helpers --------------------------------------------------------------------------------
    def _run(self, work: Callable[[Any], T]) -> T:
        """`work(db)` under the connection's lock; a driver error becomes a StoreError."""
        with self._lock:
            try:
                return work(self.db)
            except self.errors as exc:
                self._cells.clear()  # (a cell created by a transaction rolled back)
                raise StoreError(f"{self.where}: {self.words(exc)}") from None

    def _x(self, db: Any, statement: str, params: Sequence[Any] = ()) -> Any:
        return db.execute(self.sql(statement), tuple(params))

    def _one(self, db: Any, statement: str, params: Sequence[Any] = ()) -> Any:
        return self._x(db, statement, params).fetchone()

    def _all(self, db: Any, statement: str, params: Sequence[Any] = ()) -> list[Any]:
        return list(self._x(db, statement, params).fetchall())

    def _many(self, db: Any, statement: str, rows: Sequence[Sequence[Any]]) -> None:
        if rows:
            with contextlib.closing(db.cursor()) as cursor:
                cursor.executemany(self.sql(statement), rows)

    def check_schema(self, db: Any) -> None:
        row = self._one(db, "SELECT value FROM plchmi_meta WHERE key = 'schema'")
        if row is None:
            raise StoreError(f"{self.where}: not a plchmi history (no schema)")
        if row[0] != str(SCHEMA_VERSION):
            raise StoreError(f"{self.where}: a history of schema {row[0]}, this plchmi reads "
                             f"schema {SCHEMA_VERSION}")

    def _cell(self, db: Any, cell: str, create: bool = False) -> int | None:
        found = self._cells.get(cell)
        if found is not None:
            return found
        row = self._one(db, "SELECT id FROM plchmi_cells WHERE name = ?", (cell,))
        if row is None:
            if not create:
                return None
            row = self._one(db, "INSERT INTO plchmi_cells (name) VALUES (?) ON CONFLICT (name) "
                            "DO UPDATE SET name = excluded.name RETURNING id", (cell,))
        self._cells[cell] = int(row[0])
        return int(row[0])

    def _signal(self, db: Any, cell: str, name: str) -> int | None:
        cell_id = self._cell(db, cell)
        if cell_id is None:
            return None
        row = self._one(db, "SELECT id FROM plchmi_signals WHERE cell = ? AND name = ?",
                        (cell_id, name))
        return None if row is None else int(row[0])

    # -- writing ----------------------------------------------------------------------------
    def prepare(self, cell: str, signals: Sequence[Signal]
                ) -> list[tuple[int, tuple[str, ...]]]:
        def work(db: Any) -> list[tuple[int, tuple[str, ...]]]:
            with self.transaction(db):
                cell_id = self._cell(db, cell, create=True)
                stored = {row[1]: row for row in self._all(
                    db, "SELECT id, name, labels FROM plchmi_signals WHERE cell = ?",
                    (cell_id,))}
                self._x(db, "UPDATE plchmi_signals SET position = position + ? "
                        "WHERE cell = ? AND position < ?", (MOVED, cell_id, MOVED))
                found = []
                for position, signal in enumerate(signals):
                    old = stored.get(signal.name)
                    if old is not None:
                        signal = replace(signal, labels=merged_labels(labels_of(old[2]),
                                                                      signal.labels))
                        self._x(db, "UPDATE plchmi_signals SET kind = ?, description = ?, "
                                "grp = ?, device = ?, unit = ?, labels = ?, position = ? "
                                "WHERE id = ?", (*signal_row(signal)[1:], position, old[0]))
                        found.append((int(old[0]), signal.labels))
                    else:
                        row = self._one(
                            db, f"INSERT INTO plchmi_signals (cell, {SIGNAL_COLUMNS}, "
                            "position) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) RETURNING id",
                            (cell_id, *signal_row(signal), position))
                        found.append((int(row[0]), signal.labels))
            return found
        return self._run(work)

    def begin_segment(self, cell: str, start_us: int, source: str, clock: str) -> int:
        def work(db: Any) -> int:
            cell_id = self._cell(db, cell, create=True)
            return int(self._one(
                db, 'INSERT INTO plchmi_segments (cell, start, "end", source, clock) '
                "VALUES (?, ?, ?, ?, ?) RETURNING id",
                (cell_id, start_us, start_us, source, clock))[0])
        return self._run(work)

    def write(self, cell: str, batch: Batch) -> None:
        def work(db: Any) -> None:
            cell_id = self._cell(db, cell, create=True)
            self.before_write(db, [*(t for _, t, _ in batch.samples),
                                   *(e.t_us for e in batch.events)])
            segment = batch.segment
            with self.transaction(db):
                self._many(db, "INSERT INTO plchmi_samples (signal, t, value) VALUES (?, ?, ?) "
                           "ON CONFLICT (signal, t) DO UPDATE SET value = excluded.value",
                           batch.samples)
                self._many(db, f"INSERT INTO plchmi_events (cell, {EVENT_COLUMNS}) "
                           "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                           [(cell_id, *event_row(e)) for e in batch.events])
                if segment is not None:
                    for start, end in batch.gaps:
                        self._x(db, 'UPDATE plchmi_segments SET "end" = ? WHERE id = ?',
                                (start, segment))
                        segment = int(self._one(
                            db, 'INSERT INTO plchmi_segments (cell, start, "end", source, '
                            "clock) SELECT cell, ?, ?, source, clock FROM plchmi_segments "
                            "WHERE id = ? RETURNING id", (end, end, segment))[0])
                    if batch.covered_us is not None:
                        self._x(db, 'UPDATE plchmi_segments SET "end" = CASE WHEN "end" > ? '
                                'THEN "end" ELSE ? END WHERE id = ?',
                                (batch.covered_us, batch.covered_us, segment))
            batch.segment = segment
        self._run(work)

    def delete_before(self, cell: str, cutoff_us: int) -> int:
        def work(db: Any) -> int:
            cell_id = self._cell(db, cell)
            if cell_id is None:
                return 0
            deleted = 0
            with self.transaction(db):
                holding = self._one(
                    db, 'SELECT start FROM plchmi_segments WHERE cell = ? AND start < ? '
                    'AND "end" >= ? ORDER BY start DESC LIMIT 1',
                    (cell_id, cutoff_us, cutoff_us))
                if holding is not None:
                    self.before_write(db, [cutoff_us])
                for (signal,) in self._all(db, "SELECT id FROM plchmi_signals WHERE cell = ?",
                                           (cell_id,)):
                    if holding is not None:  # the value in force at the cutoff is kept
                        last = self._one(
                            db, "SELECT t, value FROM plchmi_samples WHERE signal = ? "
                            "AND t < ? ORDER BY t DESC LIMIT 1", (signal, cutoff_us))
                        if last is not None and last[0] >= holding[0]:
                            self._x(db, "INSERT INTO plchmi_samples VALUES (?, ?, ?) "
                                    "ON CONFLICT DO NOTHING", (signal, cutoff_us, last[1]))
                    deleted += self._x(db, "DELETE FROM plchmi_samples WHERE signal = ? "
                                       "AND t < ?", (signal, cutoff_us)).rowcount
                deleted += self._x(db, "DELETE FROM plchmi_events WHERE cell = ? AND t < ?",
                                   (cell_id, cutoff_us)).rowcount
                deleted += self._x(db, 'DELETE FROM plchmi_segments WHERE cell = ? '
                                   'AND "end" < ?', (cell_id, cutoff_us)).rowcount
                self._x(db, "UPDATE plchmi_segments SET start = ? WHERE cell = ? AND start < ?",
                        (cutoff_us, cell_id, cutoff_us))
            self.after_delete(db, cutoff_us)
            return int(deleted)
        return self._run(work)

    def close(self) -> None:
        with self._lock:
            self.db.close()

    # -- reading ----------------------------------------------------------------------------
    def cells(self) -> list[str]:
        return self._run(lambda db: [r[0] for r in self._all(
            db, "SELECT name FROM plchmi_cells ORDER BY name")])

    def signals(self, cell: str) -> list[Signal]:
        def work(db: Any) -> list[Signal]:
            return [signal_from(row) for row in self._all(
                db, f"SELECT {SIGNAL_COLUMNS} FROM plchmi_signals WHERE cell = ? "
                "ORDER BY position, id", (self._cell(db, cell),))]
        return self._run(work)

    def segments(self, cell: str, start_us: int, end_us: int) -> list[Segment]:
        def work(db: Any) -> list[Segment]:
            return [Segment(int(a), int(b), c, d) for a, b, c, d in self._all(
                db, 'SELECT start, "end", source, clock FROM plchmi_segments WHERE cell = ? '
                'AND "end" >= ? AND start <= ? ORDER BY start, id',
                (self._cell(db, cell), start_us, end_us))]
        return self._run(work)

    def samples(self, cell: str, name: str, start_us: int, end_us: int,
                limit: int | None = None) -> list[Sample]:
        def work(db: Any) -> list[Sample]:
            signal = self._signal(db, cell, name)
            if signal is None:
                return []
            bound = "" if limit is None else f" LIMIT {int(limit)}"
            return [Sample(int(t), float(v)) for t, v in self._all(
                db, "SELECT t, value FROM plchmi_samples WHERE signal = ? AND t > ? "
                f"AND t <= ? ORDER BY t{bound}", (signal, start_us, end_us))]
        return self._run(work)

    def before(self, cell: str, name: str, t_us: int) -> Sample | None:
        def work(db: Any) -> Sample | None:
            signal = self._signal(db, cell, name)
            if signal is None:
                return None
            row = self._one(db, "SELECT t, value FROM plchmi_samples WHERE signal = ? "
                            "AND t <= ? ORDER BY t DESC LIMIT 1", (signal, t_us))
            return None if row is None else Sample(int(row[0]), float(row[1]))
        return self._run(work)

    def buckets(self, cell: str, name: str, start_us: int, end_us: int, count: int
                ) -> list[Bucket]:
        span = end_us - start_us
        if span <= 0 or count <= 0:
            return []

        def work(db: Any) -> list[Bucket]:
            signal = self._signal(db, cell, name)
            if signal is None:
                return []
            return [Bucket(int(row[0]), int(row[1]), float(row[2]), float(row[3]),
                           float(row[4])) for row in self._all(
                db, self.bucket_sql, (start_us, count, span, span, signal, start_us, end_us))]
        return self._run(work)

    def events(self, cell: str, start_us: int, end_us: int,
               types: Iterable[str] = ()) -> list[Event]:
        chosen = tuple(types)

        def work(db: Any) -> list[Event]:
            where = f" AND type IN ({', '.join('?' * len(chosen))})" if chosen else ""
            return [event_from(row) for row in self._all(
                db, f"SELECT {EVENT_COLUMNS} FROM plchmi_events WHERE cell = ? AND t > ? "
                f"AND t <= ?{where} ORDER BY t, id",
                (self._cell(db, cell), start_us, end_us, *chosen))]
        return self._run(work)

    def span(self, cell: str) -> tuple[int, int] | None:
        def work(db: Any) -> tuple[int, int] | None:
            row = self._one(db, 'SELECT min(start), max("end") FROM plchmi_segments '
                            "WHERE cell = ?", (self._cell(db, cell),))
            return None if row is None or row[0] is None else (int(row[0]), int(row[1]))
        return self._run(work)

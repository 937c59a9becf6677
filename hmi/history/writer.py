"""The historian's writer thread: the queue into the store, in batches, and retention.

Every ``flush_s`` (1 s) it takes everything queued and writes it in one transaction, so a
killed process loses at most what was queued since the last commit began: one flush
interval's samples (the batch being written, or the one about to be). The figure for the
valve at 10 ms is in docs/history.md, measured by tests/test_history_kill.py.

It never stops the cell. When the store cannot be opened or written (a full disk, a database
server gone, a file it may not write), the batch goes back to the queue, the trouble is told
(:attr:`on_trouble`: the historian raises an alarm through the session) and the writer tries
again, waiting a little longer each time (1 s, 2 s, ... 30 s), reconnecting as needed. The
queue is bounded: past its limit the history has a gap, recorded as one (the segment ends
where the loss began and a new one starts with every signal's value once there is room).

Retention runs in the same thread at the start and every hour: everything older than the
retention (default 90 days) is deleted (hmi.history.store). The 90 days are counted back
from the wall clock, or from the history's newest instant when that is older: a clock set
ahead by mistake does not delete the history, and a history on a fixed time axis keeps its
own last 90 days.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from hmi.history.catalogue import ENUM, Catalogue
from hmi.history.recorder import SampleQueue, Taken
from hmi.history.store import Batch, Store, StoreError
from hmi.history.target import Target, open_store

FLUSH_S = 1.0
RETRY_S = (1.0, 2.0, 5.0, 10.0, 30.0)
RETENTION_EVERY_S = 3600.0
DAY_US = 86_400_000_000
DEFAULT_RETENTION_US = 90 * DAY_US


@dataclass(frozen=True)
class WriterStatus:
    state: str  # starting, writing, failing, stopped
    error: str = ""  # the last failure, in words
    written: int = 0  # samples and events committed
    batches: int = 0
    waiting: int = 0  # queued, not yet committed
    dropped: int = 0  # lost to a full queue
    deleted: int = 0  # removed by retention
    failures: int = 0


class HistoryWriter:
    def __init__(self, target: Target, catalogue: Catalogue, queue: SampleQueue, *,
                 source: str, clock: str, retention_us: int = DEFAULT_RETENTION_US,
                 flush_s: float = FLUSH_S,
                 on_trouble: Callable[[str | None], None] | None = None,
                 wall: Callable[[], float] = time.time):
        self.target = target
        self.catalogue = catalogue
        self.queue = queue
        self.source = source
        self.clock = clock
        self.retention_us = retention_us
        self.flush_s = flush_s
        self.on_trouble = on_trouble
        self.wall = wall
        self.store: Store | None = None
        self.segment: int | None = None
        self._ids: list[int] = []
        self._remap: dict[int, list[int]] = {}
        self._status = WriterStatus("starting")
        self._stop = threading.Event()
        self._flush_now = threading.Event()
        self._committed = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name="plchmi-history", daemon=True)
        self._retention_due = 0.0
        self._retry = 0
        self._trouble: str | None = None
        self._dropped_told = 0
        # cycles begun and ended (empty ones too): a flush waits for a cycle begun after it
        # was asked, the first one sure to take what was queued before; counting batches
        # let a batch already being written answer for entries queued after its take
        self._begun = 0
        self._ended = 0

    # -- life cycle -----------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Write what is queued (one last try), close the store."""
        self._stop.set()
        self._flush_now.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def flush(self, timeout: float = 30.0) -> bool:
        """Ask for a write now and wait until what was queued before is committed (tests,
        the bench, the CSV export of a running cell). False if it could not be."""
        with self._committed:
            wanted = self._begun + 1
            self._flush_now.set()
            return self._committed.wait_for(
                lambda: self._ended >= wanted or self._status.state == "failing"
                or not self._thread.is_alive(), timeout) and \
                self._status.state != "failing"

    @property
    def status(self) -> WriterStatus:
        return self._status

    def _set(self, **changes: object) -> None:
        from dataclasses import replace
        with self._committed:
            self._status = replace(self._status, waiting=len(self.queue),
                                   dropped=self.queue.dropped, **changes)  # type: ignore[arg-type]
            self._committed.notify_all()

    # -- the thread -----------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            while True:
                stopping = self._stop.is_set()
                self._cycle()
                if stopping:
                    break
                wait = self.flush_s if self._retry == 0 else \
                    RETRY_S[min(self._retry, len(RETRY_S)) - 1]
                self._flush_now.wait(wait)
                self._flush_now.clear()
        finally:
            if self.store is not None:
                with contextlib.suppress(StoreError):
                    self.store.close()
                self.store = None
            self._set(state="stopped")

    def _cycle(self) -> None:
        with self._committed:
            self._begun += 1
        try:
            self._write_queued()
        finally:
            with self._committed:
                self._ended += 1
                self._committed.notify_all()

    def _write_queued(self) -> None:
        try:
            store = self._connect()
            taken = self.queue.take()
            try:
                if len(taken) or taken.covered_us is not None:
                    self._write(store, taken)
                self.queue.done(taken)
            except BaseException:
                self.queue.give_back(taken)
                raise
            self._retain(store)
        except StoreError as exc:
            self._failed(str(exc))
            return
        self._retry = 0
        self._set(state="writing", error="")
        self._tell_losses()

    def _connect(self) -> Store:
        if self.store is None:
            store = open_store(self.target)
            try:
                found = store.prepare(self.catalogue.cell, self.catalogue.signals)
            except StoreError:
                store.close()
                raise
            self._ids = [i for i, _ in found]
            self._remap = {}
            for k, (signal, (_, labels)) in enumerate(zip(self.catalogue.signals, found,
                                                          strict=True)):
                if signal.kind == ENUM and labels[:len(signal.labels)] != signal.labels:
                    self._remap[k] = [labels.index(label) for label in signal.labels]
            self.store = store
        return self.store

    def _write(self, store: Store, taken: Taken) -> None:
        cell = self.catalogue.cell
        if self.segment is None:
            start = min((t for _, t, _ in taken.samples), default=taken.covered_us)
            if start is None:
                return
            self.segment = store.begin_segment(cell, start, self.source, self.clock)
        ids, remap = self._ids, self._remap
        rows = [(ids[i], t, v if i not in remap or v < 0 else float(remap[i][int(v)]))
                for i, t, v in taken.samples]
        batch = Batch(rows, taken.events, self.segment, taken.covered_us, tuple(taken.gaps))
        store.write(cell, batch)
        self.segment = batch.segment
        status = self._status
        self._set(written=status.written + len(taken), batches=status.batches + 1)

    def _retain(self, store: Store) -> None:
        now = time.monotonic()
        if now < self._retention_due:
            return
        self._retention_due = now + RETENTION_EVERY_S
        span = store.span(self.catalogue.cell)
        if span is None:
            return
        # Counted back from the older of the wall clock and the history's newest instant:
        # a wall clock set years ahead must not wipe the history, and a history recorded on
        # a fixed time axis (virtual time, tests, a replay) keeps its own last 90 days.
        cutoff = min(int(self.wall() * 1e6), span[1]) - self.retention_us
        deleted = store.delete_before(self.catalogue.cell, cutoff)
        self._set(deleted=self._status.deleted + deleted)

    def _failed(self, error: str) -> None:
        self._retry += 1
        if self.store is not None:
            with contextlib.suppress(StoreError):
                self.store.close()
            self.store = None
        self._set(state="failing", error=error, failures=self._status.failures + 1)
        self._trouble_is(f"the history cannot be written: {error}")

    def _tell_losses(self) -> None:
        """After a good write: a loss still going on (the queue full) is trouble; none,
        the trouble is over."""
        lost = self.queue.lost_since
        self._trouble_is(None if lost is None else
                         f"samples are being lost since {_clock(lost)} (the history has a gap "
                         f"from there: the writer cannot keep up)")

    def _trouble_is(self, message: str | None) -> None:
        if message == self._trouble:
            return
        self._trouble = message
        if self.on_trouble is not None:
            self.on_trouble(message)


def _clock(t_us: int) -> str:
    from datetime import UTC, datetime
    return datetime.fromtimestamp(t_us / 1e6, UTC).astimezone().strftime("%H:%M:%S")

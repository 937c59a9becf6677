"""The historian of one running cell: recorder, queue and writer, attached to a Session.

Whoever runs the cell builds one after the journal and before the first scan, and closes it
after the journal's last entry::

    historian = Historian(session, target, journal=recorder, source="hmi")
    ...                                  # scans
    recorder.close(); historian.close()

It only listens: a scan listener (hmi.history.recorder), a journal tap (alarms, actions and
session entries become events), an overrun listener (scan.late). The engine computes exactly
what it computed without it (the golden traces are unchanged, tests/test_history_*.py run a
trace with and without). An error inside the recorder detaches it and raises the history's
alarm, never the scan's; a store that cannot be written raises the same alarm and the cell
goes on (hmi.history.writer).
"""

from __future__ import annotations

import contextlib
import time
import traceback
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

from hmi.explain.model import Explanation, Policy
from hmi.history.catalogue import Catalogue, catalogue
from hmi.history.recorder import QUEUE_LIMIT, HistoryRecorder, SampleQueue
from hmi.history.store import Event, StoreError
from hmi.history.target import Target, open_store
from hmi.history.writer import DEFAULT_RETENTION_US, FLUSH_S, HistoryWriter, WriterStatus
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session
from hmi.session.view import CellView

KEY = "history"  # the situation's key, hence the alarm's (Session.report)


class Historian:
    def __init__(self, session: Session, target: Target, *, source: str = "hmi",
                 journal: JournalRecorder | None = None,
                 retention_us: int = DEFAULT_RETENTION_US, flush_s: float = FLUSH_S,
                 queue_limit: int = QUEUE_LIMIT, run_us: int | None = None):
        self.session = session
        self.target = target
        self.journal = journal
        engine = session.engine
        simulated = not engine.plant.is_real
        self.catalogue: Catalogue = catalogue(
            session.project, engine.layout, simulated,
            tuple(engine.plant.state()) if simulated else ())
        self.queue = SampleQueue(queue_limit)
        if session.epoch_us is None and not engine.started:
            # after the cell's history so far; a headless run in virtual time of a known
            # length (`run_us`) as if it had just run: its history ends as it finishes
            earliest = _last_instant(target, session.project.name) + 1000
            start = now_us() - (run_us or 0)
            session.epoch_us = max(start, earliest)
        self.epoch_us = session.wall_us(0)
        self.recorder = HistoryRecorder(self.catalogue, self.queue, self.epoch_us)
        self.clock = "real" if session.clock is not None else "virtual"
        self.writer = HistoryWriter(target, self.catalogue, self.queue, source=source,
                                    clock=self.clock, retention_us=retention_us,
                                    flush_s=flush_s, on_trouble=self._trouble)
        self.failure = ""  # why the recorder stopped listening (an internal error)
        self.failure_traceback = ""
        self._attached = False

    # -- life cycle -------------------------------------------------------------------------
    def attach(self) -> Historian:
        session = self.session
        target = self.target
        session.history = str(Path(target.where).resolve()) if target.kind == "sqlite" \
            else target.where
        self.writer.start()
        session.scan_listeners.append(self.on_scan)
        session.overrun_listeners.append(self.on_overrun)
        if self.journal is not None:
            self.hear(self.journal)
        self._attached = True
        return self

    def hear(self, journal: JournalRecorder) -> None:
        """Keep the journal's entries as events (from its start entry on)."""
        self.journal = journal
        journal.taps.append(self.on_entry)
        start = journal.start_entry
        self.on_entry({**start, "message": f"{start['project']} started ({start['control']}, "
                       f"{start['policy']}, {start['plant']})"})

    def detach(self) -> None:
        session = self.session
        with contextlib.suppress(ValueError):
            session.scan_listeners.remove(self.on_scan)
        with contextlib.suppress(ValueError):
            session.overrun_listeners.remove(self.on_overrun)
        if self.journal is not None:
            with contextlib.suppress(ValueError):
                self.journal.taps.remove(self.on_entry)
        self._attached = False

    def close(self, timeout: float = 10.0) -> None:
        """Stop listening, write what is queued, close the store."""
        self.detach()
        self.writer.stop(timeout)
        self.session.report(KEY, None)

    def flush(self, timeout: float = 30.0) -> bool:
        return self.writer.flush(timeout)

    @property
    def status(self) -> WriterStatus:
        return self.writer.status

    # -- what it hears ------------------------------------------------------------------------
    def on_scan(self, view: CellView) -> None:
        try:
            self.recorder.on_scan(view)
        except Exception as exc:
            self._broken("recording a scan", exc)

    def on_overrun(self, total: int) -> None:
        try:
            self.recorder.on_overrun(total)
        except Exception as exc:
            self._broken("recording an overrun", exc)

    def on_entry(self, entry: dict[str, Any]) -> None:
        """A journal entry (from the thread that journalled it): an event of the history."""
        try:
            self.queue.add_event(self.event(entry))
        except Exception as exc:
            self._broken("recording a journal entry", exc)

    def event(self, entry: dict[str, Any]) -> Event:
        t_us = _micros(entry.get("t"))
        if t_us is None:
            t_us = self.session.engine.now
        text = entry.get("text") or entry.get("message") or ""
        return Event(self.epoch_us + t_us, str(entry.get("type", "")),
                     str(entry.get("event", "")), str(entry.get("key", "")),
                     str(entry.get("severity", "")), str(text), str(entry.get("by", "")),
                     entry)

    def _broken(self, what: str, exc: Exception) -> None:
        """An error of the historian's own code: it stops listening (the scan goes on) and
        says so (its alarm, hence the journal; the traceback in `failure_traceback`)."""
        self.detach()
        self.failure = f"{what}: {type(exc).__name__}: {exc}"
        self.failure_traceback = traceback.format_exc()
        self._trouble(f"the historian stopped recording ({self.failure})", stopped=True)

    def _trouble(self, message: str | None, stopped: bool = False) -> None:
        if message is None:
            if not self.failure:
                self.session.report(KEY, None)
            return
        engine = self.session.engine
        waiting = len(self.queue)
        self.session.report(KEY, Explanation(
            key=KEY, kind="history", severity="low", device="History",
            what="History is not being recorded" if stopped or "lost" in message
            else "History cannot be written now",
            why=f"{message[0].upper()}{message[1:]}.",
            consequences=(
                "The cell keeps running: control, the safety filter, the alarms and the "
                "journal are not affected. "
                + ("Nothing more is recorded for the trends until the HMI is restarted."
                   if stopped else
                   f"{waiting:,} samples wait in memory (at most {self.queue.limit:,}); the "
                   "writer tries again by itself, and past that limit the trends show a gap "
                   "where history was lost.")),
            policies=(Policy("understood", "Understood", "Nothing is sent: free disk space or "
                             f"bring the database back ({self.target.describe()}); the "
                             "history resumes by itself", recommended=True),),
            since_scan=engine.scan, since_us=engine.now,
            detail=f"history target: {self.target.describe()}; writer: "
                   f"{self.writer.status.state}, {self.writer.status.failures} failed "
                   f"writes, {self.queue.dropped:,} samples lost"))


def _micros(t: object) -> int | None:
    """A journal entry's "t" (seconds as text, hmi.timefmt.seconds) in microseconds."""
    if isinstance(t, int | float) and not isinstance(t, bool):
        return int(Decimal(str(t)) * 1_000_000)
    if isinstance(t, str):
        try:
            return int(Decimal(t) * 1_000_000)
        except InvalidOperation:
            return None
    return None


def _last_instant(target: Target, cell: str) -> int:
    """The end of the cell's history so far (0 if none, or if the store cannot be read now:
    the writer will say so)."""
    try:
        store = open_store(target, read_only=True)
    except StoreError:
        return 0
    try:
        span = store.span(cell)
    except StoreError:
        return 0
    finally:
        store.close()
    return span[1] if span else 0


def now_us() -> int:
    return time.time_ns() // 1000

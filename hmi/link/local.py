"""A cell whose session runs in this process: the link of the pilot tests, the screenshots
and the single-process bench.

The session's scans run here — in virtual time when the caller says so (:meth:`advance`),
or on the wall clock in a thread of their own (``live``: :class:`~hmi.session.live.LiveRunner`).
Every scan feeds the :class:`~hmi.session.recorder.ScanRecorder`, so a view is one scan with
its history, as a runtime process gives it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from hmi.engine.commands import Command
from hmi.engine.snapshot import Snapshot
from hmi.explain.reset import changes, declined_message, reset_preview
from hmi.link.base import Answer, CellFacts, Identity, PlantFacts, ResetGuard, RunInfo, View
from hmi.session.live import LiveRunner
from hmi.session.recorder import ScanRecorder
from hmi.session.session import Session

# The scan thread and a UI share one interpreter lock. When the scan thread wakes up for
# its next scan while the UI is rendering, it waits until the UI thread is asked to let go,
# by default after 5 ms: that would be most of a 10 ms period. Half a millisecond bounds
# that wait; measured by `plchmi bench ui`.
SWITCH_INTERVAL_S = 0.0005


def cell_facts(session: Session) -> CellFacts:
    """What a screen needs to know of the cell once: read from the session's engine."""
    engine = session.engine
    plant = engine.plant
    return CellFacts(
        project=engine.project.name, control=engine.control_name, layout=engine.layout,
        safe_vector=tuple(bool(v) for v in engine.safe_vector),
        devices={device: tuple(outputs) for device, outputs in engine.devices.items()},
        plant=PlantFacts(
            kind=plant.kind, description=plant.status.description, is_real=plant.is_real,
            can_inject=plant.can_inject, can_repair=plant.can_repair,
            can_set_inputs=plant.can_set_inputs, free_inputs=tuple(plant.free_inputs),
            faults=tuple(tuple(f) for f in plant.faults())),  # type: ignore[misc]
        period_us=session.period_us, history=session.history, epoch_us=session.epoch_us)


def run_info(session: Session) -> RunInfo:
    state = session.state
    return RunInfo(state.label, state.running, state.speed)


class SessionLink:
    """A :class:`~hmi.link.base.CellLink` on a session in this process."""

    def __init__(self, session: Session, live: bool = False,
                 identity: Identity | None = None):
        self.session = session
        self.live = live
        self.project = session.project
        self.facts = cell_facts(session)
        self.identity = identity or Identity("operator", session="local")
        self.recorder = ScanRecorder(session.engine.layout)
        self.history = self.recorder
        # Told of an error of the recorder (in the scan thread: the scan goes on).
        self.on_recorder_error: Callable[[BaseException], None] | None = None
        self.runner = LiveRunner(session) if live else None
        session.scan_listeners.append(self._record)
        if session.last is None:
            session.scan_once()
        else:
            self._record(session.last)

    def _record(self, snapshot: Snapshot) -> None:
        try:
            self.recorder.on_scan(snapshot)
        except Exception as exc:
            if self.on_recorder_error is not None:
                self.on_recorder_error(exc)

    def view(self) -> View | None:
        recorded = self.recorder.latest()
        if recorded.snapshot is None:
            return None
        return View(recorded.snapshot, recorded.constraints, recorded.damage_count,
                    run_info(self.session), self.overruns)

    @property
    def last(self) -> Snapshot | None:
        return self.session.last

    @property
    def overruns(self) -> int:
        return self.runner.overruns if self.runner is not None else 0

    @property
    def error(self) -> BaseException | None:
        return self.runner.error if self.runner is not None else None

    def command(self, command: Command, guard: ResetGuard | None = None) -> Answer:
        session = self.session
        if guard is None:
            return Answer(session.command(command, self.origin))
        with session.lock:  # no scan between the check and the command
            now = session.last
            gone, new = changes(list(guard.shown), reset_preview(now) if now else [])
            if not gone and not new:
                return Answer(session.command(command, self.origin))
            scan = now.scan if now is not None else guard.seen_scan
            return Answer(session.decline(command, declined_message(
                gone, new, guard.seen_scan, scan)), declined=True)

    @property
    def origin(self) -> str:
        return ""

    # -- who runs the scans --------------------------------------------------------------
    def start(self) -> None:
        if self.runner is not None:
            sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
            # LiveRunner.start freezes what exists (a UI's widgets included) out of the
            # garbage collector's sight: a full collection over them took ~40 ms here.
            self.runner.start()

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop()
        if self._record in self.session.scan_listeners:
            self.session.scan_listeners.remove(self._record)

    def advance(self, duration_us: int) -> int:
        session = self.session
        if not session.state.running:
            return 0
        end = session.engine.now + duration_us
        count = 0
        while session.state.running and session.next_time <= end:
            session.scan_once()
            count += 1
        return count

    def advance_until(self, predicate: Callable[[Snapshot], bool], limit_us: int) -> bool:
        session = self.session
        end = session.engine.now + limit_us
        while session.state.running and session.next_time <= end:
            if predicate(session.scan_once()):
                return True
        return False

"""The historian's ear on the scan: what changed, into a bounded queue, and nothing else.

:class:`HistoryRecorder.on_scan` runs on the scan thread for every scan (a session scan
listener). It compares the snapshot with the last one it saw — a tuple compare first, so a
scan that changed nothing costs a few comparisons — and appends the changes to the
:class:`SampleQueue` as (signal, time, value). It never touches the database, never waits
for the writer, never allocates per signal when nothing moved.

The queue is bounded (``limit`` samples and events). When the writer cannot keep up or the
store cannot be written for long, the queue stops accepting: the samples of that stretch are
lost, counted and *said*, never silently papered over. Once it has room again it marks a gap
(the segment ends where the loss began) and asks the recorder to record every signal again
at the next scan, so the history after the gap starts from known values.

Time: a sample's time is the scan's wall time, ``epoch_us + snapshot.time_us`` in
microseconds since the Unix epoch (the session's :meth:`~hmi.session.session.Session.wall_us`
decides the epoch: the wall clock of a real plant; for a simulation, the run's own time
counted from its start).
"""

from __future__ import annotations

import operator
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hmi.engine.snapshot import Snapshot
from hmi.history.catalogue import LOCATIONS, MODES, Catalogue
from hmi.history.store import Event
from hmi.project.model import POLICIES
from hmi.session.view import CellView

QUEUE_LIMIT = 200_000  # samples and events held for the writer (a few MB)
MONITOR_LOOK_US = 50_000  # a running task's stopwatches are looked at this often
SCAN_WINDOW_US = 1_000_000  # scan.time: the longest scan of each second

Item = tuple[int, int, float]  # (catalogue index, time in µs since the epoch, value)


@dataclass
class Taken:
    """What the writer takes from the queue in one go."""

    samples: list[Item]
    events: list[Event]
    covered_us: int | None  # the last scan recorded (the history covers up to it)
    gaps: list[tuple[int, int]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.samples) + len(self.events)


class SampleQueue:
    """Between the scan thread (put) and the writer thread (take); bounded."""

    def __init__(self, limit: int = QUEUE_LIMIT):
        self.limit = limit
        self._lock = threading.Lock()
        self._samples: list[Item] = []
        self._events: list[Event] = []
        self._held = 0  # taken by the writer and given back (a failed write): still counted
        self._covered: int | None = None
        self._gaps: list[tuple[int, int]] = []
        self.dropped = 0  # samples and events lost to a full queue, in all
        self.lost_since: int | None = None  # a loss going on since this instant
        self.resync = False  # the recorder must record every signal again (after a loss)
        self._after_loss = False  # the next full picture ends the loss
        self.accepted_us: int | None = None  # the last scan whose changes were kept

    def __len__(self) -> int:
        return len(self._samples) + len(self._events) + self._held

    def put(self, items: list[Item], covered_us: int) -> None:
        """One scan's changes (possibly none) and its time; dropped whole if there is no
        room (a scan is kept entirely or not at all)."""
        with self._lock:
            size = len(self._samples) + len(self._events) + self._held
            if self.lost_since is not None:
                if self.resync or size + len(items) > self.limit // 2:
                    self.dropped += len(items)  # still no room, or not the full picture
                    return
                if not self._after_loss:
                    # room again: a scan's changes alone would be a partial picture, so the
                    # recorder records every signal at its next scan, where the gap ends
                    self.resync = True
                    self._after_loss = True
                    self.dropped += len(items)
                    return
                self._gaps.append((self.lost_since, covered_us))
                self.lost_since = None
                self._after_loss = False
            elif size + len(items) > self.limit:
                self.lost_since = self.accepted_us if self.accepted_us is not None \
                    else covered_us
                self.dropped += len(items)
                return
            if items:
                self._samples.extend(items)
            self._covered = covered_us
            self.accepted_us = covered_us

    def covered(self, t_us: int) -> None:
        """A scan without changes: the history covers up to it (no lock: one reference
        written; the writer reads whichever value is newest). During a loss nothing is
        covered."""
        if self.lost_since is None:
            self._covered = t_us
            self.accepted_us = t_us

    def add_event(self, event: Event) -> None:
        with self._lock:
            if len(self._samples) + len(self._events) + self._held >= self.limit:
                self.dropped += 1
                return
            self._events.append(event)

    def take(self) -> Taken:
        """Everything queued, for one write; counted as held until :meth:`done`."""
        with self._lock:
            taken = Taken(self._samples, self._events, self._covered, self._gaps)
            self._samples, self._events, self._gaps = [], [], []
            self._held += len(taken)
            return taken

    def done(self, taken: Taken) -> None:
        """`taken` is written: its room is free again."""
        with self._lock:
            self._held -= len(taken)

    def give_back(self, taken: Taken) -> None:
        """`taken` could not be written: in front of what came since, for the next try."""
        with self._lock:
            self._held -= len(taken)
            self._samples[:0] = taken.samples
            self._events[:0] = taken.events
            self._gaps[:0] = taken.gaps
            if self._covered is None:
                self._covered = taken.covered_us


class HistoryRecorder:
    """Turns each scan's snapshot into samples (on the scan thread)."""

    def __init__(self, catalogue: Catalogue, queue: SampleQueue, epoch_us: int):
        self.catalogue = catalogue
        self.queue = queue
        self.epoch_us = epoch_us
        self.scans = 0
        self.samples = 0  # samples put (accepted or not)
        slots = [slot for _, slot in catalogue.values] + [
            s for m in catalogue.movements for s in (m.order_slot, m.end_slot)]
        # (itemgetter of one slot gives the value, not a tuple: the slot twice then)
        self._pick: Callable[[tuple[Any, ...]], object] = (
            operator.itemgetter(*slots) if len(slots) > 1 else
            operator.itemgetter(*slots, *slots) if slots else (lambda values: ()))
        self._reset()

    def _reset(self) -> None:
        """Forget what was recorded: the next scan records every signal."""
        n = len(self.catalogue.signals)
        self.stored: list[float | None] = [None] * n  # the last value put, per signal
        self.stored_at: list[int] = [0] * n
        self._values: tuple[Any, ...] | None = None
        self._booleans: object = _NOTHING
        self._fov: tuple[bool, ...] | None = None
        self._report: object = _NOTHING
        self._violated: tuple[str, ...] | None = None
        self._diagnosers: object = _NOTHING
        self._marks: int | None = None
        self._monitor_look = 0
        self._running: list[bool] = [False] * len(self.catalogue.monitors)
        self._plant: object = _NOTHING
        self._moving: list[int | None] = [None] * len(self.catalogue.movements)
        self._cell: tuple[str, str, bool, int] | None = None
        self._window_end: int | None = None
        self._window_max = 0.0

    def on_scan(self, view: CellView) -> None:
        """One scan, on the scan thread: cheap when nothing moved."""
        snap = view.snapshot
        if self.queue.resync:
            self.queue.resync = False
            self._reset()
        t = self.epoch_us + snap.time_us
        out: list[Item] = []
        c = self.catalogue
        stored = self.stored
        values = snap.values
        booleans = self._pick(values)  # the image's Booleans only (step times move always)
        last = self._values
        if booleans != self._booleans:
            for i, slot in c.values:
                if last is None or values[slot] != last[slot]:
                    v = 1.0 if values[slot] else 0.0
                    stored[i] = v
                    out.append((i, t, v))
            if c.movements:
                self._movements(values, last, t, out)
            self._values = values
            self._booleans = booleans
        fov = snap.fov
        if fov != self._fov:
            old = self._fov
            for i, k in c.fov:
                if old is None or fov[k] != old[k]:
                    v = 1.0 if fov[k] else 0.0
                    stored[i] = v
                    out.append((i, t, v))
            self._fov = fov
        report = snap.filter_report
        if report is not self._report:
            self._report = report
            violated = report.violated_names if report is not None else ()
            if violated != self._violated:
                for i, name in c.constraints:
                    v = 1.0 if name in violated else 0.0
                    if stored[i] != v:
                        stored[i] = v
                        out.append((i, t, v))
                self._violated = violated
        diagnosers = snap.diagnosers
        if diagnosers is not self._diagnosers:
            self._diagnosers = diagnosers
            for (i, index), state in zip(c.diagnosers, diagnosers, strict=False):
                v = float(index.get(state.state, -1))
                if stored[i] != v:
                    stored[i] = v
                    out.append((i, t, v))
        if c.monitors:
            self._monitors(snap, t, out)
        cell = (snap.mode, snap.policy, bool(snap.latched), len(view.alarms))
        if cell != self._cell:
            self._cell = cell
            self._level(c.mode, _MODES.get(snap.mode, -1.0), t, out)
            self._level(c.policy, _POLICIES.get(snap.policy, -1.0), t, out)
            self._level(c.latched, 1.0 if cell[2] else 0.0, t, out)
            self._level(c.alarms, float(cell[3]), t, out)
        wall = view.scan_wall_us
        if wall:  # 0.0: not measured (a headless run in virtual time)
            self._scan_time(wall, t, out)
        if c.plant:
            plant = snap.plant_state
            if plant is not self._plant and plant != self._plant:
                self._plant = plant
                self._plant_state(plant, t, out)
        self.scans += 1
        if out:
            self.samples += len(out)
            self.queue.put(out, t)
        else:
            self.queue.covered(t)

    def _level(self, i: int, v: float, t: int, out: list[Item]) -> None:
        if self.stored[i] != v:
            self.stored[i] = v
            out.append((i, t, v))

    def _number(self, i: int, v: float, t: int, out: list[Item]) -> None:
        """A number, with its signal's deadband (and settle time for a slow drift)."""
        old = self.stored[i]
        if old == v:
            return
        signal = self.catalogue.signals[i]
        if old is None or abs(v - old) >= signal.deadband or (
                signal.settle_us and t - self.stored_at[i] >= signal.settle_us):
            self.stored[i] = v
            self.stored_at[i] = t
            out.append((i, t, v))

    def on_overrun(self, total: int) -> None:
        """A scan overrun (hmi.session.live.LiveRunner), on the scan thread."""
        values = self._values
        if values is None:
            return
        i = self.catalogue.scan_late
        self.stored[i] = float(total)
        self.queue.put([(i, self._last_t(), float(total))], self._last_t())

    def _last_t(self) -> int:
        return self.queue.accepted_us or self.epoch_us

    def _scan_time(self, wall_us: float, t: int, out: list[Item]) -> None:
        end = self._window_end
        if end is None:
            self._window_end = t + SCAN_WINDOW_US
            self._window_max = wall_us
            if self.stored[self.catalogue.scan_late] is None:
                self._level(self.catalogue.scan_late, 0.0, t, out)
            return
        if t >= end:
            self._number(self.catalogue.scan_time, round(self._window_max / 1000, 3), t, out)
            self._window_end = t + SCAN_WINDOW_US
            self._window_max = wall_us
        elif wall_us > self._window_max:
            self._window_max = wall_us

    def _movements(self, values: tuple[Any, ...], last: tuple[Any, ...] | None, t: int,
                   out: list[Item]) -> None:
        """Each movement's travel: from the order's rising edge (written) to the end
        sensor's (read), the order held meanwhile; a movement abandoned (the order dropped
        before the sensor) is not counted."""
        moving = self._moving
        stored = self.stored
        for k, m in enumerate(self.catalogue.movements):
            order, end = values[m.order_slot], values[m.end_slot]
            if stored[m.operations] is None:
                stored[m.operations] = 0.0
                out.append((m.operations, t, 0.0))
            if last is None:
                continue
            started = moving[k]
            if started is not None and end and not last[m.end_slot]:
                travel = (t - started) / 1e6
                stored[m.travel] = travel
                out.append((m.travel, t, travel))
                count = (stored[m.operations] or 0.0) + 1.0
                stored[m.operations] = count
                out.append((m.operations, t, count))
                moving[k] = None
            elif order and not last[m.order_slot]:
                moving[k] = None if end else t
            elif not order:
                moving[k] = None

    def _monitors(self, snap: Snapshot, t: int, out: list[Item]) -> None:
        marks = snap.monitor_marks
        if marks == self._marks and t < self._monitor_look:
            return
        self._marks = marks
        self._monitor_look = t + MONITOR_LOOK_US
        states = snap.monitors
        running = self._running
        for plan in self.catalogue.monitors:
            if plan.order >= len(states):
                continue
            m = states[plan.order]
            self._number(plan.x, m.x_us / 1e6, t, out)
            self._number(plan.y, m.y_us / 1e6, t, out)
            self._level(plan.state, _LOCATIONS.get(m.location, -1.0), t, out)
            self._level(plan.operations, float(m.attempt), t, out)
            if running[plan.order] and not m.running:
                duration = m.x_us / 1e6
                self.stored[plan.duration] = duration
                out.append((plan.duration, t, duration))
            running[plan.order] = m.running

    def _plant_state(self, state: tuple[tuple[str, object], ...], t: int,
                     out: list[Item]) -> None:
        plant = self.catalogue.plant
        for key, value in state:
            i = plant.get(key)
            if i is None:
                continue
            if isinstance(value, bool):
                self._level(i, 1.0 if value else 0.0, t, out)
            elif isinstance(value, int | float):
                self._number(i, float(value), t, out)


_NOTHING = object()
_MODES = {name: float(i) for i, name in enumerate(MODES)}
_POLICIES: dict[str, float] = {name: float(i) for i, name in enumerate(POLICIES)}
_LOCATIONS = {name: float(i) for i, name in enumerate(LOCATIONS)}

"""A session: the engine, its explanations and alarms, and the run state, behind one door.

:class:`Session` is what the UI, the headless commands and the OPC UA server talk to.
It owns the engine, the explanation builder and the alarm list, and the run state (running,
paused, stepping); every operator action enters through :meth:`Session.command` (listeners,
such as the journal, hear each one with its result). Each scan is the engine's core
snapshot, explained (hmi.explain reads the snapshot, never the engine) and given the alarms
it raised: a :class:`~hmi.session.view.CellView`, and :attr:`Session.last` is the last one.

It never sleeps: the live app paces it from a worker thread (hmi.session.live); headless
runs call :meth:`Session.run_for` in virtual time.
"""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommandResult,
    CommentAlarm,
    Pause,
    Resume,
    SetSpeed,
    SetView,
    Shelve,
    StepScans,
    Unshelve,
    describe,
)
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import Alarm, AlarmEvent, AlarmManager
from hmi.explain.builder import ExplanationBuilder
from hmi.explain.model import Explanation
from hmi.plant.base import PlantError
from hmi.session.view import CellView


def settle_memory() -> None:
    """Move everything built so far (project, compiled expressions, UI) out of the garbage
    collector's sight: the scan creates no reference cycles, and collections that re-traverse
    those long-lived objects are what makes a scan's worst case several times its median.
    """
    gc.collect()
    gc.freeze()


@dataclass
class RunState:
    running: bool = True
    speed: float | None = 1.0  # None: as fast as possible
    pending_steps: int = 0

    @property
    def label(self) -> str:
        if self.pending_steps:
            return "stepping"
        return "running" if self.running else "paused"


Listener = Callable[[Command, CommandResult, CellView | None], None]


class Session:
    """The engine plus its explanations, alarms and run state; thread-safe so a UI thread
    can send commands while the scan thread runs."""

    def __init__(self, engine: Engine, period_us: int | None = None,
                 clock: Callable[[], int] | None = None):
        self.engine = engine
        self.project = engine.project
        self.period_us = period_us or engine.project.scan_period_us
        engine.set_nominal_period(self.period_us)
        # A real plant runs on real time: each scan's time comes from `clock` (see
        # hmi.session.live.WallClock) instead of advancing by one period per scan.
        self.clock = clock
        self.state = RunState()
        self.lock = threading.RLock()
        self.explainer = ExplanationBuilder(engine.project)
        self.alarms = AlarmManager()
        self.explanations: tuple[Explanation, ...] = ()  # the last scan's
        self._last: CellView | None = None  # the last scan, explained (see last)
        self._quiet = False  # the last scan was quiet: its view is built when read
        self._quiet_alarms: tuple[Alarm, ...] = ()  # the alarm list at that scan
        self._pending_alarm_events: list[AlarmEvent] = []  # acknowledgements between scans
        self.listeners: list[Listener] = []
        self.origin = ""  # who sent the command being carried out ("": the cell's operator)
        self.origin_details: Mapping[str, str] = {}  # and what else the journal says of them
        self.scan_listeners: list[Callable[[CellView], None]] = []
        # A scan listener's check that it has nothing to do on a quiet scan now (see
        # run_for); a listener without one is given every scan's view.
        self.idle_checks: dict[Callable[[CellView], None], Callable[[], bool]] = {}
        # Told of each scan overrun (a real-time runner more than a period late), for the
        # journal; called from the scan thread with the runner's overrun count.
        self.overrun_listeners: list[Callable[[int], None]] = []
        # The wall time (microseconds since the Unix epoch) of the run's time 0: a scan at
        # time_us happened at epoch_us + time_us (wall_us). What the OPC UA server stamps
        # its values with and the historian its samples.
        self.epoch_us: int | None = None
        # Where this session's history is kept ("" if none): set by the historian that
        # records it (hmi.history), told to the screens (hmi.link.base.CellFacts.history).
        self.history = ""
        # Situations reported by services beside the scan (the historian that cannot write:
        # hmi.history), explained and alarmed like the scan's own; replaced, never changed,
        # so the scan thread reads a consistent one (see report).
        self._services: dict[str, Explanation] = {}
        self._services_seen: dict[str, Explanation] | None = None

    @property
    def last(self) -> CellView | None:
        """The last scan, explained; a quiet scan's (run_for) is built here, when read."""
        if self._quiet:
            with self.lock:
                if self._quiet:
                    core = self.engine.snapshot()
                    if core.error is not None:
                        # Building it failed (the engine latched, Engine._snapshot_despite):
                        # no longer a quiet scan; explained and told now, like any other.
                        return self._scanned(core)
                    # What _explained makes of a quiet scan: the last scan's explanations,
                    # the alarm list as it was, no alarm event, no error, nothing shelved;
                    # the session added no time to the engine's.
                    self._last = CellView(core, self.explanations, self._quiet_alarms)
                    self._quiet = False
        return self._last

    @last.setter
    def last(self, view: CellView | None) -> None:
        with self.lock:
            self._last = view
            self._quiet = False

    def wall_us(self, time_us: int) -> int:
        """The wall time of the run's time `time_us`: a real plant's scans are stamped by
        the wall clock (hmi.session.live.WallClock), so this is when they ran; a
        simulation's time is counted from the wall time of its start (paused time is not
        in it; at ×10 it runs ahead). Fixed at the first call, unless set before (the
        historian places a run after the cell's history so far)."""
        epoch = self.epoch_us
        if epoch is None:
            epoch = self.epoch_us = time.time_ns() // 1000 - time_us
        return epoch + time_us

    def report(self, key: str, explanation: Explanation | None) -> None:
        """A service's situation (None: over), from any thread: in the next scan's
        explanations, hence its alarm and the journal. Nothing new (a situation that is
        over reported over again): nothing changes, and the scans stay quiet."""
        if self._services.get(key) is explanation:
            return
        services = dict(self._services)
        if explanation is None:
            services.pop(key, None)
        else:
            services[key] = explanation
        self._services = services

    @property
    def next_time(self) -> int:
        if self.clock is not None:
            return self.clock()
        return 0 if not self.engine.scan else self.engine.now + self.period_us

    def command(self, command: Command, origin: str = "",
                details: Mapping[str, str] | None = None) -> CommandResult:
        """Carry out one operator command; `origin` says who sent it (``terminal:alice``,
        an OPC UA user ``opcua:bob``; "" the cell's own operator), `details` what else the
        journal writes of them (their role, their screen), for the journal."""
        with self.lock:
            self.origin = origin
            self.origin_details = details or {}
            match command:
                case Pause():
                    self.state.running = False
                    result = CommandResult.ok("paused" + self._park_real_plant())
                case Resume():
                    self.state.running = True
                    self.state.pending_steps = 0
                    result = CommandResult.ok("running")
                case StepScans(count=n):
                    if self.engine.drives_real_plant:
                        result = CommandResult.refused(
                            "stepping would drive a real plant for a scan and leave it so; "
                            "not available on a real plant (pause holds it safe)")
                    elif n < 1:
                        result = CommandResult.refused("step count must be at least 1")
                    else:
                        self.state.running = False
                        for _ in range(n):
                            self.scan_once()
                        result = CommandResult.ok(f"stepped {n} scan{'s' if n > 1 else ''}, "
                                                  f"now scan {self.engine.scan}")
                case SetSpeed(factor=factor):
                    self.state.speed = factor
                    result = CommandResult.ok(describe(command))
                case Acknowledge(key=key):
                    result = self._acknowledge(key)
                case ChoosePolicy(key=key, policy=policy_id):
                    result = self._choose_policy(key, policy_id)
                case Shelve() | Unshelve() | CommentAlarm():
                    result = self._alarm_note(command)
                case SetView(engineering=engineering):
                    result = CommandResult.ok(
                        "engineering view: internal names, states, flags and bounds shown"
                        if engineering else "operator view: devices and plain words")
                case _:
                    result = self.engine.apply(command)
            self._tell(command, result)
            return result

    def decline(self, command: Command, why: str, origin: str = "",
                details: Mapping[str, str] | None = None) -> CommandResult:
        """A command not carried out, for a reason outside the engine: a confirmation whose
        dialog's promise had changed under it (hmi.explain.reset.changes), a screen not in
        control. Refused, and told to the listeners like any command, so the journal says
        what the operator did and why nothing happened."""
        with self.lock:
            self.origin = origin
            self.origin_details = details or {}
            result = CommandResult.refused(why)
            self._tell(command, result)
            return result

    def _tell(self, command: Command, result: CommandResult) -> None:
        for listener in self.listeners:
            listener(command, result, self.last)

    def _acknowledge(self, key: str | None) -> CommandResult:
        engine = self.engine
        events = self.alarms.acknowledge(key, engine.scan, engine.now)
        self._pending_alarm_events.extend(events)
        if key is not None and not events:
            alarm = self.alarms.alarms.get(key)
            if alarm is not None and alarm.acknowledged:  # the operator may not see it yet
                return CommandResult.refused(f"already acknowledged: {alarm.text}")
            return CommandResult.refused(f"no alarm {key} to acknowledge")
        return CommandResult.ok(f"acknowledged {len(events)} alarm"
                                f"{'s' if len(events) != 1 else ''}")

    def _alarm_note(self, command: Shelve | Unshelve | CommentAlarm) -> CommandResult:
        """Shelving and comments: they change the alarm list, never the plant."""
        engine, alarms = self.engine, self.alarms
        match command:
            case Shelve(key=key, duration_us=duration):
                events, why = alarms.shelve(key, duration, engine.scan, engine.now)
                if why:
                    return CommandResult.refused(why)
                message = f"{events[0].text}: shelved {events[0].note}; journalled meanwhile"
            case Unshelve(key=key):
                events = alarms.unshelve(key, engine.scan, engine.now)
                if not events:
                    return CommandResult.refused(f"alarm {key} is not shelved")
                message = f"{events[0].text or key}: back in the list"
            case CommentAlarm(key=key, text=text):
                text = " ".join(text.split())[:500]
                if not text:
                    return CommandResult.refused("an empty comment")
                events = alarms.comment(key, text, engine.scan, engine.now)
                if not events:
                    return CommandResult.refused(f"no alarm {key} in the list")
                message = f"comment journalled on {events[0].text}"
        self._pending_alarm_events.extend(events)
        return CommandResult.ok(message)

    def take_alarm_events(self) -> list[AlarmEvent]:
        """Alarm transitions since the last scan (acknowledgements), for whoever journals
        them now; those not taken go into the next view's alarm_events."""
        events, self._pending_alarm_events = self._pending_alarm_events, []
        return events

    def _explanation(self, key: str) -> Explanation | None:
        explanation = next((e for e in self.explanations if e.key == key), None)
        if explanation is None:
            alarm = self.alarms.alarms.get(key)
            explanation = alarm.explanation if alarm else None
        return explanation

    def policy_command(self, key: str, policy_id: str) -> Command | None:
        """What choosing policy `policy_id` of situation `key` would carry out now (None:
        nothing, or no such policy): the runtime asks a reason for it as for the command
        itself."""
        with self.lock:
            explanation = self._explanation(key)
            policy = next((p for p in explanation.policies if p.id == policy_id),
                          None) if explanation is not None else None
            return policy.command if policy is not None else None

    def _choose_policy(self, key: str, policy_id: str) -> CommandResult:
        explanation = self._explanation(key)
        if explanation is None:
            return CommandResult.refused(f"no situation {key} to act on")
        policy = next((p for p in explanation.policies if p.id == policy_id), None)
        if policy is None:
            return CommandResult.refused(f"{key} offers no policy {policy_id!r}; it offers "
                                         + ", ".join(p.id for p in explanation.policies))
        if policy.command is None:
            return CommandResult.ok(f"policy '{policy.label}' chosen for {key}: "
                                    f"{policy.effect}")
        result = self.engine.apply(policy.command)
        verdict = "chosen" if result.accepted else "could not be carried out"
        return CommandResult(result.accepted, f"policy '{policy.label}' {verdict} for {key}: "
                             f"{result.message}")

    def _park_real_plant(self) -> str:
        """A paused PLC must not leave a real plant driven: write the safe vector once."""
        engine = self.engine
        plant = engine.plant
        if not self.engine.drives_real_plant or not engine.started:
            return ""
        try:
            plant.write(engine.now, dict(zip(engine.layout.outputs, engine.safe_vector,
                                             strict=True)))
        except PlantError as exc:
            return f"; the safe outputs could not be written ({exc})"
        return "; real plant: outputs written safe while paused"

    def scan_if_running(self) -> CellView | None:
        """One scan unless paused meanwhile (checked under the lock, so no scan follows a
        pause: a paused real plant keeps the safe outputs the pause wrote)."""
        with self.lock:
            return self.scan_once() if self.state.running else None

    def scan_once(self) -> CellView:
        with self.lock:
            return self._scanned(self.engine.step(self.next_time))

    def _scanned(self, core: Snapshot) -> CellView:
        view = self._explained(core)
        self._last = view
        self._quiet = False
        for listener in self.scan_listeners:
            listener(view)
        return view

    def _scan_unless_quiet(self, now: int) -> CellView | None:
        """One scan at `now`; None when it is quiet (its view built only if `last` is
        read): the engine says the scan has no news (hmi.engine.scan.Engine.run) and the
        session is ready for one (:meth:`_ready_for_quiet`)."""
        with self.lock:
            engine = self.engine
            if not engine.run(now) and self._ready_for_quiet():
                self._quiet_from_here()
                return None
            return self._scanned(engine.snapshot())

    def _ready_for_quiet(self) -> bool:
        """Whether a scan with no news from the engine is quiet for the session too: no
        alarm event waits, the alarm list is settled for the last scan's explanations
        (AlarmManager.settled: an update with them would change nothing) and every scan
        listener is idle. Such a scan's explanations are the very tuple the last scan's were
        (every field they are found from is the same: ExplanationBuilder.build returns its
        last result), so the alarm list has nothing to update either. Nothing a quiet scan
        does changes this: only a scan with news or a command can."""
        alarms = self.alarms
        explanations = self.explanations
        # (with no explanation, no alarm and nothing shelved the list is settled)
        return self._services is self._services_seen and not self._pending_alarm_events and (
            not (explanations or alarms.alarms or alarms.shelved)
            or alarms.settled(explanations)) and (
            not self.scan_listeners or self._listeners_idle())

    def _quiet_from_here(self) -> None:
        """The last scan was quiet: `last` builds its view when read."""
        self._quiet = True
        # the list as it is now (a command may change it before `last` is read)
        self._quiet_alarms = self.alarms.listed() if self.alarms.alarms else ()

    def _listeners_idle(self) -> bool:
        checks = self.idle_checks
        for listener in self.scan_listeners:
            check = checks.get(listener)
            if check is None or not check():
                return False
        return True

    def _explained(self, core: Snapshot) -> CellView:
        """The engine's snapshot with its explanations, the alarm list and its changes, and
        the time explaining took, when the engine measures the scan's."""
        timed = self.engine.wall_times
        started = time.perf_counter() if timed else 0.0
        error = None
        try:
            explanations = self.explainer.build(core)
        except Exception as exc:  # explanations must never stop the scan
            explanations = ()
            error = f"explanations: {type(exc).__name__}: {exc}"
        services = self._services
        self._services_seen = services
        if services:
            explanations = (*explanations, *services.values())
        self.explanations = explanations
        events = self._pending_alarm_events  # acknowledgements since the last scan
        if events:
            self._pending_alarm_events = []
        alarms = self.alarms
        if explanations or alarms.alarms or alarms.shelved:
            # (with no situation, no alarm and nothing shelved the update has nothing to do)
            events = events + alarms.update(explanations, core.scan, core.time_us)
        return CellView(core, explanations, alarms.listed(), tuple(events) if events else (),
                        alarms.shelved_listed() if alarms.shelved else (), error,
                        (time.perf_counter() - started) * 1e6 if timed else 0.0)

    def run_for(self, duration_us: int, on_scan: Callable[[CellView], None] | None = None,
                on_quiet: Callable[[int], None] | None = None) -> CellView:
        """Run scans in virtual time from now until `duration_us` more has elapsed.

        With `on_quiet`, quiet scans (no news from the engine and the session ready for them,
        :meth:`_ready_for_quiet`: most scans of a working cell) are told to it by their
        number instead of to `on_scan`, and their views are not built (`last` builds the
        last one if read); a stretch of them runs in the engine at once
        (Engine.run_while_quiet), up to the first scan with news. For a caller that needs no
        view where nothing happened (plchmi run without a trace counts the scans).

        In virtual time nobody watches the scans' wall time (the HMI and OPC UA drive
        scan_once): the engine does not measure it meanwhile (Engine.wall_times; the
        snapshots' scan_wall_us and filter_wall_us are 0.0, and so is explain_wall_us)."""
        if self.clock is not None:
            return self._run_for(duration_us, on_scan, on_quiet)
        engine = self.engine
        timed, engine.wall_times = engine.wall_times, False
        try:
            return self._run_for(duration_us, on_scan, on_quiet)
        finally:
            engine.wall_times = timed

    def _run_for(self, duration_us: int, on_scan: Callable[[CellView], None] | None,
                 on_quiet: Callable[[int], None] | None) -> CellView:
        end = self.next_time + duration_us
        if on_quiet is None:
            while self.next_time <= end:
                view = self.scan_once()
                if on_scan is not None:
                    on_scan(view)
        else:
            engine = self.engine
            while (now := self.next_time) <= end:
                if self.clock is not None or not self._ready_for_quiet():
                    built = self._scan_unless_quiet(now)
                    quiet = 0 if built is not None else 1
                else:
                    with self.lock:
                        count, news = engine.run_while_quiet(now, end, self.period_us)
                        quiet = count - news
                        if news:
                            built = self._scanned(engine.snapshot())
                        else:
                            built = None
                            self._quiet_from_here()
                if quiet:
                    on_quiet(quiet)
                if built is not None and on_scan is not None:
                    on_scan(built)
        last = self.last
        assert last is not None
        return last


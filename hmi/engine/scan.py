"""The scan: one PLC cycle, in the order of DESIGN.md (000 Fig. 1, 004 Fig. 1).

    1 input scan   2 memory (timers, observers, step times)   3 diagnosers
    4 reconstruction   5 functional control (or manual requests)
    6 filter (with the diagnosers' mask)   7 output scan   8 monitors

Each stage is a small object the engine owns (hmi.engine.stages declares their interfaces);
:meth:`Engine.step` (through ``_cycle``) calls them in that order, hands each what it reads
and keeps what it returns. No stage reaches back into the engine: the filter returns its
decision and the engine latches, the diagnosers return their routes and mask and the engine
passes them on.

The stages of the mode's program are declared (hmi.engine.program_stages): what each gives a
scan with news, what a snapshot reads of it, its fault reset, capture and restore come from
its declaration, which the engine walks without naming the stage. What the engine holds of
its own: the commands, the latches, running the program (the parts of a scan, the mode's
function, the filter's hand-over) and deciding news.

The engine never reads a clock for what it decides: :meth:`Engine.step` is given the scan's
time. It only measures how long its scans take in wall time, for the people watching a live
run (:attr:`Engine.wall_times`). Everything it computes lands in an immutable
:class:`Snapshot`. The engine knows nothing of any UI.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator
from operator import is_
from typing import Any, NamedTuple

from hmi.engine.commands import (
    Command,
    CommandResult,
    EndRecovery,
    FaultReset,
    InjectFault,
    ManualOutput,
    ReleaseDevice,
    RepairFaults,
    SetInput,
    SetMode,
    SetPolicy,
    StartRecovery,
    StopDevice,
)
from hmi.engine.compiled import CompiledScan
from hmi.engine.diagnoser import NO_DIAGNOSIS, Diagnosis
from hmi.engine.filter import FilterReport, Solver
from hmi.engine.layout import Layout
from hmi.engine.program_stages import (
    DIAGNOSERS,
    FILTER,
    LAW,
    MEMORY,
    MONITORS,
    RECOVERY,
    SUPERVISION,
    Moment,
    StageContext,
    build_stages,
)
from hmi.engine.scan_record import (
    EVENTS,
    STATUS,
    QuietRun,
    Raised,
    ScanNews,
    ScanRecord,
    news_kind,
)
from hmi.engine.snapshot import INTERNAL_PARTS, LatchReason, Snapshot
from hmi.engine.stages import InputScan, OutputScan, plant_detail
from hmi.errors import UsageError
from hmi.logic.expr import Expr, Image, max_depth
from hmi.plant.base import Plant, PlantError, PlantStatus
from hmi.program import order
from hmi.project.diagnosers import layout_names
from hmi.project.model import POLICIES, Project
from hmi.project.recovery import recoveries_of


class EngineState(NamedTuple):
    """A copy of everything an engine's scans and commands change (Engine.capture)."""

    image: Image
    history: tuple[tuple[Any, ...], ...]
    scan: int
    now: int
    started: bool
    latched: tuple[LatchReason, ...]
    mode: str
    manual: tuple[tuple[str, bool], ...]
    policy: str
    stopped_devices: frozenset[str]
    readback: tuple[bool, ...]
    stages: tuple[Any, ...]  # each declared stage's (Engine.stages, in its order)


MONITOR_POLICY_REFUSED = ("the monitor policy passes unsafe orders through to a real plant; "
                          "choose --policy block or correct, or add --allow-monitor")


class Engine:
    """One project's scan on one plant. `allow_monitor_policy` permits the `monitor` policy
    (unsafe orders pass, only reported) on a real plant: refused otherwise, at construction
    and when the policy is switched (a simulated plant, or observing read-only, may)."""

    def __init__(self, project: Project, plant: Plant, control: str | None = None,
                 policy: str | None = None, solver: str | None = None,
                 diagnosis: str = "ftc", solver_budget: int | None = None,
                 allow_monitor_policy: bool = False, compiled: bool = True,
                 high_level: bool = True):
        self.project = project
        self.plant = plant
        # What decides a scan's path (run() reads it as one flag, _fast; the properties
        # below keep it): the automatic mode's printed frame, once started, no device
        # stopped, not measuring wall times.
        self._frame: Callable[[int], bool] | None = None
        self._mode, self._started, self._wall_times = "auto", False, True
        self._stop_mask: tuple[int, ...] = ()
        self._auto_ready = self._fast = False
        self._parts = _Parts()  # what _cycle's parts hand on
        self._clean: dict[str, FilterReport] = {}
        self.control_name = control or project.default_control
        if self.control_name not in project.controls:
            raise KeyError(self.control_name)
        law = project.controls[self.control_name]
        self.policy = policy or project.policy
        if self.policy not in POLICIES:
            raise ValueError(self.policy)
        # Read-only plant (observing a real PLC): the device's own outputs, read back, replace
        # the FOV; the control law does not run, nothing is written, the filter only detects.
        self.observe = plant.read_only
        if self.observe:
            self.policy = "monitor"
        self.allow_monitor_policy = allow_monitor_policy
        if self.policy == "monitor" and self.drives_real_plant and not allow_monitor_policy:
            raise UsageError(MONITOR_POLICY_REFUSED)
        # Partition flags and filtered sensors get slots (hmi/engine/diagnoser.py).
        self.layout = Layout.build(project, law, extra=layout_names(project))
        lay = self.layout
        self.output_slots = lay.indices(lay.outputs)
        # the outputs' slots as one slice when they follow each other (every example
        # project's): a vector of as many outputs goes into the image at once, not one by one
        first = self.output_slots[0] if self.output_slots else 0
        self._outputs_at = (slice(first, first + len(self.output_slots))
                            if self.output_slots == tuple(range(first, first + len(
                                self.output_slots))) else None)
        self.safe_vector = tuple(v.safe for v in project.outputs)
        solver_args = Solver(solver or project.solver, solver_budget or project.solver_budget)
        # The stages of the mode's program, built from their declarations in the scan's
        # order (hmi.engine.program_stages); the engine addresses the built-in ones
        # by their role where it needs that one.
        self.stages = build_stages(StageContext(project, lay, law, self.safe_vector,
                                                solver_args, diagnosis, high_level))
        self.law = self.stages.need(LAW)  # 5 (and the GRAFCET's step times, 2)
        # The GRAFCET when it has supervised steps, else None: the commands say when its
        # supervision is watched (_supervise); its stage watches it after a scan
        # (program_stages.SUPERVISION).
        supervision = self.stages.of(SUPERVISION)
        self._supervised = supervision.grafcet if supervision is not None else None
        # The stages, in scan order (hmi.engine.stages).
        self.input_scan = InputScan(plant, lay, read_back=self.observe)  # 1
        self.memory = self.stages.need(MEMORY)  # 2 (and the GRAFCET's step times: control)
        # 3-4 (None: no diagnosers), with the High Level Diagnoser after the local ones
        self.diagnosis = self.stages.of(DIAGNOSERS)
        self.filter_stage = self.stages.need(FILTER)  # 6: the filter, given the diagnosers' mask
        self.safety_filter = self.filter_stage.filter
        self.output_scan = OutputScan(plant, lay)  # 7
        self.monitors = self.stages.of(MONITORS)  # 8 (None: no monitors)
        # Recovery procedures (replace stages 5-6's law and constraints while one runs).
        self.recovery = self.stages.of(RECOVERY)
        # The stages added to the mode's program (each declares its own place)
        self.added = self.stages.added
        self._shows = any(d.shown is not None for d, _ in self.stages)  # (Snapshot.stages)
        # What the stages give a scan with news and what a snapshot reads of them besides
        # (their declarations' `news` and `fields`): Engine._conclude and Engine.snapshot
        # walk them, each with whether the stage runs after the output scan (not read at a
        # scan where that part raised: _scan_monitors).
        self._publishing = tuple((news.read, stage, news.reading, news.failed, _after(stage))
                                 for news, stage in self.stages.publishing)
        self._published_fields = tuple(news.field for news, _ in self.stages.publishing)
        self._reads = tuple((news.read, stage) for news, stage in self.stages.publishing)
        self._showing = tuple((fields, stage, _after(stage))
                              for fields, stage in self.stages.showing)
        # The history is as deep as the deepest expression of any stage reads.
        depth = max((max_depth(expr) for expr in _all_exprs(project)), default=1)
        depth = max(depth, self.stages.depth)
        self.history: deque[tuple[Any, ...]] = deque(maxlen=max(depth, 1))
        self.image: Image = lay.initial_image(project)
        self.scan = 0
        self.now = 0
        self.mode = "auto"
        self.manual: dict[str, bool] = {}
        self.latched: list[LatchReason] = []
        self.started = False
        # The last scan as the engine left it: no explanations nor alarms (the session adds
        # them: Session.last is what the UI shows).
        self.last: Snapshot | None = None
        self.devices = {v.device: tuple(o.name for o in project.outputs
                                        if o.device == v.device)
                        for v in project.outputs if v.device}
        self.stopped_devices: set[str] = set()
        # The scan program (hmi.engine.compiled): the stages' lowerings in the order of a
        # scan, per mode, printed as Python; `compiled=False` runs the same program through
        # its evaluator (the reference the printed form is tested against).
        # Its stages are the declared ones (those placed by hmi.program.order, then those
        # that declare their own place), their names allowed in the printed code.
        # A stage's functions of its own (the filter's questions) are built in the same
        # form and handed to it (its declaration's `functions` and `bind`).
        self.compiled = CompiledScan(lay, self.stages.program, self.recovery,
                                     f"{project.name}/{self.control_name}", python=compiled,
                                     added=self.added, functions=self.stages.functions)
        self._bindings = self.input_scan.bindings
        self._period = project.scan_period_us
        # The last run()'s results until snapshot() builds them into a Snapshot, and what
        # news is judged against (hmi.engine.scan.Engine.run).
        self._record = ScanRecord()
        self._pending = False  # whether _record holds a scan whose snapshot is not built
        # (_unmatched: the next scan has news whatever it finds: none yet, or a command
        # since; a tuple of what no scan gives, so that the comparison itself says so)
        self._news_kind = news_kind(self._published_fields)
        never = (_NEVER,) * (1 + len(self._published_fields))
        self._unmatched = self._news_kind(never, *never)  # type: ignore[call-arg]
        self._news: ScanNews = self._unmatched
        self._clean = self.filter_stage.clean  # each policy's report of a clean scan
        self.policy = self.policy  # (its clean report, now that the filter is there)
        self.wall_times = True
        if compiled and not self.observe:  # the automatic mode's scan, printed
            self._frame = self.compiled.frame(self)
            self._refresh()

    # -- what decides a scan's path -----------------------------------------------------------
    @property
    def mode(self) -> str:
        """auto, manual or recovery."""
        return self._mode

    @mode.setter
    def mode(self, mode: str) -> None:
        self._mode = mode
        self._refresh()

    @property
    def started(self) -> bool:
        """The first scan ran (the program started from its initial steps)."""
        return self._started

    @started.setter
    def started(self, started: bool) -> None:
        self._started = started
        self._refresh()

    @property
    def wall_times(self) -> bool:
        """Whether scans measure their wall time (Snapshot.scan_wall_us, filter_wall_us):
        the HMI's status bar and OPC UA show the scan's, the filter benches read the
        filter's. Nothing decided reads them; a headless run in virtual time, where nobody
        watches them, turns this off (Session.run_for); they are 0.0 then."""
        return self._wall_times

    @wall_times.setter
    def wall_times(self, timed: bool) -> None:
        self._wall_times = timed
        self._refresh()

    @property
    def policy(self) -> str:
        return self._policy

    @policy.setter
    def policy(self, policy: str) -> None:
        self._policy = policy
        self.clean_report = self._clean.get(policy)  # the policy's report of a clean scan

    def _refresh(self) -> None:
        self._auto_ready = (self._started and self._mode == "auto" and not self._stop_mask
                            and not self.observe)
        self._fast = self._auto_ready and self._frame is not None and not self._wall_times

    # -- commands ----------------------------------------------------------------------------
    def apply(self, command: Command) -> CommandResult:
        """Apply an operator command now; its effect on outputs shows at the next scan."""
        self._before_change()
        if self.observe and isinstance(command, SetMode | ManualOutput | SetPolicy
                                       | StartRecovery):
            return CommandResult.refused("read-only mode: nothing is written to the plant and "
                                         "the filter only detects")
        match command:
            case SetMode() if self.mode == "recovery":
                return CommandResult.refused("in recovery mode: leave recovery first")
            case SetMode(manual=True):
                if self.mode == "manual":
                    return CommandResult.refused("already in manual mode")
                self.mode = "manual"
                self.manual = {}
                self.law.hold(self.now)  # the program waits where it is
                self._supervise()
                return CommandResult.ok(f"manual mode: the control program waits{self._where()}"
                                        "; outputs follow operator requests, still through "
                                        "the safety filter")
            case SetMode(manual=False):
                if self.mode == "auto":
                    return CommandResult.refused("already in automatic mode")
                released = sorted(self.manual)
                self.mode = "auto"
                self.manual = {}
                self.law.resume(self.now)  # from where it waited, at the next scan
                self._supervise()
                extra = f"; released {', '.join(released)}" if released else ""
                return CommandResult.ok("automatic mode: the control program resumes"
                                        f"{self._where('from')} and drives the outputs"
                                        + extra)
            case ManualOutput(name=name, value=value):
                if self.mode != "manual":
                    return CommandResult.refused("manual requests need manual mode")
                if name not in self.layout.outputs:
                    return CommandResult.refused(f"{name!r} is not an output")
                if value is None:
                    self.manual.pop(name, None)
                    return CommandResult.ok(f"{name} released")
                self.manual[name] = bool(value)
                return CommandResult.ok(f"{name} requested {'on' if value else 'off'}")
            case FaultReset():
                return self.fault_reset()
            case StartRecovery(procedure=name):
                return self._start_recovery(name)
            case EndRecovery():
                return self._end_recovery()
            case SetPolicy(policy=policy):
                if policy not in POLICIES:
                    return CommandResult.refused(f"unknown policy {policy!r}")
                if policy == "monitor" and self.drives_real_plant and \
                        not self.allow_monitor_policy:
                    return CommandResult.refused(
                        "monitor policy passes unsafe orders through; refused on a real plant "
                        "(start with --allow-monitor to permit it)")
                old, self.policy = self.policy, policy
                if old == policy:  # (the journal must not read as a switch)
                    return CommandResult.ok(f"filter policy stays {policy}: already in effect")
                return CommandResult.ok(f"filter policy {old} -> {policy}")
            case InjectFault(injection=injection):
                if not self.plant.can_inject:
                    return CommandResult.refused("fault injection needs a simulated plant")
                try:
                    self.plant.inject(injection)
                except Exception as exc:  # a UsageError naming what exists
                    return CommandResult.refused(str(exc))
                return CommandResult.ok(f"SIMULATION: fault {injection} scheduled")
            case RepairFaults(device=device):
                if not self.plant.can_repair:
                    return CommandResult.refused("only a simulated plant can be repaired from "
                                                 "here")
                try:
                    repaired = self.plant.repair(self.now, device)
                except UsageError as exc:
                    return CommandResult.refused(str(exc))
                if not repaired:
                    return CommandResult.refused("no simulated fault to repair")
                done = "; ".join(f"{name} repaired ({', '.join(codes)} removed)"
                                 for name, codes in repaired)
                # Never promise what the reset may not do (a valve repaired between its
                # ends cannot be re-synchronised, a cell may have no diagnoser): its dialog
                # says what it resets and what stays.
                return CommandResult.ok(f"SIMULATION: {done}; next: a fault reset (r), "
                                        "which says first what it resets and what stays")
            case StopDevice(device=device):
                if device not in self.devices:
                    return CommandResult.refused(f"no device {device!r}; devices: "
                                                 + ", ".join(self.devices))
                self.stopped_devices.add(device)
                self._update_stop_mask()
                return CommandResult.ok(f"{device} stopped: its outputs "
                                        f"({', '.join(self.devices[device])}) are held at their "
                                        "safe values until released")
            case ReleaseDevice(device=device):
                if device not in self.stopped_devices:
                    return CommandResult.refused(f"{device} is not stopped")
                self.stopped_devices.discard(device)
                self._update_stop_mask()
                return CommandResult.ok(f"{device} released")
            case SetInput(name=name, value=value):
                if not self.plant.can_set_inputs:
                    return CommandResult.refused("inputs can only be set on a simulated plant")
                try:
                    self.plant.set_input(name, value)
                except KeyError:
                    return CommandResult.refused(
                        f"{name!r} is driven by the simulated plant, not by the operator")
                return CommandResult.ok(f"SIMULATION: input {name} {'on' if value else 'off'}")
        return CommandResult.refused(f"the engine does not handle {command!r}")

    def _supervise(self) -> None:
        """The steps' supervision watched only while the program runs in automatic mode:
        not while it waits (manual mode), nor in recovery mode (it waits, and restarts
        from its initial steps after), nor observing a device (it does not run)."""
        grafcet = self._supervised
        if grafcet is not None:
            grafcet.supervise(self.started and self.mode == "auto" and not self.observe,
                              self.now)

    def _where(self, word: str = "at") -> str:
        """' at “Closing” (X3), X10': the program's active steps for SetMode's answers, by
        their descriptions for the operator and the journal, their names for the engineer (''
        without a GRAFCET, or before the first scan: the program starts from its initial
        steps)."""
        steps = self.law.active_steps(self.image) if self.started else ()
        if not steps:
            return ""
        grafcet = self.project.controls[self.control_name].grafcet
        said = {s.name: s.description for s in grafcet.steps} if grafcet else {}
        return f" {word} " + ", ".join(f"\u201c{said[s]}\u201d ({s})" if said.get(s) else s
                                       for s in steps)

    def _start_recovery(self, name: str) -> CommandResult:
        stage = self.recovery
        if stage is None:
            return CommandResult.refused("this project declares no recovery procedure")
        if name not in stage.procedures:
            return CommandResult.refused(f"no recovery procedure {name!r}; the project has "
                                         + ", ".join(stage.procedures))
        if self.mode == "recovery" and stage.status == "running" and stage.active:
            return CommandResult.refused(f"recovery {stage.active.spec.name} is running: "
                                         "leave recovery first")
        if self.latched:
            return CommandResult.refused(
                "the outputs are held safe (" + "; ".join(r.detail for r in self.latched)
                + "): a fault reset first, then the recovery")
        spec = stage.procedures[name].spec
        stopped = sorted(d for d in self.stopped_devices
                         if set(self.devices[d]) & set(spec.outputs))
        if stopped:
            return CommandResult.refused(f"{', '.join(stopped)} stopped by the operator: "
                                         "release it first")
        devices = {v.device for v in self.project.outputs
                   if v.name in spec.outputs and v.device}
        if self.diagnosis is not None:
            self.diagnosis.resynchronise(devices, self.now, self.scan,
                                         f"recovery {name} started: re-synchronising")
        if self.monitors is not None:  # the program's tasks in progress are void now
            self.monitors.abandon()
        self.mode = "recovery"
        self.manual = {}
        self.law.hold(self.now)  # the program waits while the procedure runs
        stage.start(name, self.now)
        self._supervise()
        return CommandResult.ok(
            f"RECOVERY mode: {spec.description}; only {', '.join(spec.outputs)} move, "
            "every other output is held safe, and its own constraints still filter them")

    def _end_recovery(self) -> CommandResult:
        if self.mode != "recovery" or self.recovery is None:
            return CommandResult.refused("not in recovery mode")
        active = self.recovery.active
        reached = self.recovery.stop()
        self.mode = "auto"
        self.law.reset(self.image, self.now)
        self.law.resume(self.now)  # from its initial steps, their times from now
        self._supervise()
        if active is not None and reached == "done":
            # The observers the procedure re-establishes (a turntable emptied: an observer
            # set on an edge that never came back would deny it) start from their initial
            # values, like the program's steps.
            for observer in self.project.observers:
                if observer.name in active.spec.resets:
                    self.image[self.layout.slots[observer.name]] = observer.initial
        if self.monitors is not None:  # tasks the procedure's moves started are not the
            self.monitors.abandon()    # program's
        return CommandResult.ok(f"recovery {reached}; automatic mode: the control program "
                                "starts again from its initial steps")

    def limit_search_time(self, wall_us: float | None) -> None:
        """Live runs only: the corrector's search also stops after `wall_us` of wall time, a
        safety net on a loaded machine (a headless run never sets it: traces depend on the
        search's steps only; docs/filter.md, "Budget")."""
        self.safety_filter.wall_limit_us = wall_us

    def set_nominal_period(self, period_us: int) -> None:
        """The period the scans are meant to run at, when a session runs at another than the
        project's (--period): the diagnosers count a gap in the observation in it, and never
        in less than the project's period (a faster session does not make gaps shorter)."""
        if self.diagnosis is not None:
            self.diagnosis.period = max(period_us, self.project.scan_period_us)

    @property
    def drives_real_plant(self) -> bool:
        """Outputs written by this engine move real machinery."""
        return self.plant.is_real and not self.observe

    def _update_stop_mask(self) -> None:
        stopped = {o for d in self.stopped_devices for o in self.devices[d]}
        self._stop_mask = tuple(k for k, v in enumerate(self.project.outputs)
                                if v.name in stopped)
        self._refresh()

    def _before_change(self) -> None:
        """Something other than a scan is about to change the engine or its plant: the last
        scan's snapshot, if still pending, is built now from what that scan left."""
        if self._pending:
            self.snapshot()
        self._news = self._unmatched  # (the next scan has news)

    def fault_reset(self) -> CommandResult:
        self._before_change()
        parts = []
        if self.latched:
            parts.append("safe-state latch released (" + "; ".join(
                r.detail for r in self.latched) + ")")
            self.latched = []
        parts.extend(self.stages.reset(Moment(self.image, self.history, self.now, self.scan,
                                              self.started)))
        return CommandResult.ok("fault reset: " + ("; ".join(parts) if parts
                                                   else "nothing was latched"))

    # -- the state, for the closed-loop exploration ----------------------------------------
    def capture(self) -> EngineState:
        """Everything a scan or a command changes, copied: :meth:`restore` makes the engine
        continue exactly as from here (the project's compiled parts are shared). A stage that
        cannot be captured raises NotImplementedError (the monitors)."""
        return EngineState(
            # The history's images are never changed once in it: shared, not copied.
            list(self.image), tuple(self.history), self.scan, self.now,
            self.started, tuple(self.latched), self.mode, tuple(self.manual.items()),
            self.policy, frozenset(self.stopped_devices), self.input_scan.readback,
            self.stages.capture())

    def restore(self, state: EngineState) -> None:
        self._before_change()
        self.image[:] = state.image
        self.history.clear()
        self.history.extend(state.history)
        self.scan, self.now, self.started = state.scan, state.now, state.started
        self.latched = list(state.latched)
        self.mode, self.manual, self.policy = state.mode, dict(state.manual), state.policy
        self.stopped_devices = set(state.stopped_devices)
        self._update_stop_mask()
        self.input_scan.readback = state.readback
        self.stages.restore(state.stages)
        self._supervise()

    def latch_safe(self, source: str, detail: str) -> None:
        self._before_change()  # (between scans: a runner or the journal latching)
        if not any(r.source == source and r.detail == detail for r in self.latched):
            self.latched.append(LatchReason(source, detail, self.scan, self.now))

    def _latch_internal(self, error: str) -> None:
        """An internal error latches the outputs safe, once per distinct error: the same
        error again at the next scans (a stage broken for good) adds no reason, and the
        operator reads one, dated from the scan it began at (else one reason, and one
        explanation, per scan: a live run would fall behind more at every scan)."""
        for r in self.latched:
            if r.source == "internal" and r.detail == f"internal error at scan {r.scan}: {error}":
                return
        self.latch_safe("internal", f"internal error at scan {self.scan}: {error}")

    def _failure(self, part: str, exc: Exception) -> str:
        """An exception outside the scan's own handling (reading what the scan left for its
        snapshot, writing to the plant): latched as an internal error naming `part` in plain
        words, one of INTERNAL_PARTS (LatchReason.part reads it back); returns the error for
        the snapshot. Whoever calls this then puts the outputs in the safe state
        (:meth:`_go_safe`)."""
        assert part in INTERNAL_PARTS, part
        error = f"{part} failed: {type(exc).__name__}: {exc}"
        self._latch_internal(error)
        return error

    def _go_safe(self, now: int) -> None:
        """After an internal error outside the scan's own handling, when this scan's outputs
        are already written: the image's outputs safe and the safe vector written to the
        plant at once, so no scan that could not be completed leaves the plant driven until
        the next scan. If the plant cannot take it, that is latched too (a PlantError as the
        plant's, anything else as one more internal error). Observing a read-only device
        writes nothing."""
        if self.observe:
            return
        safe = self.safe_vector
        image = self.image
        for slot, value in zip(self.output_slots, safe, strict=True):
            image[slot] = value
        try:
            lost = self.output_scan.write(now, safe)
        except Exception as exc:
            self._failure("writing the safe outputs to the plant", exc)
            return
        if lost is not None:
            self.latch_safe("plant", lost)

    def _left_safe(self, error: str | None) -> None:
        """The scan's results once an internal error put its outputs safe after they were
        decided (:meth:`_go_safe`, a failed write): the outputs as the image holds them now,
        the image as the scan's values and the history's newest entry, the scan's error."""
        image = self.image
        record = self._record
        record.outputs = tuple(image[s] for s in self.output_slots)
        record.error = record.error or error
        if tuple(image) != record.values:
            record.values = tuple(image)
            self.history[0] = record.values

    # -- the scan ----------------------------------------------------------------------------
    def step(self, now: int) -> Snapshot:
        """One scan at `now`, and what it left behind."""
        self.run(now)
        return self.snapshot()

    def run(self, now: int) -> bool:
        """One scan at `now` without building its snapshot (:meth:`snapshot` builds it on
        demand, until anything changes the engine again). Returns whether the scan has news:
        False only when its filter report is the very object of the previous scan's (the
        policy's clean one, or a remembered correction given again) and its snapshot would
        show no latch, no error, no plant event, nothing reconstructed nor masked, no manual
        request, and the same plant status, diagnosers, recovery state and monitor_marks as
        the previous scan, with no command since. A quiet scan's snapshot differs from the
        one before only in what moves by itself: scan, time, values, fov, outputs, steps and
        firings, timers, plant state and counters, monitors' stopwatches, wall times; a
        reader that counts reports per scan counts the same report again
        (hmi.session.run_report.RunCollector.quiet)."""
        if self._fast:
            return self._frame(now)  # type: ignore[misc]  # (the automatic mode's, printed)
        timed = self.wall_times
        wall = time.perf_counter() if timed else 0.0
        self._pending = False  # the previous scan's snapshot, if never asked for: dropped
        self._cycle(now)
        return self._conclude(now, wall)

    def _conclude(self, now: int, wall: float = 0.0, taken: tuple[Any, ...] | None = None,
                  raised: Raised | None = None) -> bool:
        """What run() does after stages 1 to 8 (the scan's record filled): the supervision,
        what the scan left read for its snapshot, the history, whether the scan has news.
        `taken`: the plant's events when they were taken already; `raised`: the read the
        printed frame made (settling the monitors, taking the plant's events or reading its
        status: hmi.engine.compiled) that raised, handled here as if this one had."""
        record = self._record
        diagnosis, monitored, error = record.diagnosis, record.monitored, record.error
        image = self.image
        plant = self.plant
        history = self.history
        # What the scan left, read for its snapshot: each read outside the stages' own error
        # handling is guarded (free in Python 3.11 when nothing raises); one that fails
        # latches an internal error naming it and puts the outputs safe at once (_go_safe).
        # First what each publishing stage gives (its declaration's `news`), before the
        # scan's image joins the history; a stage that runs after the output scan is not
        # read when that part raised (latched already): it gives what it gives when its
        # read fails.
        failed: str | None = None
        given: list[Any] = []
        if raised is None and monitored:  # (most scans: each read once, none raising)
            try:
                for read, stage in self._reads:
                    given.append(read(stage, image, history, now))
            except Exception as exc:  # (the one that raised, then the rest one by one)
                _, stage, reading, unread, _ = self._publishing[len(given)]
                failed = self._failure(reading, exc)
                given.append(unread(stage))
                failed = self._publish_carefully(now, monitored, raised, given) or failed
        else:
            failed = self._publish_carefully(now, monitored, raised, given)
        published = tuple(given)
        # The image as the scan left it: the snapshot's values and the history's newest
        # entry are one tuple (an image in the history is never changed).
        values = tuple(image)
        history.appendleft(values)
        try:
            if raised is not None and raised.part == EVENTS:
                raise raised.exc
            events = plant.take_events() if taken is None else taken
        except Exception as exc:
            failed = self._failure(EVENTS, exc)
            events = ()
        try:
            if raised is not None and raised.part == STATUS:
                raise raised.exc
            status = plant.status
        except Exception as exc:
            failed = self._failure(STATUS, exc)
            status = self._status_unknown()
        if failed is not None or error is not None:
            if failed is not None:
                self._go_safe(now)
            record.values = values
            self._left_safe(failed)
            values = record.values
            error = record.error
        last = self._news
        # (a command since, a new policy included, makes this scan news and compares the
        # next with this one: _news _unmatched)
        news = not (error is None and not events and not self.latched
                    and not diagnosis.masked and not diagnosis.reconstructed
                    and not self.manual)
        compared = (status, *published)
        if not news:  # (and the plant's status and what each stage gives are the very
            # objects of then: the filter's report, the monitors' marks, ...)
            news = not all(map(is_, compared, last.given))
        if news:
            self._news = self._news_kind(compared, *compared)  # type: ignore[call-arg]
        record.values = values
        record.published = published
        record.events = events
        record.scan_us = (time.perf_counter() - wall) * 1e6 if self._wall_times else 0.0
        record.settled = False
        self._pending = True
        return news

    def _publish_carefully(self, now: int, monitored: bool, raised: Raised | None,
                           given: list[Any]) -> str | None:
        """What each publishing stage not in `given` yet gives (into `given`), each read on
        its own: one that raises (or whose printed read raised: `raised`) is latched under
        what it reads and gives what it gives when it fails; one that runs after the output
        scan is not read when that part raised (`monitored` False: latched already).
        Returns the error of the last that failed."""
        image, history = self.image, self.history
        failed: str | None = None
        for read, stage, reading, unread, after in self._publishing[len(given):]:
            try:
                if after and not monitored:
                    given.append(unread(stage))
                    continue
                if raised is not None and raised.part == reading:
                    raise raised.exc
                given.append(read(stage, image, history, now))
            except Exception as exc:
                failed = self._failure(reading, exc)
                given.append(unread(stage))
        return failed

    def run_while_quiet(self, start: int, end: int, period: int) -> QuietRun:
        """Scans at `start`, `start + period`, ... up to `end` included, by :meth:`run`,
        stopping after the first that has news. Returns how many ran and whether the last
        had news. A headless run hands the engine a stretch of scans at once when nothing
        it reads can change at a quiet scan (hmi.session.Session.run_for); the last scan's
        snapshot is pending as after run()."""
        run, frame = self.run, self._frame
        now = start
        while now <= end:  # (the scans counted from the times: one addition a scan)
            if self._fast:  # (the printed frame, without run()'s call)
                if frame(now):  # type: ignore[misc]
                    return QuietRun((now - start) // period + 1, True)
            elif run(now):
                return QuietRun((now - start) // period + 1, True)
            now += period
        return QuietRun((now - start) // period, False)

    def snapshot(self) -> Snapshot:
        """The last scan's snapshot (:meth:`run`), built now if not yet: the engine's
        state is still the one that scan left (a command builds it first)."""
        if not self._pending:
            if self.last is None:
                raise RuntimeError("no scan has run yet")
            return self.last
        self._pending = False
        record = self._record
        plant = self.plant
        policy = self._policy
        now = self.now
        # What the snapshot reads of the engine and the plant, each guarded as in run(): one
        # that raises latches an internal error naming it, is shown empty (the timers'
        # elapsed times as 0), and the outputs go safe at once.
        failed: str | None = None
        # What the stages gave the scan (their declarations' `news`) and what is read of
        # them now (their `fields`; one that runs after the output scan, not when that part
        # raised, as in run()), by the snapshot's field
        shown = dict(zip(self._published_fields, record.published, strict=True))
        image = self.image
        monitored = record.monitored
        for fields, stage, after in self._showing:
            if after and not monitored:
                values = fields.failed(stage)
            else:
                try:
                    values = fields.read(stage, image, now)
                except Exception as exc:
                    failed = self._failure(fields.reading, exc)
                    values = fields.failed(stage)
            shown.update(zip(fields.fields, values, strict=True))
        try:
            status = plant.status
        except Exception as exc:
            failed = self._failure("reading the plant's status", exc)
            status = self._status_unknown()
        try:
            state = plant.state()
        except Exception as exc:
            failed = self._failure("reading the plant's state", exc)
            state = ()
        try:
            counters = plant.counters()
        except Exception as exc:
            failed = self._failure("reading the plant's counters", exc)
            counters = ()
        diagnosis = record.diagnosis
        masked: tuple[str, ...] = ()
        if policy != "monitor":
            try:
                masked = self._masked(diagnosis)
            except Exception as exc:
                failed = self._failure("reading the masked outputs", exc)
        if failed is not None:
            self._go_safe(now)
            self._left_safe(failed)
        snapshot = self.last = Snapshot(
            scan=self.scan, time_us=now, period_us=self._period, layout=self.layout,
            values=record.values, fov=tuple(record.fov), outputs=tuple(record.outputs),
            control_name=self.control_name, mode=self._mode,
            manual=tuple(sorted(self.manual.items())) if self.manual else (), policy=policy,
            latched=tuple(self.latched) if self.latched else (), plant=status,
            plant_state=state, plant_counters=counters, plant_events=record.events,
            reconstructed=diagnosis.reconstructed, masked=masked,
            stopped_devices=(tuple(sorted(self.stopped_devices)) if self.stopped_devices
                             else ()),
            error=record.error, scan_wall_us=record.scan_us,
            filter_wall_us=record.filter_us, **shown)
        if self._shows:  # (the stages that show something: Snapshot.stages)
            snapshot = self.last = snapshot._replace(stages=self.stages.shown())
        return snapshot

    def _status_unknown(self) -> PlantStatus:
        """The plant's status when reading it failed: the last one shown, else a plain one
        (an internal error is latched for it)."""
        if self.last is not None:
            return self.last.plant
        return PlantStatus("unknown", "the plant's status could not be read")

    def advance(self, now: int) -> None:
        """One scan at `now` whose results nobody reads: the same stages, no snapshot (the
        closed-loop exploration, hmi.studies.explore, only follows the state). The plant's
        events stay with the plant (take_events)."""
        self._pending = False
        self._news = self._unmatched  # (the next run() cannot compare with this scan)
        self._cycle(now)
        self.history.appendleft(tuple(self.image))

    def _cycle(self, now: int) -> None:
        """Stages 1 to 8 (module docstring): the parts hmi.program.order.ENGINE names, in
        its order (_GUARDED, then _EXCHANGED): stages 2-5 are the scan program of the
        engine's mode (hmi.engine.compiled), the filter's first test and the monitors too;
        the stages' own handlers run whatever else happens (a violation, masking, a latch,
        a recovery), on the same state. A part before the output scan that fails leaves
        the outputs safe (the inputs unknown: held); the output scan and the monitors run
        whatever happened before them."""
        self.scan += 1
        self.now = now
        s = self._parts
        s.diagnosis = self.diagnosis.current if self.diagnosis else NO_DIAGNOSIS
        s.report = s.error = None
        s.filter_us = 0.0
        try:
            for part in _GUARDED:
                part(self, s, now)
        except _InputsUnknown:
            s.fov = s.outputs = self._held_outputs()
        except Exception as exc:  # never leave the plant driven by a half-computed scan
            s.error = f"{type(exc).__name__}: {exc}"
            self._latch_internal(s.error)
            s.fov = s.outputs = self.safe_vector
        for part in _EXCHANGED:
            part(self, s, now)
        self._keep(s.fov, s.outputs, s.report, s.diagnosis, s.monitored, s.error,
                   s.filter_us)

    def _scan_inputs(self, s: _Parts, now: int) -> None:
        """1. input scan"""
        lost = self.input_scan.read(self.image, now)
        if lost is not None:
            # The inputs are unknown (plant lost): memories, timers and steps hold, so the
            # control law never acts on stale inputs; the outputs go safe (latched).
            self.latch_safe("plant", lost)
            raise _InputsUnknown
        if not self._started:
            self._start(now)

    def _scan_program(self, s: _Parts, now: int) -> None:
        """2-5: memory, diagnosers, reconstruction, recoveries needed, and the law (or the
        operator's requests, or a recovery procedure): the mode's program"""
        fast = self.compiled
        image, hist = self.image, self.history
        recovery = self.recovery
        if self.observe:
            fast.observed(image, hist, now, self.scan)
            fov = self.input_scan.readback
        elif self._mode == "manual":  # the program waits: neither its step times nor law
            fast.held(image, hist, now, self.scan)
            fov = self._manual_fov()
        elif self._mode == "recovery" and recovery is not None:
            active = recovery.active
            if active is None:  # (none started: the program waits, the outputs safe)
                fast.held(image, hist, now, self.scan)
                fov = self.safe_vector
            else:
                fov = fast.recovery(active.spec.name)(image, hist, now, self.scan)
        else:
            fov = fast.core(image, hist, now, self.scan)
        if self.diagnosis is not None:
            s.diagnosis = self.diagnosis.current
        if self._stop_mask and not self.observe:
            fov = tuple(self.safe_vector[k] if k in self._stop_mask else value
                        for k, value in enumerate(fov))
        s.fov = fov

    def _scan_filter(self, s: _Parts, now: int) -> None:
        """6. filter: its stage's decision (FilterStage.decide), given the policy, the latch,
        the diagnosers' mask and whether a recovery runs"""
        timed = self._wall_times
        started = time.perf_counter() if timed else 0.0
        decision = self.filter_stage.decide(self.image, self.history, s.fov, self._policy,
                                            bool(self.latched), s.diagnosis.mask,
                                            self._mode == "recovery")
        if timed:
            s.filter_us = (time.perf_counter() - started) * 1e6
        if decision.latch is not None:
            self.latch_safe("filter", decision.latch)
        outputs = decision.outputs
        s.report = decision.report
        if self.observe:
            outputs = s.fov  # what the device has: it is observed, never driven
        elif self.latched:
            outputs = self.safe_vector
        s.outputs = outputs

    def _scan_outputs(self, s: _Parts, now: int) -> None:
        """7. output scan: the outputs into the image, and written to the plant (unless it
        is observed). The write is OutputScan.write's (a PlantError latched as the plant's,
        with its detail, which still writes the safe vector: _go_safe), written out here
        rather than called: it runs at every scan."""
        outputs = s.outputs
        self._image_outputs(outputs)
        if not self.observe:
            try:
                self.plant.write_vector(now, self.output_scan.names, outputs)
            except Exception as exc:
                s.error = self._write_error(now, outputs, s.error, exc)

    def _image_outputs(self, outputs: tuple[bool, ...]) -> None:
        """The outputs into the image: one slice when they sit together, else slot by slot."""
        at = self._outputs_at
        if at is not None and len(outputs) == len(self.output_slots):
            self.image[at] = outputs
        else:
            for slot, value in zip(self.output_slots, outputs, strict=True):
                self.image[slot] = value

    def _scan_monitors(self, s: _Parts, now: int) -> None:
        """8. the part after the output scan (the stages' statements there: the monitors'),
        on the I/O this scan exchanged (what they publish and show: their declarations)"""
        monitors = self.compiled.monitors
        if monitors is None:
            s.monitored = False
            return
        try:
            monitors(self.image, self.history, now, self.scan)
        except Exception as exc:
            s.monitored = False
            s.error = self._monitors_error(now, s.error, exc)
            return
        s.monitored = True

    def _auto_lost(self, now: int, exc: PlantError) -> None:
        """The automatic mode's input scan failed: as in _cycle, memories, timers and steps
        hold, the outputs go safe (latched), the output scan and the monitors run."""
        self.latch_safe("plant", plant_detail(exc))
        stage = self.diagnosis
        self._auto_safe(now, None, stage.current if stage is not None else NO_DIAGNOSIS)

    def _auto_failed(self, now: int, exc: Exception, diagnosis: Diagnosis) -> None:
        """An exception in the automatic mode's stages 2-6: latched, the outputs safe."""
        error = f"{type(exc).__name__}: {exc}"
        self._latch_internal(error)
        self._auto_safe(now, error, diagnosis)

    def _auto_safe(self, now: int, error: str | None, diagnosis: Diagnosis) -> None:
        safe = self.safe_vector
        monitored, error = self._output_scan(now, safe, error)
        self._keep(safe, safe, None, diagnosis, monitored, error, 0.0)

    def _auto_filter(self, now: int, fov: tuple[bool, ...], diagnosis: Diagnosis,
                     unquiet: object = None) -> FilterReport | None:
        """The automatic mode's filter when the candidate is masked, latched or violated
        (`unquiet`: the frame's test, the violation word when nothing is masked nor
        latched). Nothing masked nor latched, before the decision or by it: the decision's
        report, its outputs in the image and the scan's record (ScanRecord.outputs), which
        the printed frame writes, monitors and concludes as it does a clean candidate's.
        Otherwise the output scan and the monitors run here and the scan is kept (None: the
        frame concludes it)."""
        image = self.image
        mask = diagnosis.mask
        try:
            if mask is None and not self.latched:
                # violated, nothing masked: the stage's decision given the word (the frame's
                # test is the word itself then)
                unmasked = self.filter_stage.unmasked
                decision = unmasked(image, self.history, fov, self._policy, False, unquiet)
            else:
                decision = self.filter_stage.apply(image, self.history, fov, self._policy,
                                                   bool(self.latched), mask)
            if decision.latch is not None:
                self.latch_safe("filter", decision.latch)
            outputs = decision.outputs
            report = decision.report
            if self.latched:
                outputs = self.safe_vector
        except Exception as exc:  # never leave the plant driven by a half-computed scan
            self._auto_failed(now, exc, diagnosis)
            return None
        if mask is None and not self.latched:
            self._image_outputs(outputs)  # (the output scan's first half: _scan_outputs)
            self._record.outputs = outputs
            return report
        monitored, error = self._output_scan(now, outputs, None)
        self._keep(fov, outputs, report, diagnosis, monitored, error, 0.0)
        return None

    def _finish(self, now: int, fov: tuple[bool, ...], outputs: tuple[bool, ...],
                report: FilterReport, diagnosis: Diagnosis, monitored: bool,
                error: str | None, taken: tuple[Any, ...] | None = None,
                raised: Raised | None = None) -> bool:
        """An automatic-mode scan filtered, written and monitored, kept and concluded (the
        printed frame's way out when the rest is not a quiet scan's: _conclude's `taken`
        and `raised`)."""
        self._keep(fov, outputs, report, diagnosis, monitored, error, 0.0)
        return self._conclude(now, 0.0, taken, raised)

    def _keep(self, fov: tuple[bool, ...], outputs: tuple[bool, ...],
              report: FilterReport | None, diagnosis: Diagnosis, monitored: bool,
              error: str | None, filter_us: float) -> None:
        """What stages 1 to 8 decided, into the scan's record (ScanRecord), the filter's
        report into its stage (what it publishes: program_stages.FILTER)."""
        record = self._record
        self.filter_stage.report = report
        record.fov = fov
        record.outputs = outputs
        record.diagnosis = diagnosis
        record.monitored = monitored
        record.error = error
        record.filter_us = filter_us

    def _output_scan(self, now: int, outputs: tuple[bool, ...], error: str | None
                     ) -> tuple[bool, str | None]:
        """The parts from the output scan on (_EXCHANGED: stage 7 then 8) for `outputs`,
        after the rest of a scan ran its own way (the printed frame's exits). Returns whether
        the monitors ran and the scan's error."""
        s = self._parts
        s.outputs = outputs
        s.error = error
        for part in _EXCHANGED:
            part(self, s, now)
        return s.monitored, s.error

    def _write_error(self, now: int, outputs: tuple[bool, ...], error: str | None,
                     exc: Exception) -> str | None:
        """Writing the outputs raised `exc`: a PlantError is the plant's own, latched as
        OutputScan.write reports it; anything else a bug, in the plant or here. Returns the
        scan's error."""
        if isinstance(exc, PlantError):
            self.latch_safe("plant", plant_detail(exc))
            return error
        return error or self._write_failed(now, outputs, exc)

    def _monitors_error(self, now: int, error: str | None, exc: Exception) -> str:
        """A broken monitor must not stop the scan silently: latched, and, the outputs
        written already (the monitors watch what was exchanged), safe at once, not from the
        next scan. Returns the scan's error."""
        message = f"{type(exc).__name__}: {exc}"
        self._latch_internal(message)
        self._go_safe(now)
        return error or message

    def _write_failed(self, now: int, outputs: tuple[bool, ...], exc: Exception) -> str:
        """Writing the scan's outputs raised something other than a PlantError: latched as an
        internal error; the image's outputs go safe and, unless they were already, the safe
        vector is written at once (that failing too is latched: :meth:`_go_safe`)."""
        error = self._failure("writing the outputs to the plant", exc)
        if outputs != self.safe_vector:
            self._go_safe(now)
        return error

    def _start(self, now: int) -> None:
        self.law.reset(self.image, now)
        self.history.clear()
        values = tuple(self.image)
        for _ in range(self.history.maxlen or 1):
            self.history.append(values)
        self.started = True
        self._supervise()

    def _masked(self, diagnosis: Diagnosis) -> tuple[str, ...]:
        """The outputs the diagnosers' mask holds at 0 (a running recovery lifts it from the
        outputs it drives)."""
        recovery = self.recovery
        if self._mode != "recovery" or recovery is None or recovery.active is None:
            return diagnosis.masked
        driven = recovery.active.spec.outputs
        return tuple(o for o in diagnosis.masked if o not in driven)

    def _manual_fov(self) -> tuple[bool, ...]:
        """Manual mode: the operator's requests as the vector (an output not requested:
        off)."""
        manual = self.manual
        return tuple(manual.get(name, False) for name in self.layout.outputs)

    def _held_outputs(self) -> tuple[bool, ...]:
        """Outputs of a scan whose inputs are unknown: safe; observed ones as last seen."""
        if self.observe:
            return tuple(self.image[s] for s in self.output_slots)
        return self.safe_vector

# What no scan gives (Engine._unmatched)
_NEVER = object()



class _InputsUnknown(Exception):
    """The input scan failed: skip to the output scan with the outputs safe."""


class _Parts:
    """What a scan's parts hand on to the next ones (Engine._cycle): one per engine, filled
    in place by every scan, as ScanRecord is."""

    __slots__ = ("diagnosis", "error", "filter_us", "fov", "monitored", "outputs", "report")

    def __init__(self) -> None:
        self.diagnosis = NO_DIAGNOSIS  # routes, mask and records (stage 3)
        self.fov: tuple[bool, ...] = ()  # the functional output vector (stage 5)
        self.outputs: tuple[bool, ...] = ()  # what is written (stage 7)
        self.report: FilterReport | None = None  # the filter's (None: not reached)
        self.error: str | None = None  # an internal error of the scan, latched
        self.filter_us = 0.0  # the filter's wall time (0.0 unless Engine.wall_times)
        self.monitored = False  # whether the monitors ran (stage 8)


# Engine's part for each part of hmi.program.order.ENGINE, and the two walks Engine._cycle
# takes of them
_PART = {order.INPUTS: Engine._scan_inputs, order.MODE_PROGRAM: Engine._scan_program,
         order.FILTER: Engine._scan_filter, order.OUTPUTS: Engine._scan_outputs,
         order.MONITORS: Engine._scan_monitors}
_GUARDED = tuple(_PART[part] for part in order.GUARDED)
_EXCHANGED = tuple(_PART[part] for part in order.EXCHANGED)


def _after(stage: Any) -> bool:
    """Whether a declared stage runs after the output scan (hmi.program.order.MONITORS)."""
    return order.MONITORS in stage.parts


def _all_exprs(project: Project) -> Iterator[Expr]:
    for procedure in recoveries_of(project):
        yield from procedure.exprs
    for t in project.timers:
        yield t.input
    for o in project.observers:
        yield from (e for e in (o.expr, o.set, o.reset) if e is not None)
    for c in project.constraints:
        yield c.expr
    for law in project.controls.values():
        for eq in law.equations:
            yield from (e for e in (eq.expr, eq.set, eq.reset) if e is not None)
        if law.grafcet:
            for tr in law.grafcet.transitions:
                yield tr.receptivity
            for step in law.grafcet.steps:
                for action in step.actions:
                    if action.condition is not None:
                        yield action.condition

"""The scan: one PLC cycle, in the order of DESIGN.md (000 Fig. 1, 004 Fig. 1).

    1 input scan   2 memory (timers, observers, step times)   3 diagnosers
    4 reconstruction   5 functional control (or manual requests)   6 filter   7 output scan

The engine never reads a clock: :meth:`Engine.step` is given the scan's time. Everything it
computes lands in an immutable :class:`Snapshot`. The engine knows nothing of any UI.
"""

from __future__ import annotations

import time
import traceback
from collections import deque
from collections.abc import Callable, Sequence

from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    CommandResult,
    FaultReset,
    InjectFault,
    ManualOutput,
    ReleaseDevice,
    RepairFaults,
    SetInput,
    SetMode,
    SetPolicy,
    StopDevice,
)
from hmi.engine.diagnoser import install_diagnosers
from hmi.engine.filter import SafetyFilter
from hmi.engine.layout import Layout
from hmi.engine.monitors import install_monitors
from hmi.engine.snapshot import LatchReason, Snapshot
from hmi.errors import UsageError
from hmi.explain.alarms import AlarmManager
from hmi.explain.builder import ExplanationBuilder
from hmi.logic.control import ControlRuntime
from hmi.logic.expr import BoolFn, compile_bool, max_depth
from hmi.logic.timers import TimerRuntime
from hmi.plant.base import Plant, PlantError
from hmi.project.diagnosers import layout_names
from hmi.project.model import POLICIES, Project


class Engine:
    def __init__(self, project: Project, plant: Plant, control: str | None = None,
                 policy: str | None = None, solver: str | None = None,
                 diagnosis: str = "ftc", solver_budget: int | None = None):
        self.project = project
        self.plant = plant
        self.control_name = control or project.default_control
        if self.control_name not in project.controls:
            raise KeyError(self.control_name)
        law = project.controls[self.control_name]
        self.policy = policy or project.policy
        if self.policy not in POLICIES:
            raise ValueError(self.policy)
        # Read-only plant (observing a real PLC): the device's own outputs, read back, replace
        # the FOV; the control law does not run, nothing is written, the filter only detects.
        self.observe = bool(getattr(plant, "read_only", False))
        if self.observe:
            self.policy = "monitor"
        self._readback: tuple[bool, ...] = ()
        # Partition flags and filtered sensors get slots (hmi/engine/diagnoser.py).
        self.layout = Layout.build(project, law, extra=layout_names(project))
        lay = self.layout
        slots, times = lay.slots, lay.step_times
        self.input_slots = lay.indices(lay.inputs)
        self.output_slots = lay.indices(lay.outputs)
        self.safe_vector = tuple(v.safe for v in project.outputs)
        self.timers = [(TimerRuntime(t.name, t.kind, t.preset_us), slots[t.name],
                        compile_bool(t.input, slots, times)) for t in project.timers]
        self.observers: list[tuple[int, BoolFn | None, BoolFn | None, BoolFn | None]] = []
        for o in project.observers:
            if o.expr is not None:
                self.observers.append((slots[o.name], compile_bool(o.expr, slots, times),
                                       None, None))
            else:
                self.observers.append((slots[o.name], None, compile_bool(o.set, slots, times),
                                       compile_bool(o.reset, slots, times)))
        self.control = ControlRuntime(law, slots, times)
        depth = 1
        for expr in _all_exprs(project):
            depth = max(depth, max_depth(expr))
        self.history: deque[list] = deque(maxlen=depth)
        self.image: list = lay.initial_image(project)
        self.scan = 0
        self.now = 0
        self.mode = "auto"
        self.manual: dict[str, bool] = {}
        self.latched: list[LatchReason] = []
        self.last: Snapshot | None = None
        self.started = False
        # Extension points, in scan order. A stage reads and writes the image and may put
        # what it wants shown into `self.extras` (keys are Snapshot field names).
        self.stages_after_memory: list[Callable[[Engine], None]] = []  # diagnosers
        self.output_stage: Callable[[Engine, tuple[bool, ...]], tuple[tuple[bool, ...], object]]
        self.filter = SafetyFilter(project, slots, times, solver or project.solver,
                                   solver_budget or project.solver_budget)
        self.output_stage = self.filter  # the safety filter
        # Observers of the whole scan (I(t) read and O(t) written): stopwatch monitors.
        self.stages_after_output: list[Callable[[Engine], None]] = []
        self.snapshot_extras: list[Callable[[Engine, dict], None]] = []  # explanations...
        # Each reset hook releases what its feature latched and returns lines saying what
        # was reset (or what stays, and why).
        self.reset_hooks: list[Callable[[Engine], list[str]]] = []
        self.extras: dict = {}
        # Explanations and alarms (computed every scan; the journal listens from outside).
        self.explainer = ExplanationBuilder(project)
        self.alarm_manager = AlarmManager()
        self.pending_alarm_events: list = []  # from acknowledgements between scans
        self.explanations: tuple = ()
        self.devices = {v.device: tuple(o.name for o in project.outputs
                                        if o.device == v.device)
                        for v in project.outputs if v.device}
        self.stopped_devices: set[str] = set()
        self._stop_mask: tuple[int, ...] = ()
        install_monitors(self)  # after the explainer: it adds a builder to it
        # Diagnosers (stages 3-4), masking around the filter, their reset hook.
        self.diagnosis = install_diagnosers(self, diagnosis)

    # -- commands ----------------------------------------------------------------------------
    def apply(self, command) -> CommandResult:
        """Apply an operator command now; its effect on outputs shows at the next scan."""
        if self.observe and isinstance(command, SetMode | ManualOutput | SetPolicy):
            return CommandResult.refused("read-only mode: nothing is written to the plant and "
                                         "the filter only detects")
        match command:
            case SetMode(manual=True):
                if self.mode == "manual":
                    return CommandResult.refused("already in manual mode")
                self.mode = "manual"
                self.manual = {}
                return CommandResult.ok("manual mode: outputs follow operator requests, "
                                        "still through the safety filter")
            case SetMode(manual=False):
                if self.mode == "auto":
                    return CommandResult.refused("already in automatic mode")
                released = sorted(self.manual)
                self.mode = "auto"
                self.manual = {}
                extra = f"; released {', '.join(released)}" if released else ""
                return CommandResult.ok("automatic mode: the control law drives the outputs"
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
            case SetPolicy(policy=policy):
                if policy not in POLICIES:
                    return CommandResult.refused(f"unknown policy {policy!r}")
                if policy == "monitor" and getattr(self.plant, "kind", "sim") != "sim" and \
                        not getattr(self, "allow_monitor_on_real_plant", False):
                    return CommandResult.refused(
                        "monitor policy passes unsafe orders through; refused on a real plant "
                        "(start with --allow-monitor to permit it)")
                old, self.policy = self.policy, policy
                return CommandResult.ok(f"filter policy {old} -> {policy}")
            case InjectFault(injection=injection):
                inject = getattr(self.plant, "inject", None)
                if inject is None:
                    return CommandResult.refused("fault injection needs a simulated plant")
                try:
                    inject(injection)
                except Exception as exc:  # a UsageError naming what exists
                    return CommandResult.refused(str(exc))
                return CommandResult.ok(f"SIMULATION: fault {injection} scheduled")
            case RepairFaults(device=device):
                repair = getattr(self.plant, "repair", None)
                if repair is None:
                    return CommandResult.refused("only a simulated plant can be repaired from "
                                                 "here")
                try:
                    repaired = repair(self.now, device)
                except UsageError as exc:
                    return CommandResult.refused(str(exc))
                if not repaired:
                    return CommandResult.refused("no simulated fault to repair")
                done = "; ".join(f"{name} repaired ({', '.join(codes)} removed)"
                                 for name, codes in repaired)
                return CommandResult.ok(f"SIMULATION: {done}; a fault reset now re-synchronises "
                                        "the diagnosers")
            case Acknowledge(key=key):
                events = self.alarm_manager.acknowledge(key, self.scan, self.now)
                self.pending_alarm_events.extend(events)
                if key is not None and not events:
                    return CommandResult.refused(f"no alarm {key} to acknowledge")
                return CommandResult.ok(f"acknowledged {len(events)} alarm"
                                        f"{'s' if len(events) != 1 else ''}")
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
            case ChoosePolicy(key=key, policy=policy_id):
                return self._choose_policy(key, policy_id)
            case SetInput(name=name, value=value):
                set_input = getattr(self.plant, "set_input", None)
                if set_input is None:
                    return CommandResult.refused("inputs can only be set on a simulated plant")
                try:
                    set_input(name, value)
                except KeyError:
                    return CommandResult.refused(
                        f"{name!r} is driven by the simulated plant, not by the operator")
                return CommandResult.ok(f"SIMULATION: input {name} {'on' if value else 'off'}")
        return CommandResult.refused(f"the engine does not handle {command!r}")

    def _update_stop_mask(self) -> None:
        stopped = {o for d in self.stopped_devices for o in self.devices[d]}
        self._stop_mask = tuple(k for k, v in enumerate(self.project.outputs)
                                if v.name in stopped)

    def _choose_policy(self, key: str, policy_id: str) -> CommandResult:
        explanation = next((e for e in self.explanations if e.key == key), None)
        if explanation is None:
            alarm = self.alarm_manager.alarms.get(key)
            explanation = alarm.explanation if alarm else None
        if explanation is None:
            return CommandResult.refused(f"no situation {key} to act on")
        policy = next((p for p in explanation.policies if p.id == policy_id), None)
        if policy is None:
            return CommandResult.refused(f"{key} offers no policy {policy_id!r}; it offers "
                                         + ", ".join(p.id for p in explanation.policies))
        if policy.command is None:
            return CommandResult.ok(f"policy '{policy.label}' chosen for {key}: "
                                    f"{policy.effect}")
        result = self.apply(policy.command)
        verdict = "chosen" if result.accepted else "could not be carried out"
        return CommandResult(result.accepted, f"policy '{policy.label}' {verdict} for {key}: "
                             f"{result.message}")

    def fault_reset(self) -> CommandResult:
        parts = []
        if self.latched:
            parts.append("safe-state latch released (" + "; ".join(
                r.detail for r in self.latched) + ")")
            self.latched = []
        for hook in self.reset_hooks:
            parts.extend(hook(self))
        return CommandResult.ok("fault reset: " + ("; ".join(parts) if parts
                                                   else "nothing was latched"))

    def latch_safe(self, source: str, detail: str) -> None:
        if not any(r.source == source and r.detail == detail for r in self.latched):
            self.latched.append(LatchReason(source, detail, self.scan, self.now))

    # -- the scan ----------------------------------------------------------------------------
    def step(self, now: int) -> Snapshot:
        wall = time.perf_counter()
        self.scan += 1
        self.now = now
        image = self.image
        error = None
        extras: dict = {}
        self.extras = extras
        try:
            if not self._input_scan(now):
                # The inputs are unknown (plant lost): memories, timers and steps hold, so
                # the control law never acts on stale inputs; the outputs go safe (latched).
                raise _InputsUnknown
            if not self.started:
                self._start(now)
            hist = self.history
            # 2. memory
            for runtime, slot, fn in self.timers:
                image[slot] = runtime.update(fn(image, hist), now)
            for slot, expr, set_, reset in self.observers:
                if expr is not None:
                    image[slot] = expr(image, hist)
                else:
                    image[slot] = not reset(image, hist) and (set_(image, hist) or image[slot])
            self.control.update_times(image, now)
            # 3-4. diagnosers, reconstruction hook in here (monitors: after the output scan)
            for stage in self.stages_after_memory:
                stage(self)
            # 5. functional control
            if self.observe:
                fov = self._readback
            else:
                self.control.run(image, hist, now)
                if self.mode == "manual":
                    fov = tuple(self.manual.get(name, False) for name in self.layout.outputs)
                else:
                    fov = tuple(image[s] for s in self.output_slots)
                if self._stop_mask:
                    fov = tuple(self.safe_vector[k] if k in self._stop_mask else value
                                for k, value in enumerate(fov))
            # 6. filter
            outputs, report = self.output_stage(self, fov)
            if self.observe:
                outputs = fov  # what the device has: it is observed, never driven
            elif self.latched:
                outputs = self.safe_vector
            extras["filter"] = report
        except _InputsUnknown:
            fov = outputs = self._held_outputs()
        except Exception as exc:  # never leave the plant driven by a half-computed scan
            error = f"{type(exc).__name__}: {exc}"
            self.latch_safe("internal", f"internal error at scan {self.scan}: {error}")
            fov = self.safe_vector
            outputs = self.safe_vector
            extras["traceback"] = traceback.format_exc()
        # 7. output scan
        for slot, value in zip(self.output_slots, outputs, strict=True):
            image[slot] = value
        if not self.observe:
            self._output_scan(now, outputs)
        try:
            for stage in self.stages_after_output:
                stage(self)
        except Exception as exc:  # a broken monitor must not stop the scan silently
            message = f"{type(exc).__name__}: {exc}"
            error = error or message
            self.latch_safe("internal", f"internal error at scan {self.scan}: {message}")
            extras["traceback"] = traceback.format_exc()
        try:
            self.explanations = self.explainer.build(self, extras.get("filter"))
        except Exception as exc:  # explanations must never stop the scan
            self.explanations = ()
            error = error or f"explanations: {type(exc).__name__}: {exc}"
        events = self.pending_alarm_events
        self.pending_alarm_events = []
        events.extend(self.alarm_manager.update(self.explanations, self.scan, now))
        extras["explanations"] = self.explanations
        extras["alarms"] = self.alarm_manager.listed()
        extras["alarm_events"] = tuple(events)
        for hook in self.snapshot_extras:
            hook(self, extras)
        snapshot = self._snapshot(fov, outputs, extras, error,
                                  (time.perf_counter() - wall) * 1e6)
        self.history.appendleft(image.copy())
        self.last = snapshot
        return snapshot

    def _start(self, now: int) -> None:
        self.control.reset(self.image, now)
        self.history.clear()
        for _ in range(self.history.maxlen or 1):
            self.history.append(self.image.copy())
        self.started = True

    def _input_scan(self, now: int) -> bool:
        try:
            values = self.plant.read(now)
        except PlantError as exc:
            self.latch_safe("plant", _plant_detail(exc))
            return False
        image = self.image
        for name, slot in zip(self.layout.inputs, self.input_slots, strict=True):
            image[slot] = bool(values[name])
        if self.observe:
            self._readback = tuple(bool(values[name]) for name in self.layout.outputs)
        return True

    def _held_outputs(self) -> tuple[bool, ...]:
        """Outputs of a scan whose inputs are unknown: safe; observed ones as last seen."""
        if self.observe:
            return tuple(self.image[s] for s in self.output_slots)
        return self.safe_vector

    def _output_scan(self, now: int, outputs: Sequence[bool]) -> None:
        try:
            self.plant.write(now, dict(zip(self.layout.outputs, outputs, strict=True)))
        except PlantError as exc:
            self.latch_safe("plant", _plant_detail(exc))

    def _snapshot(self, fov, outputs, extras: dict, error: str | None,
                  wall_us: float) -> Snapshot:
        plant = self.plant
        state = getattr(plant, "state", None)
        counters = getattr(plant, "counters", None)
        take_events = getattr(plant, "take_events", None)
        new_events = take_events() if take_events is not None else ()
        return Snapshot(
            scan=self.scan, time_us=self.now, period_us=self.project.scan_period_us,
            layout=self.layout, values=tuple(self.image), fov=tuple(fov),
            outputs=tuple(outputs), active_steps=self.control.active_steps(self.image),
            fired=self.control.fired,
            timer_elapsed=tuple(rt.elapsed(self.now) for rt, _, _ in self.timers),
            control=self.control_name, mode=self.mode,
            manual=tuple(sorted(self.manual.items())), policy=self.policy,
            latched=tuple(self.latched), plant=plant.status,
            plant_state=state() if state else (),
            plant_counters=counters() if counters else (),
            plant_events=new_events,
            filter=extras.get("filter"),
            diagnosers=extras.get("diagnosers", ()),
            monitors=extras.get("monitors", ()),
            reconstructed=extras.get("reconstructed", ()),
            masked=extras.get("masked", ()),
            explanations=extras.get("explanations", ()),
            alarms=extras.get("alarms", ()),
            alarm_events=extras.get("alarm_events", ()),
            stopped_devices=tuple(sorted(self.stopped_devices)),
            error=error, scan_wall_us=wall_us,
        )


def _plant_detail(exc: PlantError) -> str:
    lost = getattr(exc, "lost", True)
    return f"plant {'connection lost' if lost else 'error'}: {exc}"


class _InputsUnknown(Exception):
    """The input scan failed: skip to the output scan with the outputs safe."""


def _pass_through(engine: Engine, fov: tuple[bool, ...]):
    return fov, None


def _all_exprs(project: Project):
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

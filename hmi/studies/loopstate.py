"""The state of a closed loop (engine + simulated plant): capture, restore, and a time-free key.

The exhaustive exploration of the closed loop (hmi/studies/explore.py) needs three things the
scan itself never does:

* **capture / restore**: fork a run at an injection instant without re-running its
  fault-free prefix. Only the mutable parts are copied (the image, the history, timers, the
  GRAFCET's activation times, the diagnosers, the plant's devices); the compiled project is
  shared. A few hundred microseconds instead of rebuilding an engine.
* **key**: a hashable summary of everything that decides the loop's future, with every time
  made relative to the scan and saturated just above the largest constant it is ever
  compared with. Two states with the same key have the same future, scan for scan (the loop
  is deterministic and time-invariant: nothing reads the absolute time except through
  differences, and a difference beyond every constant it meets compares like any other).
  That is what lets the exploration stop a run the moment it reaches a state already
  explored, and prove a run periodic when its key comes back.

What the key leaves out, and why that is sound:

* absolute times, scan numbers, counters (cycles done), the plant's event log, the records
  shown to people (`via`, `since_scan`): nothing in the scan reads them to decide anything;
* the explanations and alarms: they are computed from the scan and never fed back into it
  (the exploring engine does not build them at all);
* times beyond their saturation (a step active for 5 s or for 50 s): a GRAFCET step time is
  only compared with durations (:func:`step_caps`), a diagnoser's clock only with its state's
  window bounds and timeout (:func:`state_caps`), a TON's only with its preset, the valve's
  stall time only with its tolerance;
* the position of a jammed valve: it never moves again (the sweep does not repair), so it
  matters only through the end switches it makes, which the key keeps.

Supported: engines whose stages are the filter and the diagnosers (no stopwatch monitors)
and plants made of the device models listed in `_DEVICE_KEYS`. Anything else raises
:class:`Unsupported` with what is missing, so a sweep never silently merges states it cannot
compare.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from hmi.engine.scan import Engine, EngineState
from hmi.logic.expr import Compare, Duration, Expr, StepTime, walk
from hmi.plant.sim.device import SimDevice
from hmi.plant.sim.plant import SimPlant
from hmi.plant.sim.valve import Valve
from hmi.project.model import ControlLaw, DiagnoserSpec, Project


class Unsupported(Exception):
    """The closed loop holds state this module does not know how to capture or compare."""


def step_caps(project: Project, law: ControlLaw) -> dict[str, int]:
    """Per GRAFCET step: a time past which every comparison of its activity time agrees.

    A step time is only ever compared with a duration (`X2.t >= 3s`): every value above the
    largest such constant compares the same way, so the key saturates the time one
    microsecond above it; a step whose time is never compared gets 0. A step time compared
    with anything else (another step time) is not saturated at all.
    """
    caps: dict[str, int] = {}
    unbounded: set[str] = set()
    if law.grafcet is None:
        return caps
    for expr in _expressions(project):
        for node in walk(expr.root):
            if isinstance(node, Compare):
                sides = (node.left, node.right)
                steps = [n.step for n in sides if isinstance(n, StepTime)]
                limits = [n.us for n in sides if isinstance(n, Duration)]
                if steps and len(limits) == 1:
                    for step in steps:
                        caps[step] = max(caps.get(step, 0), limits[0] + 1)
                else:
                    unbounded.update(steps)
    out: dict[str, int] = {}
    for each in law.grafcet.steps:
        if each.name not in unbounded:
            out[each.name] = caps.get(each.name, 0)
    return out


def state_caps(spec: DiagnoserSpec) -> list[int]:
    """Per diagnoser state: the time in state past which no window or timeout differs."""
    caps = {s.name: 0 for s in spec.states}
    for tr in spec.transitions:
        for value in (tr.tmin_us, tr.tmax_us, tr.after_us):
            if value is not None:
                caps[tr.source] = max(caps[tr.source], value + 1)
    return [caps[s.name] for s in spec.states]


def _expressions(project: Project) -> Iterator[Expr]:
    from hmi.engine.scan import _all_exprs
    from hmi.project.diagnosers import diagnosers_of
    yield from _all_exprs(project)
    for spec in diagnosers_of(project):
        for tr in spec.transitions:
            if tr.when is not None:
                yield tr.when
        for rule in spec.resync:
            yield rule.when


@dataclass
class LoopState:
    """A captured closed loop: enough to restore the engine and the plant exactly."""

    engine: EngineState
    plant: tuple[Any, ...]


class LoopAccess:
    """Capture, restore and key of one engine and its simulated plant."""

    def __init__(self, engine: Engine, plant: SimPlant):
        self.engine = engine
        self.plant = plant
        if engine.monitors is not None:
            raise Unsupported("stopwatch monitors are not supported by the closed-loop "
                              "exploration yet")
        for device in plant.devices:
            if type(device) not in _DEVICE_KEYS:
                raise Unsupported(f"device model {device.MODEL!r} ({device.name}) is not "
                                  "supported by the closed-loop exploration (supported: "
                                  + ", ".join(sorted(c.MODEL for c in _DEVICE_KEYS)) + ")")
            if getattr(device, "bounce", 0) and device.params["bounce_pattern"] == "each":
                raise Unsupported(f"{device.name} bounces its own way at every switch change "
                                  "(bounce_pattern: each): its loop never repeats; the "
                                  "exploration needs bounce_pattern: same")
        layout = engine.layout
        law = engine.project.controls[engine.control_name]
        caps = step_caps(engine.project, law)
        self.time_slots = tuple((slot, caps[step]) for step, slot in layout.step_times.items()
                                if step in caps)
        self.timers = engine.memory.timers
        stage = engine.diagnosis
        self.stage = stage
        self.runtimes = stage.runtimes if stage is not None else []
        self.state_caps = [state_caps(rt.spec) for rt in self.runtimes]

    # -- capture / restore (the engine's own, Engine.capture) ---------------------------------
    def capture(self) -> LoopState:
        p = self.plant
        plant = (dict(p._values), list(p._taken),
                 tuple(_copy_vars(d) for d in p.devices))
        return LoopState(self.engine.capture(), plant)

    def restore(self, state: LoopState) -> None:
        self.engine.restore(state.engine)
        p = self.plant
        values, taken, devices = state.plant
        p._values.clear()
        p._values.update(values)
        p._taken[:] = taken
        for device, saved in zip(p.devices, devices, strict=True):
            _restore_vars(device, saved)
        p.forget_writes()  # the devices' orders are the captured ones now

    # -- the key --------------------------------------------------------------------------
    def key(self) -> tuple[object, ...]:
        e = self.engine
        now = e.now
        slots = self.time_slots
        image = _image_key(e.image, slots)
        history = tuple(_image_key(h, slots) for h in e.history)
        timers = tuple((rt.q, None if rt.since is None else min(now - rt.since, rt.preset))
                       for rt, _, _ in self.timers)
        diag = tuple((rt.current, None if rt.since_us is None else
                      min(now - rt.since_us, caps[rt.current]),
                      None if rt.refined is None else rt.refined[0])
                     for rt, caps in zip(self.runtimes, self.state_caps, strict=True))
        latched = tuple(r.source for r in e.latched)
        devices = tuple(_DEVICE_KEYS[type(d)](d, now) for d in self.plant.devices)
        return (image, history, timers, diag, latched, devices)

    def region(self) -> tuple[object, ...]:
        """The plant's discrete state: its key with every continuous quantity (a position, a
        clock, an instant to come) replaced by the side it lies on of each constant it is
        compared with. Runs of one fault injected at two instants of the same scan interval
        see the same inputs at every scan and the same engine state; if they also go through
        the same regions until they meet, every instant between them does (each comparison
        is of a quantity moving linearly with the instant), which is what lets the exact
        sweep (hmi/studies/explore.py, Explorer.pieces) vouch for a whole interval."""
        now = self.engine.now
        return tuple(_DEVICE_REGIONS[type(d)](d, now) for d in self.plant.devices)


def _image_key(image: Sequence[Any], time_slots: Sequence[tuple[int, int]]
               ) -> tuple[object, ...]:
    if not time_slots:
        return tuple(image)
    values = list(image)
    for slot, cap in time_slots:
        if values[slot] > cap:
            values[slot] = cap
    return tuple(values)


_SKIP = frozenset({"name", "params", "travel", "band"})  # constant after construction


def _copy_vars(device: SimDevice) -> tuple[tuple[str, object], ...]:
    out: list[tuple[str, object]] = []
    for name, value in vars(device).items():
        if name in _SKIP:
            continue
        if isinstance(value, (list, dict, set)):
            value = value.copy()
        out.append((name, value))
    return tuple(out)


def _restore_vars(device: SimDevice, saved: tuple[tuple[str, object], ...]) -> None:
    for name, value in saved:
        if isinstance(value, (list, dict, set)):
            value = value.copy()
        setattr(device, name, value)


def _valve_key(v: Valve, now: int) -> Any:
    tolerance = v.params["stall_tolerance"]
    pending = tuple((p.code, p.at_us - now, p.duration_us) for p in v.pending)
    glitches = tuple(sorted((sensor, value, max(start - now, 0), end - now)
                            for sensor, (value, start, end) in v.glitches.items()
                            if end > now))
    where = (v.true_fsc(), v.true_fso()) if v.jammed else v.pos
    # The switches' own dynamics (delay, bounce): what they read, and what is still to come
    # out of them (bounce_pattern `same`: the patterns depend on nothing else).
    switches = (tuple(v.reading.values()), tuple((t - now, sensor, value)
                                                 for t, sensor, value in v.to_come)
                ) if v.switching else ()
    return (where, v.jammed, v.self_drive, tuple(sorted(v.armed)), glitches,
            min(v.stall_us, tolerance + 1), v.stall_reported, v.both_on, v.was_open,
            tuple(sorted(v.orders.items())), tuple(sorted(v.active_faults)), pending, switches)


def _side(value: int, mark: int) -> int:
    return (value > mark) - (value < mark)


def _valve_region(v: Valve, now: int) -> Any:
    tolerance = v.params["stall_tolerance"]
    marks = (*v._marks, v._block_point())
    where = (v.true_fsc(), v.true_fso()) if v.jammed else tuple(_side(v.pos, m) for m in marks)
    glitches = tuple(sorted((sensor, value, start <= now) for sensor, (value, start, end)
                            in v.glitches.items() if end > now))
    switches = (tuple(v.reading.values()), tuple((sensor, value) for _, sensor, value
                                                 in v.to_come)) if v.switching else ()
    return (where, v.jammed, v.self_drive, tuple(sorted(v.armed)), glitches,
            _side(v.stall_us, 0), _side(v.stall_us, tolerance), v.stall_reported, v.both_on,
            v.was_open, tuple(sorted(v.orders.items())), tuple(sorted(v.active_faults)),
            tuple(p.code for p in v.pending), switches)


# By the device's exact class: each function takes that class's devices (hence Any).
_DEVICE_KEYS: dict[type[SimDevice], Callable[[Any, int], object]] = {Valve: _valve_key}
_DEVICE_REGIONS: dict[type[SimDevice], Callable[[Any, int], object]] = {Valve: _valve_region}

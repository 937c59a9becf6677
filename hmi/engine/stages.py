"""The stages of one scan (000 Fig. 1, DESIGN.md), each a small object the engine owns.

    1 InputScan        plant -> input slots of the image
    2 Memory           timers, observers, GRAFCET step times (held in manual mode)
    3 diagnosers       hmi.engine.diagnoser.DiagnosisStage (optional)
    4 Reconstruction   filtered sensors <- the sensor or its estimate, as the diagnosers route
    5 Control          the control law -> FOV; in manual mode the operator's requests, and
                       the program waits where it is (ControlRuntime.hold / resume)
    6 filter           hmi.engine.filter_stage.FilterStage, given the diagnosers' mask
    7 OutputScan       written vector -> plant
    8 monitors         hmi.engine.monitors.MonitorStage (optional), on the I/O just exchanged

The engine (hmi.engine.scan) calls them in that order in ``Engine._cycle`` (for Engine.step
and Engine.advance) and passes each what it reads; a stage returns what it decided and never
reaches back into the engine. The protocols below are the declared interfaces: a new stage
implements one and is called from ``Engine._cycle`` at its place in the cycle
(docs/architecture.md).

Every stage works on the image (a flat list of slot values, hmi.engine.layout) and its
history (``history[0]`` the image at the end of the previous scan, and so on back).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

from hmi.engine.control import ControlRuntime
from hmi.engine.layout import Layout
from hmi.logic.expr import History, Image
from hmi.logic.timers import TimerRuntime
from hmi.plant.base import Plant, PlantError
from hmi.program.evaluate import evaluator
from hmi.program.memories import lower_observer
from hmi.program.timers import lower_timer
from hmi.project.model import Project

if TYPE_CHECKING:
    from hmi.engine.diagnoser import DiagnoserState, Diagnosis
    from hmi.engine.filter import FilterDecision
    from hmi.engine.monitors import LazyMonitors, MonitorState


# -- the declared interfaces ------------------------------------------------------------------

class DiagnoserStage(Protocol):
    """Stage 3: steps the local diagnosers on I(t) and the orders of t-1, sets their flags."""

    depth: int  # how many past images its conditions read

    def step(self, image: Image, history: History, now: int, scan: int) -> Diagnosis: ...

    def publish(self, image: Image, history: History) -> tuple[DiagnoserState, ...]: ...

    def reset(self, image: Image, history: History, now: int, scan: int) -> list[str]: ...


class FilterStageProtocol(Protocol):
    """Stage 6: the safety filter on the candidate vector, orders masked by the diagnosers."""

    def apply(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
              latched: bool, mask: tuple[bool, ...] | None) -> FilterDecision: ...


class MonitorStageProtocol(Protocol):
    """After the output scan: the stopwatch monitors on the I/O the scan exchanged."""

    depth: int

    def step(self, image: Image, history: History, now: int, scan: int) -> None: ...

    def settle(self) -> int: ...

    def capture(self, now: int) -> tuple[MonitorState, ...] | LazyMonitors: ...

    def reset(self) -> list[str]: ...


# -- the engine's own stages ------------------------------------------------------------------

class InputScan:
    """Stage 1: read the plant's inputs into the image."""

    def __init__(self, plant: Plant, layout: Layout, read_back: bool):
        self.plant = plant
        self.names = layout.inputs
        self.slots = layout.indices(layout.inputs)
        self.outputs = layout.outputs
        self.read_back = read_back  # observing: the device's own outputs are read too
        self.readback: tuple[bool, ...] = ()
        self.bindings = tuple(zip(self.names, self.slots, strict=True))

    def read(self, image: Image, now: int) -> str | None:
        """None when the inputs are in the image; else why not (the engine latches safe)."""
        if not self.read_back:
            try:
                self.plant.read_into(now, image, self.bindings)
            except PlantError as exc:
                return plant_detail(exc)
            return None
        try:
            values = self.plant.read(now)
        except PlantError as exc:
            return plant_detail(exc)
        for name, slot in zip(self.names, self.slots, strict=True):
            image[slot] = bool(values[name])
        if self.read_back:
            self.readback = tuple(bool(values[name]) for name in self.outputs)
        return None


class Memory:
    """Stage 2: timers (TON/TOF), observers, and the GRAFCET's step activity times (these
    held while the program waits in manual mode: ControlRuntime.update_times)."""

    def __init__(self, project: Project, layout: Layout, control: ControlRuntime):
        slots, times = layout.slots, layout.step_times
        # (runtime, slot, IN): the state of each timer; its rule is hmi.program.timers'
        # lowering, which this stage runs through the scan program's evaluator
        self.timers = [(TimerRuntime(t.name, t.kind, t.preset_us), slots[t.name], t.input.root)
                       for t in project.timers]
        # the timers, then the observers, as the scan program (hmi.program): the statements
        # the compiled scan prints (self.program) and this stage evaluates
        self.program = tuple(stmt for rt, slot, input_ in self.timers
                             for stmt in lower_timer(rt, slot, input_)) + tuple(
            stmt for o in project.observers for stmt in lower_observer(o, slots[o.name]))
        self._program = evaluator(self.program, slots, times)
        self.control = control

    def update(self, image: Image, history: History, now: int) -> None:
        self._program(image, history, now)
        self.control.update_times(image, now)

    def capture(self) -> tuple[tuple[bool, int | None], ...]:
        """The timers' state (observers live in the image)."""
        return tuple((rt.q, rt.since) for rt, _, _ in self.timers)

    def restore(self, state: tuple[tuple[bool, int | None], ...]) -> None:
        for (rt, _, _), (q, since) in zip(self.timers, state, strict=True):
            rt.q, rt.since = q, since

    def elapsed(self, now: int) -> tuple[int, ...]:
        """Each timer's ET, for the snapshot."""
        if not self.timers:
            return ()
        return tuple([rt.elapsed(now) for rt, _, _ in self.timers])


class Reconstruction:
    """Stage 4: each filtered sensor slot takes the value the diagnosers route to it, the
    sensor itself or its estimate (000 eq. 7-8)."""

    def apply(self, image: Image, routes: Sequence[tuple[int, int]]) -> None:
        for filtered, source in routes:
            image[filtered] = image[source]


class Control:
    """Stage 5: the functional output vector, from the control law or the manual requests."""

    def __init__(self, runtime: ControlRuntime, layout: Layout):
        self.runtime = runtime
        self.outputs = layout.outputs
        self.slots = layout.indices(layout.outputs)

    def fov(self, image: Image, history: History, now: int,
            manual: Mapping[str, bool] | None) -> tuple[bool, ...]:
        """The law's vector; in manual mode (`manual`: the operator's requests) the program
        waits: the law does not run (no transition fires, no equation is evaluated, its steps
        and memories hold; its step times were held at stage 2, ControlRuntime.hold) and the
        requests are the vector. In recovery mode the program waits too (the engine does not
        call this: the procedure's vector is used), and leaving recovery restarts it from its
        initial steps."""
        if manual is not None:
            return self.manual_fov(manual)
        self.runtime.run(image, history, now)
        return tuple(image[s] for s in self.slots)

    def manual_fov(self, manual: Mapping[str, bool]) -> tuple[bool, ...]:
        """The operator's requests as the vector (an output not requested: off)."""
        return tuple(manual.get(name, False) for name in self.outputs)


class OutputScan:
    """Stage 7: write the vector the filter decided to the plant. The engine's scan writes it
    the same way itself (Engine._output_scan, at every scan: a call less); this writes the
    safe vector when an error puts the outputs safe at once (Engine._go_safe)."""

    def __init__(self, plant: Plant, layout: Layout):
        self.plant = plant
        self.names = layout.outputs

    def write(self, now: int, outputs: Sequence[bool]) -> str | None:
        """None when written; else why not (the engine latches safe)."""
        try:
            self.plant.write_vector(now, self.names, tuple(outputs))
        except PlantError as exc:
            return plant_detail(exc)
        return None


def plant_detail(exc: PlantError) -> str:
    return f"plant {'connection lost' if exc.lost else 'error'}: {exc}"

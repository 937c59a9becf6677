"""The stages of one scan (000 Fig. 1, DESIGN.md), each a small object the engine owns.

    1 InputScan        plant -> input slots of the image
    2 Memory           timers, observers; the GRAFCET's step times (held in manual mode)
    3 diagnosers       hmi.engine.diagnoser.DiagnosisStage (optional)
    4 reconstruction   filtered sensors <- the sensor or its estimate (DiagnosisStage)
    5 control          hmi.engine.control.ControlRuntime: the control law -> FOV; in manual
                       mode the operator's requests, and the program waits where it is
                       (ControlRuntime.hold / resume); in recovery mode the procedure's
                       vector (hmi.engine.recovery.RecoveryStage)
    6 filter           hmi.engine.filter_stage.FilterStage, given the diagnosers' mask
    7 OutputScan       written vector -> plant
    8 monitors         hmi.engine.monitors.MonitorStage (optional), on the I/O just exchanged

What stages 2 to 5 and 8 do at each scan is their lowering into the scan program
(hmi.program, :attr:`program` on each: ``Memory.program``, ``DiagnosisStage.program``,
``ControlRuntime.program`` ...), which hmi.engine.compiled puts in a scan's order per mode
and runs; the stage objects hold the state and the handlers of what happens rarely (a
diagnoser's transition, a GRAFCET firing, a violation, a fault reset). The engine
(hmi.engine.scan, ``Engine._cycle``) runs stage 1, the mode's program, the filter and the
output scan, and passes each what it reads; a stage returns what it decided and never
reaches back into the engine. The protocols below are the declared interfaces of the
handlers the engine calls (docs/architecture.md: adding a stage).

Every stage works on the image (a flat list of slot values, hmi.engine.layout) and its
history (``history[0]`` the image at the end of the previous scan, and so on back).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from hmi.engine.codegen import Vocabulary
from hmi.engine.layout import Layout
from hmi.logic.expr import History, Image
from hmi.logic.timers import TimerRuntime
from hmi.plant.base import Plant, PlantError
from hmi.program import order
from hmi.program.ir import Function, Local, Stmt, Value
from hmi.program.memories import lower_observer
from hmi.program.timers import lower_timer
from hmi.project.model import Project

if TYPE_CHECKING:
    from hmi.engine.diagnoser import DiagnoserState, Diagnosis
    from hmi.engine.filter import FilterDecision
    from hmi.engine.monitors import LazyMonitors, MonitorState


# -- the declared interfaces ------------------------------------------------------------------

class ProgramStage(Protocol):
    """A stage of the mode's program (hmi.program.order.PROGRAM): its lowering, by the parts
    of the scan it runs at, and the names its printed statements use (the compiled scan's
    allow-list, hmi.engine.codegen). Every stage of the program is declared once
    (hmi.engine.program_stages), the engine builds them from their declarations; the scan
    program puts their parts in order (hmi.engine.compiled)."""

    PRINTED: Vocabulary  # (a class attribute)

    @property
    def parts(self) -> Mapping[str, tuple[Stmt, ...]]: ...


class DiagnoserStage(Protocol):
    """Stage 3: steps the local diagnosers on I(t) and the orders of t-1, sets their flags."""

    depth: int  # how many past images its conditions read
    program: tuple[Stmt, ...]  # stage 3 at a scan (hmi.program.diagnosers)
    reconstruction: tuple[Stmt, ...]  # stage 4
    current: Diagnosis  # the routes, mask and records as the last scan left them

    def publish(self, image: Image, history: History) -> tuple[DiagnoserState, ...]: ...

    def reset(self, image: Image, history: History, now: int, scan: int) -> list[str]: ...


class FilterStageProtocol(Protocol):
    """Stage 6: the safety filter on the candidate vector, orders masked by the diagnosers.
    Its lowering is its own (`functions`, built by the compiled scan and handed back by
    `bind`); the engine's part calls `decide`, the printed frame `question` and then, when
    that is not quiet, `unmasked` (nothing masked nor latched) or `apply`."""

    @property
    def functions(self) -> Mapping[str, Function]: ...

    def bind(self, built: Mapping[str, Callable[..., Any]]) -> None: ...

    def question(self, image: Value, history: Value, candidate: Value, local: Local
                 ) -> tuple[Stmt, Value]: ...

    def decide(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
               latched: bool, mask: tuple[bool, ...] | None, recovering: bool
               ) -> FilterDecision: ...

    # (nothing masked: the image, history, candidate, policy, latch and the candidate's
    # violation word, or None)
    unmasked: Callable[..., FilterDecision]

    def apply(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
              latched: bool, mask: tuple[bool, ...] | None) -> FilterDecision: ...


class MonitorStageProtocol(Protocol):
    """After the output scan: the stopwatch monitors on the I/O the scan exchanged."""

    depth: int
    program: tuple[Stmt, ...]  # the automata at a scan (hmi.program.monitors)

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
    """Stage 2: timers (TON/TOF) and observers (the GRAFCET's step times are its runtime's,
    hmi.engine.grafcet). The rules are hmi.program's lowerings (:attr:`program`, the scan
    program's part the compiled scan prints); this object holds the timers' state."""

    # a timer's state, and the TON's locals (hmi.program.timers)
    PRINTED = Vocabulary(frozenset({"since", "q"}), frozenset({"s", "q"}))

    def __init__(self, project: Project, layout: Layout):
        slots = layout.slots
        # (runtime, slot, IN): the state of each timer
        self.timers = [(TimerRuntime(t.name, t.kind, t.preset_us), slots[t.name], t.input.root)
                       for t in project.timers]
        # the timers, then the observers, as the scan program (hmi.program)
        self.program = tuple(stmt for rt, slot, input_ in self.timers
                             for stmt in lower_timer(rt, slot, input_)) + tuple(
            stmt for o in project.observers for stmt in lower_observer(o, slots[o.name]))

    @property
    def parts(self) -> dict[str, tuple[Stmt, ...]]:
        return {order.MEMORY: self.program}

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


class OutputScan:
    """Stage 7: write the vector the filter decided to the plant. The engine's scan writes it
    the same way itself (Engine._scan_outputs, at every scan: a call less); this writes the
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

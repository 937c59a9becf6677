"""The stages of the mode's program, declared once: the one list a stage joins.

A stage of the mode's program is its lowering (``hmi/program/<stage>.py``: its rules as the
scan program's statements, its rare events as calls of its handler) and its handler (the
object holding its state and those methods, ``hmi/engine/<stage>.py``). Each is declared by
a :class:`Declaration` (:func:`stage_declarations`: :data:`BUILT_IN`, then those of
:data:`ADDED`): its role (the name the engine and the PLC export
address it by), how it is built from the project and the engine's choices, where it runs
(the built-in stages' parts are hmi.program.order's own; an added stage's ``PLACE`` puts its
part after one of them), how deep a history it reads, what a fault reset does to it, how its
state is captured and restored (an exploration forking the engine: Engine.capture), what
it gives every scan with news (its snapshot field, compared to say whether a scan has news:
:class:`Publication`) and what else a snapshot reads of it (:class:`Shown`). Everything else
derives from the declarations:

* the engine builds every declared stage (``Engine.__init__``, :func:`build_stages`), in
  this order, each given those built before it; the compiled scan puts each stage's parts
  in the scan's order (:func:`hmi.program.order.placed`), in every mode's function, printed
  and evaluated, and allows their names (``PRINTED``); the history is as deep as the
  deepest stage; a fault reset, Engine.capture/restore, the end of a scan
  (Engine._conclude: each publication read, news judged on them), the printed frame's
  quiet test (each publication's, printed) and the snapshot walk the declarations;
* the PLC export builds the same stages from the same declarations, each stage's function
  blocks (hmi.export.stage_blocks, keyed by role, an added stage's by class), and the PLC
  program calls them at the stage's place (hmi.export.program_pou).

Besides the stages of the mode's program, the filter (:data:`FILTER`: its part of the scan
the engine runs itself, between the program and the output scan) and the monitors
(:data:`MONITORS`: their statements at the part after the output scan, a function of the
scan program of its own) are declared the same way: what they publish and show is read by
the same walks, with no branch of their own in the engine or its printed frame.

The engine addresses a built-in stage by its role where it needs that one (the diagnosers'
mask for the filter, a recovery procedure in place of the law, the filter its part runs,
the monitors a recovery abandons): :meth:`Stages.of`.

A stage added beyond the built-in ones (:class:`AddedStage`) declares all of that on its own
class; naming the class in :data:`ADDED` declares it (:func:`declared`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, ClassVar, Generic, NamedTuple, Protocol, TypeVar, cast

from hmi.engine.codegen import Vocabulary
from hmi.engine.control import ControlRuntime
from hmi.engine.diagnoser import DiagnosisStage, diagnosis_stage
from hmi.engine.filter import SafetyFilter, Solver
from hmi.engine.filter_stage import FilterStage
from hmi.engine.grafcet import GrafcetRuntime
from hmi.engine.layout import Layout
from hmi.engine.monitors import MonitorStage, monitor_stage
from hmi.engine.recovery import NO_RECOVERY, RecoveryStage, recovery_stage
from hmi.engine.snapshot import StageState
from hmi.engine.stages import Memory, ProgramStage
from hmi.logic.expr import History, Image
from hmi.program import ir, order
from hmi.project.model import ControlLaw, Project

S = TypeVar("S")


@dataclass(frozen=True)
class StageContext:
    """What a stage is built from: the project, its layout, the control law that runs and
    the engine's choices, and the stages declared before it, by role (filled as they are
    built: :func:`build_stages`)."""

    project: Project
    layout: Layout
    law: ControlLaw
    safe_vector: tuple[bool, ...]
    solver: Solver  # the corrector
    diagnosis: str = "ftc"  # the diagnosers' mode
    high_level: bool = True  # the High Level Diagnoser's rules
    built: dict[str, Any] = field(default_factory=dict)


class Moment(NamedTuple):
    """The engine between scans, as a fault reset hands it to a stage."""

    image: Image
    history: History
    now: int
    scan: int
    started: bool  # a scan ran (before it, nothing has a state to reset)


class Handed(NamedTuple):
    """What the printed frame hands a publication's quiet test (Publication.quiet): its
    locals holding the scan's hand-overs, as scan-program values."""

    diagnosis: ir.Value  # the diagnosers' decision of the scan (Diagnosis)
    report: ir.Value  # the filter's report of the scan (FilterReport)


@dataclass(frozen=True)
class Publication(Generic[S]):
    """What a stage gives every scan with news, for its snapshot field: read at the end of
    the scan (Engine._conclude), the very same object again while nothing changed. A scan is
    quiet for the stage (no news) only when it gives the object the last scan with news
    gave; the printed frame, which concludes a quiet scan without calling `read`, asks
    `quiet` once, when it is printed (hmi.engine.compiled.auto_frame)."""

    field: str  # the Snapshot field it fills
    # (the stage, the image as the scan left it, the history without it yet, the scan's time)
    read: Callable[[S, Image, History, int], Any]
    reading: str  # what failed, in plain words, when `read` raises (snapshot.INTERNAL_PARTS)
    # what the snapshot shows then, given the stage (also when the stage's own part of the
    # scan raised: Engine._conclude does not read it then)
    failed: Callable[[S], Any]
    # Given the stage and the frame's hand-overs (Handed): the test that says the scan is
    # not quiet for the stage (None: it always is, but for what it gives) and the value
    # `read` gives at a quiet scan (None: the test alone says, and at a quiet scan the stage
    # gives what it gave the last scan with news), both as scan-program values (the scan's
    # time: ir.Now)
    quiet: Callable[[S, Handed], tuple[ir.Value | None, ir.Value | None]]
    # The value `quiet` gives is a read that may raise, made at every scan (no cheaper test
    # says the scan is quiet: the monitors' marks): the printed frame makes it once, guarded
    # as Engine._conclude's read, into a local
    guarded: bool = False


@dataclass(frozen=True)
class Shown(Generic[S]):
    """What a snapshot shows of a stage besides its publication, read when the snapshot is
    built (Engine.snapshot): never news."""

    fields: tuple[str, ...]  # the Snapshot fields it fills
    read: Callable[[S, Image, int], tuple[Any, ...]]  # (the stage, the image, the scan's time)
    reading: str  # what failed, in plain words, when `read` raises (snapshot.INTERNAL_PARTS)
    failed: Callable[[S], tuple[Any, ...]]  # what the snapshot shows then


@dataclass(frozen=True)
class Declaration(Generic[S]):
    """A stage of the mode's program (see the module docstring). Every hook is optional: a
    stage without one has nothing of that kind."""

    role: str
    build: Callable[[StageContext], S | None]  # (None: the project has nothing for it)
    # (its part, the part of hmi.program.order it runs right after); None: the stage's parts
    # are hmi.program.order.PROGRAM's own
    place: tuple[str, str] | None = None
    depth: Callable[[S], int] | None = None  # how many past images its statements read
    # a fault reset: what it did, in plain words (Engine.fault_reset)
    reset: Callable[[S, Moment], list[str]] | None = None
    capture: Callable[[S], Any] | None = None  # its state, copied (Engine.capture)
    restore: Callable[[S, Any], None] | None = None
    shown: Callable[[S], Any] | None = None  # what a snapshot shows of it (Snapshot.stages)
    news: Publication[S] | None = None  # what it gives a scan with news (Engine._conclude)
    fields: Shown[S] | None = None  # what a snapshot reads of it besides (Engine.snapshot)
    # its scan program's functions of its own, outside the mode's program, by name (the
    # filter's questions), and what takes the compiled scan's form of them: the compiled
    # scan builds each in its form (printed or evaluated) and hands them over
    functions: Callable[[S], Mapping[str, ir.Function]] | None = None
    bind: Callable[[S, Mapping[str, Any]], None] | None = None


class AddedStage(ProgramStage, Protocol):
    """A stage added to the mode's program beyond the built-in ones: its handler, declaring
    on its class where it runs and how it is built, and holding the methods a fault reset,
    an exploration's capture/restore and the snapshot call (see the module docstring)."""

    # (its part of the scan, the part of hmi.program.order it runs right after)
    PLACE: ClassVar[tuple[str, str]]
    depth: int  # how many past images its statements read

    @classmethod
    def build(cls, project: Project, layout: Layout) -> AddedStage | None:
        """The stage for `project` (None: the project has nothing for it to do)."""
        ...

    def reset(self, moment: Moment) -> list[str]:
        """A fault reset: what it reset, in plain words ([]: nothing)."""
        ...

    def capture(self) -> Any:
        """Its state, copied: :meth:`restore` continues exactly from there."""
        ...

    def restore(self, state: Any) -> None: ...

    def state(self) -> Any:
        """What a snapshot shows of it: a plain scalar (a bool, int, float or str: immutable,
        as the snapshot outlives the scan, and what hmi.wire carries for a value typed Any to
        a screen)."""
        ...


def declared(kind: type[AddedStage]) -> Declaration[AddedStage]:
    """The declaration of an added stage: all of it read from its class."""
    return Declaration(
        kind.PLACE[0], lambda c: kind.build(c.project, c.layout), place=kind.PLACE,
        depth=lambda s: s.depth, reset=lambda s, m: s.reset(m), capture=lambda s: s.capture(),
        restore=lambda s, state: s.restore(state), shown=lambda s: s.state())


# -- the built-in stages ----------------------------------------------------------------------

def _reset_diagnosers(stage: DiagnosisStage, m: Moment) -> list[str]:
    return stage.reset(m.image, m.history, m.now, m.scan) if m.started else []


def _recovery(c: StageContext) -> RecoveryStage | None:
    # a procedure's own filter is given the diagnosers' mask, as the cell's filter is
    diagnosers = cast("DiagnosisStage | None", c.built.get(DIAGNOSERS.role))
    return recovery_stage(c.project, c.layout, c.safe_vector, c.solver,
                          diagnosers.mask_flags if diagnosers is not None else {})


def _elapsed(memory: Memory, image: Image, now: int) -> tuple[Any, ...]:
    return (memory.elapsed(now),)


def _no_elapsed(memory: Memory) -> tuple[Any, ...]:
    return ((0,) * len(memory.timers),)


def _steps(law: ControlRuntime, image: Image, now: int) -> tuple[Any, ...]:
    grafcet = law.grafcet
    return ((), ()) if grafcet is None else (grafcet.active(image), grafcet.fired)


def _no_steps(law: ControlRuntime) -> tuple[Any, ...]:
    return ((), law.grafcet.fired if law.grafcet is not None else ())


def _diagnosers(stage: DiagnosisStage, image: Image, history: History, now: int) -> Any:
    # (DiagnosisStage.publish: the records themselves unless one is faulty)
    return stage.publish(image, history) if stage.faulty else stage.current.records


def _diagnosers_quiet(stage: DiagnosisStage, handed: Handed
                      ) -> tuple[ir.Value | None, ir.Value | None]:
    # faulty: DiagnosisStage.publish previews what a fault reset would do (Diagnosis.records)
    return ir.Cell(stage, "faulty"), ir.Field(handed.diagnosis, "records")


class Supervision:
    """The GRAFCET's steps' supervision times as a stage: no part of the mode's program; at
    the end of a scan past its deadline (a step's supervision time, or a firing:
    hmi.engine.grafcet) the overdue steps are found again, one comparison a scan otherwise.
    A change of them is news (an alarm raised or cleared: Snapshot.overdue_steps). The
    engine says when they are watched (Engine._supervise: the program running in automatic
    mode)."""

    PRINTED = Vocabulary(frozenset({"deadline"}))
    parts: Mapping[str, tuple[ir.Stmt, ...]] = {}

    def __init__(self, grafcet: GrafcetRuntime):
        self.grafcet = grafcet


def _supervision(c: StageContext) -> Supervision | None:
    law = cast("ControlRuntime | None", c.built.get(LAW.role))
    grafcet = law.grafcet if law is not None else None
    return Supervision(grafcet) if grafcet is not None and grafcet.supervision else None


def _overdue(stage: Supervision, image: Image, history: History, now: int) -> Any:
    grafcet = stage.grafcet
    if now > grafcet.deadline:
        grafcet.watch(now)  # (the overdue steps keep their identity while unchanged)
    return grafcet.overdue


def _overdue_quiet(stage: Supervision, handed: Handed
                   ) -> tuple[ir.Value | None, ir.Value | None]:
    # (before the deadline, the overdue steps are those the last watch found)
    return ir.Compare(">", ir.Now(), ir.Cell(stage.grafcet, "deadline")), None


def _recovery_state(stage: RecoveryStage, image: Image, history: History, now: int) -> Any:
    # (RecoveryStage.state: the idle state itself when none runs nor is needed)
    return stage._idle if stage.active is None and not stage.needed else stage.state(now)


def _recovery_quiet(stage: RecoveryStage, handed: Handed
                    ) -> tuple[ir.Value | None, ir.Value | None]:
    return (ir.Or((ir.Cell(stage, "needed"), ir.Not(ir.IsNone(ir.Cell(stage, "active"))))),
            ir.Cell(stage, "_idle"))


def _filter(c: StageContext) -> FilterStage:
    # the cell's filter, given the diagnosers' mask, and the recovery procedures (whose
    # running one's filter takes its place in recovery mode)
    diagnosers = cast("DiagnosisStage | None", c.built.get(DIAGNOSERS.role))
    return FilterStage(SafetyFilter(c.project, c.layout.slots, c.layout.step_times, *c.solver),
                       diagnosers.mask_flags if diagnosers is not None else {},
                       diagnosers.masking if diagnosers is not None else (),
                       cast("RecoveryStage | None", c.built.get(RECOVERY.role)))


def _report(stage: FilterStage, image: Image, history: History, now: int) -> Any:
    return stage.report


def _report_quiet(stage: FilterStage, handed: Handed
                  ) -> tuple[ir.Value | None, ir.Value | None]:
    # (the clean candidate's report, or the decision's: the frame's local)
    return None, handed.report


def _marks(stage: MonitorStage, image: Image, history: History, now: int) -> Any:
    return stage.settle()


def _marks_quiet(stage: MonitorStage, handed: Handed
                 ) -> tuple[ir.Value | None, ir.Value | None]:
    # (the marks move at any scan a task's automaton changes: settled at every scan)
    return None, ir.Call(stage, "settle", ())


def _monitor_states(stage: MonitorStage, image: Image, now: int) -> tuple[Any, ...]:
    # (the bases change only in a scan or a command, which builds the snapshot first)
    return (stage.capture(now),)


def _no_capture(stage: MonitorStage) -> Any:
    raise NotImplementedError("an engine with stopwatch monitors cannot be captured")


MEMORY: Declaration[Memory] = Declaration(
    "memory", lambda c: Memory(c.project, c.layout),
    capture=Memory.capture, restore=Memory.restore,
    fields=Shown(("timer_elapsed",), _elapsed, "computing the timers' elapsed times",
                 _no_elapsed))
DIAGNOSERS: Declaration[DiagnosisStage] = Declaration(
    "diagnosers", lambda c: diagnosis_stage(c.project, c.layout, c.diagnosis, c.high_level),
    depth=lambda s: s.depth, reset=_reset_diagnosers, capture=DiagnosisStage.capture,
    restore=DiagnosisStage.restore,
    news=Publication("diagnosers", _diagnosers, "reading the diagnosers' states",
                     lambda s: (), _diagnosers_quiet))
LAW: Declaration[ControlRuntime] = Declaration(
    "law", lambda c: ControlRuntime(c.law, c.layout.slots, c.layout.step_times),
    capture=ControlRuntime.capture, restore=ControlRuntime.restore,
    fields=Shown(("active_steps", "fired"), _steps, "reading the active steps", _no_steps))
SUPERVISION: Declaration[Supervision] = Declaration(
    "supervision", _supervision,
    news=Publication("overdue_steps", _overdue, "watching the steps' supervision times",
                     lambda s: (), _overdue_quiet))
RECOVERY: Declaration[RecoveryStage] = Declaration(
    "recovery", _recovery, capture=RecoveryStage.capture, restore=RecoveryStage.restore,
    news=Publication("recovery", _recovery_state, "reading the recovery's state",
                     lambda s: NO_RECOVERY, _recovery_quiet))
FILTER: Declaration[FilterStage] = Declaration(
    "filter", _filter, functions=lambda s: s.functions, bind=FilterStage.bind,
    news=Publication("filter_report", _report, "reading the filter's report", lambda s: None,
                     _report_quiet))
MONITORS: Declaration[MonitorStage] = Declaration(
    "monitors", lambda c: monitor_stage(c.project, c.layout),
    depth=lambda s: s.depth, reset=lambda s, m: s.reset(), capture=_no_capture,
    news=Publication("monitor_marks", _marks, "settling the monitors", lambda s: s.marks,
                     _marks_quiet, guarded=True),
    fields=Shown(("monitors",), _monitor_states, "reading the monitors' states",
                 lambda s: ((),)))

# The built-in stages, in the scan's order (the order they are built in: a stage is given
# those before it)
BUILT_IN: tuple[Declaration[Any], ...] = (MEMORY, DIAGNOSERS, LAW, SUPERVISION, RECOVERY,
                                          FILTER, MONITORS)

# The added stages, in the order they are placed (several after one part: in this order):
# each its class (declared()), or a declaration of its own (one with `news`: its state
# makes a scan news)
ADDED: tuple[type[AddedStage] | Declaration[Any], ...] = ()


def stage_declarations() -> tuple[Declaration[Any], ...]:
    """Every declared stage: the built-in ones, then the added ones (ADDED, read at each
    call)."""
    return (*BUILT_IN, *(kind if isinstance(kind, Declaration) else declared(kind)
                         for kind in ADDED))


class Stages:
    """The declared stages one engine (or one export) built, in declaration order: those a
    project has nothing for are left out."""

    def __init__(self, built: Sequence[tuple[Declaration[Any], Any]]):
        self.built = tuple(built)
        self._by_role = {d.role: stage for d, stage in self.built}

    def of(self, declaration: Declaration[S]) -> S | None:
        """The stage built for `declaration`'s role (None: the project has none)."""
        return cast("S | None", self._by_role.get(declaration.role))

    def need(self, declaration: Declaration[S]) -> S:
        """The stage built for a role every project has."""
        stage = self.of(declaration)
        if stage is None:
            raise ValueError(f"no {declaration.role} stage was built")
        return stage

    def __iter__(self) -> Iterator[tuple[Declaration[Any], Any]]:
        return iter(self.built)

    @property
    def program(self) -> tuple[ProgramStage, ...]:
        """The stages whose parts are hmi.program.order.PROGRAM's own."""
        return tuple(stage for d, stage in self.built if d.place is None)

    @property
    def added(self) -> tuple[AddedStage, ...]:
        """The stages that declare their own place (hmi.program.order.placed)."""
        return tuple(stage for d, stage in self.built if d.place is not None)

    @property
    def places(self) -> list[tuple[str, str]]:
        return [d.place for d, _ in self.built if d.place is not None]

    @property
    def publishing(self) -> tuple[tuple[Publication[Any], Any], ...]:
        """The stages that publish something at a scan with news, with what they publish,
        in declaration order."""
        return tuple((d.news, stage) for d, stage in self.built if d.news is not None)

    @property
    def showing(self) -> tuple[tuple[Shown[Any], Any], ...]:
        """The stages a snapshot reads something of besides, with what it reads."""
        return tuple((d.fields, stage) for d, stage in self.built if d.fields is not None)

    @property
    def functions(self) -> tuple[tuple[Mapping[str, ir.Function],
                                       Callable[[Mapping[str, Any]], None]], ...]:
        """The stages' scan-program functions of their own (their declarations'
        `functions`), each stage's by name, with what takes the compiled form of them."""
        return tuple((d.functions(stage), partial(d.bind, stage)) for d, stage in self.built
                     if d.functions is not None and d.bind is not None)

    @property
    def depth(self) -> int:
        """The deepest history any stage's statements read."""
        return max((d.depth(stage) for d, stage in self.built if d.depth is not None),
                   default=0)

    def reset(self, moment: Moment) -> list[str]:
        """A fault reset of every stage that has one: what each did, in order."""
        done: list[str] = []
        for d, stage in self.built:
            if d.reset is not None:
                done.extend(d.reset(stage, moment))
        return done

    def capture(self) -> tuple[Any, ...]:
        """Each stage's state (None for a stage that has none to capture)."""
        return tuple(d.capture(stage) if d.capture is not None else None
                     for d, stage in self.built)

    def restore(self, states: Sequence[Any]) -> None:
        for (d, stage), state in zip(self.built, states, strict=True):
            if d.restore is not None:
                d.restore(stage, state)

    def shown(self) -> tuple[StageState, ...]:
        """What a snapshot shows of the stages that show something, by role."""
        return tuple(StageState(d.role, d.shown(stage)) for d, stage in self.built
                     if d.shown is not None)


def build_stages(context: StageContext,
                 declarations: Sequence[Declaration[Any]] | None = None) -> Stages:
    """Every declared stage (or those of `declarations`) `context`'s project has, built in
    order."""
    built = []
    for declaration in stage_declarations() if declarations is None else declarations:
        stage = declaration.build(context)
        if stage is not None:
            context.built[declaration.role] = stage
            built.append((declaration, stage))
    return Stages(built)


def program_order(added: Sequence[AddedStage]) -> tuple[str, ...]:
    """The parts of the mode's program with the added stages' (hmi.program.order.PROGRAM,
    each added part right after the part it declares)."""
    return order.placed(order.PROGRAM, [stage.PLACE for stage in added])

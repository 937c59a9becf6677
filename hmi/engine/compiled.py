"""The scan program of one engine, per mode, and the two forms that run it.

Each stage lowers its rules once into the scan program's statements (hmi.program: timers and
observers, the diagnosers and the reconstruction, which recovery procedures the cell needs,
the GRAFCET and the equations, the running recovery procedure, the constraints' test, the
stopwatch monitors); :class:`ScanProgram` puts them in the order of a scan for each mode,
as functions (hmi.program.ir.Function):

* ``core(v, h, now, scan)``, automatic mode: stage 2 (timers, observers, step times), stage
  3 (the diagnosers), stage 4 (reconstruction), which recovery procedures the cell needs,
  and stage 5 (GRAFCET evolution, continuous actions, equations); it returns the functional
  output vector;
* ``held(v, h, now, scan)``, manual mode, where the program waits: the same without the
  step times and without stage 5 (the engine takes the operator's requests);
* ``observed(v, h, now, scan)``, observing a read-only device: stages 2-4 with the step
  times, no stage 5 (the device's own outputs are the vector);
* ``recovery_<k>(v, h, now, scan)``, recovery mode with procedure k running: stages 2-4
  without the step times (the program waits, as in manual mode), then the procedure's
  step, whose vector it returns;
* ``monitors(v, h, now, scan)``: the part after the output scan (the stopwatch monitors);
* a stage's functions of its own (its declaration's ``functions``: the filter stage's
  ``violated(v, h, f)``, the constraints the candidate `f` violates as a word, stage 6's
  first question, 0 on most scans; ``decide(v, h, f, w, p, latched)``, the policy applied to
  that word, calling the filter's handler when it has something to decide; and
  ``active_bits(v, h)``, the corrector's memory key; the PLC's filter block prints the same
  lowerings, hmi.export.filter_pou), each handed back to its stage.

:class:`CompiledScan` holds one form of them: the Python printed from the statements
(hmi.engine.codegen: slot indices, integer constants and a fixed set of operators, never
text of a project file), what every engine runs, or the closures of the program's evaluator
(hmi.program.evaluate), the reference ``Engine(..., compiled=False)`` runs and the tests
compare with (tests/test_compiled_scan.py). Both work on the stage objects' own state (a
timer's ``since``, a diagnoser's ``current``, a GRAFCET's activation times) and hand every
rare event to the stage's own handler: a diagnoser's transition to ``take``, a GRAFCET
firing to ``fire``, a violation to the filter itself. Functions a mode needs are built the
first time it does (an engine that never enters manual mode never generates ``held``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from hmi.engine.codegen import Vocabulary, allow, build_function
from hmi.engine.diagnoser import NO_DIAGNOSIS
from hmi.engine.program_stages import AddedStage, Handed, program_order
from hmi.engine.scan_record import EVENTS, STATUS, Raised
from hmi.logic.expr import History, Image
from hmi.plant.base import PlantError
from hmi.program import ir, order
from hmi.program.evaluate import function_evaluator

if TYPE_CHECKING:
    from hmi.engine.layout import Layout
    from hmi.engine.recovery import RecoveryStage
    from hmi.engine.stages import ProgramStage

CoreFn = Callable[[Image, History, int, int], tuple[bool, ...]]
HeldFn = Callable[[Image, History, int, int], None]
MonitorFn = Callable[[Image, History, int, int], None]
# a stage's functions of its own (hmi.engine.program_stages.Stages.functions): by name, and
# what takes the compiled form of them
StageFunctions = tuple[Mapping[str, ir.Function], Callable[[Mapping[str, Any]], None]]

SCAN = ("v", "h", "now", "scan")


class ScanProgram:
    """An engine's scan program per mode, assembled from its stages' lowerings (see the
    module docstring)."""

    def __init__(self, layout: Layout, stages: Sequence[ProgramStage],
                 recovery: RecoveryStage | None, added: Sequence[AddedStage] = ()):
        self.outputs = layout.outputs
        # the parts of the mode's program in order: hmi.program.order's, with each added
        # stage's where it declares (hmi.engine.program_stages)
        self.order = program_order(added)
        # each part's statements (the stages' in the order given), walked in that order;
        # and those of the part after the output scan, a function of its own
        self.parts: dict[str, tuple[ir.Stmt, ...]] = dict.fromkeys(
            (*self.order, order.MONITORS), ())
        for stage in (*stages, *added):
            for part, stmts in stage.parts.items():
                if part not in self.parts:
                    raise ValueError(f"{type(stage).__name__}: {part!r} is not a part of the "
                                     "mode's program (hmi.program.order.PROGRAM, or an "
                                     "added stage's PLACE) nor the part after the output "
                                     "scan (hmi.program.order.MONITORS)")
                self.parts[part] += stmts
        self._fov = ir.Tuple(tuple(ir.Slot(s) for s in layout.indices(layout.outputs)))
        self._recovery = recovery

    def walk(self, without: tuple[str, ...] = (), law: tuple[ir.Stmt, ...] | None = None
             ) -> tuple[ir.Stmt, ...]:
        """The parts of the mode's program in order, but those `without`, the law replaced by
        `law` when given."""
        body: tuple[ir.Stmt, ...] = ()
        for part in self.order:
            if part not in without:
                body += law if part == order.LAW and law is not None else self.parts[part]
        return body

    def core(self) -> ir.Function:
        return ir.Function("core", SCAN, self.walk(), self._fov)

    def held(self) -> ir.Function:
        """The program waits: neither its step times nor its law."""
        return ir.Function("held", SCAN, self.walk((order.STEP_TIMES, order.LAW)))

    def observed(self) -> ir.Function:
        """A read-only device's own outputs are the vector: no law."""
        return ir.Function("observed", SCAN, self.walk((order.LAW,)))

    def recovery(self, name: str) -> ir.Function:
        """Recovery mode while procedure `name` is the one started."""
        stage = self._recovery
        assert stage is not None
        number = list(stage.procedures).index(name)
        return ir.Function(f"recovery_{number}", SCAN,
                           self.walk((order.STEP_TIMES,), stage.procedures[name].program),
                           ir.Local("f"))

    def monitors(self) -> ir.Function | None:
        """The part after the output scan, on the I/O just exchanged (None: no stage has
        statements there)."""
        body = self.parts[order.MONITORS]
        return ir.Function("monitors", SCAN, body) if body else None


class CompiledScan:
    """One form of an engine's scan program (see the module docstring): `python` the printed
    Python, else the evaluator's closures."""

    def __init__(self, layout: Layout, stages: Sequence[ProgramStage],
                 recovery: RecoveryStage | None, label: str, python: bool = True,
                 added: Sequence[AddedStage] = (), functions: Sequence[StageFunctions] = ()):
        self.slots = layout.slots
        self.times = layout.step_times
        self.label = label
        self.python = python
        self.program = ScanProgram(layout, stages, recovery, added)
        # what the printed code may name: every stage's names (their PRINTED), the frame's
        self.vocabulary = FRAME.union(*(stage.PRINTED for stage in (*stages, *added)))
        if python:
            allow(self.vocabulary)
        self.sources: list[str] = []  # every printed function's text, in build order
        self.core: CoreFn = self._form(self.program.core())
        monitor = self.program.monitors()
        self.monitors: MonitorFn | None = self._form(monitor) if monitor is not None else None
        # the stages' functions of their own (the filter's questions), in this form, by
        # name, each handed to its stage
        self.functions: dict[str, Any] = {}
        for declared, bind in functions:
            built = {name: self._form(function) for name, function in declared.items()}
            self.functions.update(built)
            bind(built)
        self._held: HeldFn | None = None
        self._observed: HeldFn | None = None
        self._recoveries: dict[str, CoreFn] = {}

    def _form(self, function: ir.Function) -> Any:
        if not self.python:
            return function_evaluator(function, self.slots, self.times)
        fn = build_function(function, self.slots, self.times, self.label)
        self.sources.append(fn.__doc__ or "")
        return fn

    @property
    def held(self) -> HeldFn:
        """Manual mode's (see the module docstring), built at the first call."""
        fn = self._held
        if fn is None:
            fn = self._held = self._form(self.program.held())
        return fn

    @property
    def observed(self) -> HeldFn:
        """Observing a read-only device (see the module docstring), built at the first
        call."""
        fn = self._observed
        if fn is None:
            fn = self._observed = self._form(self.program.observed())
        return fn

    def recovery(self, name: str) -> CoreFn:
        """Recovery mode with procedure `name` started, built at its first scan."""
        fn = self._recoveries.get(name)
        if fn is None:
            fn = self._recoveries[name] = self._form(self.program.recovery(name))
        return fn

    def frame(self, engine: Any) -> Callable[[int], bool]:
        """The automatic mode's scan (auto_frame), in this form."""
        # (each publication's field: ScanNews's, and a guarded one's local)
        publishing = engine.stages.publishing
        fields = Vocabulary(frozenset(news.field for news, _ in publishing),
                            frozenset(news.field for news, _ in publishing if news.guarded))
        self.vocabulary = self.vocabulary.union(fields)
        if self.python:
            allow(fields)
        fn: Callable[[int], bool] = self._form(auto_frame(engine))
        return fn


# What the frame (auto_frame) names: its locals, and what it reads or calls on the engine, its
# plant, its scan record and the diagnosers' decision (what a stage's publication reads of
# it is the stage's PRINTED; a guarded publication's local is named after its field:
# CompiledScan.frame)
FRAME = Vocabulary(
    frozenset({"_pending", "scan", "now", "latched", "clean_report", "_news",
               "_auto_lost", "_auto_failed", "_auto_filter", "_write_error",
               "_monitors_error", "_finish", "_conclude", "read_into", "write_vector",
               "take_events", "status", "core", "monitors", "appendleft", "fov",
               "outputs", "diagnosis", "monitored", "error", "filter_us", "values", "events",
               "published", "scan_us", "settled", "manual", "current", "mask",
               "reconstructed"}),
    frozenset({"exc", "diag", "report", "error", "monitored", "events", "status",
               "last", "values", "w", "none_waiting", "out", "run_core", "run_violated",
               "run_monitors"}))


def auto_frame(engine: Any) -> ir.Function:
    """``auto(now) -> news``: `engine`'s (hmi.engine.scan.Engine, not imported: it imports
    this module) Engine.run scan in automatic mode, once started, with no
    device stopped and no wall time measured (most scans of a run), written out: stage 1,
    the mode's program (``core``), the constraints' test (the filter's decision when the
    candidate violates a constraint, nothing masked nor latched: Engine._auto_filter), the
    output scan and the monitors, then what Engine._conclude does for a quiet scan (nothing
    masked nor latched, no error, no plant event, no supervision due, no diagnoser faulty,
    no recovery needed, nothing changed since the last scan with news but what moves by
    itself: a remembered correction is the very same report). Whatever is
    not such a scan goes on where Engine._cycle and Engine._conclude go on, through
    the engine's own methods, from the point reached: the same scan, in both paths."""
    e, plant, scan_program = engine, engine.plant, engine.compiled
    image, history = ir.Ref(engine.image), ir.Ref(engine.history)
    now, scan = ir.Local("now"), ir.Local("scan")
    f, diag, report, error = (ir.Local(n) for n in ("f", "diag", "report", "error"))
    events, status, values = ir.Local("events"), ir.Local("status"), ir.Local("values")
    out = ir.Local("out")
    calm = ir.Local("none_waiting")
    monitored, exc, unquiet = ir.Local("monitored"), ir.Local("exc"), ir.Local("w")
    # (the compiled scan's functions, read at each scan: whoever replaces one is called)
    core, violated, monitor = (ir.Local(n) for n in ("run_core", "run_violated",
                                                      "run_monitors"))
    stage = engine.diagnosis
    filter_stage = engine.filter_stage  # (its part of the scan: order.FILTER)
    record = engine._record

    def cell(owner: Any, name: str) -> ir.Cell:
        return ir.Cell(owner, name)

    def call(owner: Any, method: str, *args: ir.Value) -> ir.Call:
        return ir.Call(owner, method, args)

    def raised(part: str) -> ir.Call:  # (Engine._conclude's `raised`: this read raised exc)
        return call(Raised, "__call__", ir.Ref(part), exc)

    def conclude(*stmts: ir.Stmt) -> tuple[ir.Stmt, ...]:
        return (*stmts, ir.Return(call(e, "_conclude", now)))

    finish = ir.Return(call(e, "_finish", now, f, out, report, diag, monitored, error))
    body: list[ir.Stmt] = [
        ir.Assign(cell(e, "_pending"), ir.FALSE),  # (the last scan's snapshot: dropped)
        ir.Assign(scan, ir.Add(cell(e, "scan"), ir.Const(1))),
        ir.Assign(cell(e, "scan"), scan),
        ir.Assign(cell(e, "now"), now),
        ir.Assign(diag, cell(stage, "current") if stage is not None else ir.Ref(NO_DIAGNOSIS)),
    ]
    # Stages 2-6's statements, under one guard (an exception there: _auto_failed)
    guarded: list[ir.Stmt] = []

    def inputs() -> None:  # 1. input scan
        body.append(ir.Try(
            (ir.Do(call(plant, "read_into", now, image, ir.Ref(engine._bindings))),),
            ((PlantError, "exc", conclude(ir.Do(call(e, "_auto_lost", now, exc)))),
             (Exception, "exc", conclude(ir.Do(call(e, "_auto_failed", now, exc, diag)))))))

    def program() -> None:  # 2-5, the mode's program
        guarded.append(ir.Assign(core, cell(scan_program, "core")))
        guarded.append(ir.Assign(f, ir.Apply(core, (image, history, now, scan))))
        if stage is not None:
            guarded.append(ir.Assign(diag, cell(stage, "current")))

    def filter_() -> None:  # 6: the filter stage's first question; its handler if not quiet
        # masked, latched, or else the violation word: not quiet unless 0 (the filter is
        # handed the word, which it does not compute again, when nothing is masked nor
        # latched)
        read, word = filter_stage.question(image, history, f, violated)
        guarded.append(read)
        guarded.append(ir.Assign(unquiet, ir.Or((
            ir.Not(ir.IsNone(ir.Field(diag, "mask"))), cell(e, "latched"), word))))
        body.append(ir.Try(tuple(guarded), ((Exception, "exc", conclude(
            ir.Do(call(e, "_auto_failed", now, exc, diag)))),)))
        # the filter's decision when it is not the candidate (what it writes: `out`); it
        # concludes the scan itself unless that goes on as a clean candidate's would
        body.append(ir.If(unquiet, (
            ir.Assign(report, call(e, "_auto_filter", now, f, diag, unquiet)),
            ir.If(ir.IsNone(report), (ir.Return(call(e, "_conclude", now)),)),
            ir.Assign(out, cell(record, "outputs"))),
            (ir.Assign(out, f), ir.Assign(report, cell(e, "clean_report")))))
        body.append(ir.Assign(error, ir.NONE))

    def outputs() -> None:  # 7. output scan (and whether the plant says no event waits)
        body.append(ir.Try(
            (ir.Assign(calm, call(plant, "write_vector", now,
                                  ir.Ref(engine.output_scan.names), out)),),
            ((Exception, "exc", (ir.Assign(calm, ir.FALSE),
                                 ir.Assign(error, call(e, "_write_error", now, out, error,
                                                       exc)))),)))

    def monitors_() -> None:  # 8. the part after the output scan (the monitors)
        if scan_program.monitors is None:  # (no stage has statements there)
            body.append(ir.Assign(monitored, ir.FALSE))
            return
        body.extend((
            ir.Assign(monitored, ir.TRUE),
            ir.Try((ir.Assign(monitor, cell(scan_program, "monitors")),
                    ir.Do(ir.Apply(monitor, (image, history, now, scan)))),
                   ((Exception, "exc", (ir.Assign(monitored, ir.FALSE),
                                        ir.Assign(error, call(e, "_monitors_error", now, error,
                                                              exc)))),))))

    # the parts in the order hmi.program.order declares (as Engine._cycle walks them)
    parts: dict[str, Callable[[], None]] = {
        order.INPUTS: inputs, order.MODE_PROGRAM: program, order.FILTER: filter_,
        order.OUTPUTS: outputs, order.MONITORS: monitors_}
    for part in order.ENGINE:
        parts[part]()
    # what Engine._conclude would find other than a quiet scan's: its own way
    body.append(ir.If(ir.Not(ir.IsNone(error)), (finish,)))
    # each publishing stage's (its declaration's `news`): whether the scan is not quiet for
    # it, and what it gives at a quiet scan (a guarded one read here, once: its local)
    publishing = engine.stages.publishing
    quiet = [news.quiet(stage_, Handed(diag, report)) for news, stage_ in publishing]
    for unquiet_, _ in quiet:
        if unquiet_ is not None:
            body.append(ir.If(unquiet_, (finish,)))
    given: list[ir.Value | None] = []
    for (news, _), (_, value) in zip(publishing, quiet, strict=True):
        if news.guarded and value is not None:
            local = ir.Local(news.field)
            body.append(ir.Try((ir.Assign(local, value),), ((Exception, "exc", (ir.Return(
                call(e, "_finish", now, f, out, report, diag, monitored, error, ir.NONE,
                     raised(news.reading))),)),)))
            value = local
        given.append(value)
    taken = ir.Return(call(e, "_finish", now, f, out, report, diag, monitored, error, events))
    # the plant's events, unless the write said none waits (Plant.write_vector), its status
    body += [
        ir.If(calm, (ir.Assign(events, ir.Const(())),), (
            ir.Try((ir.Assign(events, call(plant, "take_events")),),
                   ((Exception, "exc", (ir.Return(call(e, "_finish", now, f, out, report, diag,
                                                       monitored, error, ir.NONE,
                                                       raised(EVENTS))),)),)),
            ir.If(events, (taken,)))),
        ir.Try((ir.Assign(status, cell(plant, "status")),),
               ((Exception, "exc", (ir.Return(call(e, "_finish", now, f, out, report, diag,
                                                   monitored, error, events,
                                                   raised(STATUS))),)),)),
    ]
    # news: as Engine._conclude judges it (ScanNews: the plant's status, then each stage's,
    # by its field; Engine._unmatched after a command: no scan's)
    last = ir.Local("last")
    body += [
        ir.Assign(last, cell(e, "_news")),
        ir.If(ir.Or((ir.Field(diag, "reconstructed"), cell(e, "manual"))), (taken,)),
        ir.If(ir.Not(ir.And((
            ir.Compare("is", status, ir.Field(last, "status")),
            *(ir.Compare("is", value, ir.Field(last, news.field))
              for (news, _), value in zip(publishing, given, strict=True)
              if value is not None)))), (taken,)),
        # a quiet scan: the image into the history, the record
        ir.Assign(values, call(tuple, "__call__", image)),
        ir.Do(call(engine.history, "appendleft", values)),
    ]
    zero = ir.Ref(0.0)
    fields: tuple[tuple[str, ir.Value], ...] = (
        ("diagnosis", diag), ("monitored", monitored), ("error", ir.NONE),
        ("filter_us", zero),
        ("published", ir.Tuple(tuple(ir.Field(last, news.field) if value is None else value
                                     for (news, _), value in zip(publishing, given,
                                                                 strict=True)))),
        ("events", ir.Const(())), ("scan_us", zero))
    moving = (ir.Assign(cell(record, "fov"), f), ir.Assign(cell(record, "outputs"), out),
              ir.Assign(cell(record, "values"), values))
    body += [
        ir.If(cell(record, "settled"), moving,
              (*moving, *(ir.Assign(cell(record, name), value) for name, value in fields),
               ir.Assign(cell(record, "settled"), ir.TRUE))),
        ir.Assign(cell(e, "_pending"), ir.TRUE),
        ir.Return(ir.FALSE),
    ]
    return ir.Function("auto", ("now",), tuple(body))

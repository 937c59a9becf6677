"""A proof, with z3, that one call of an exported stopwatch monitor FB, as blark parses it,
does what the scan program (hmi.program, the reference) does, for every input and every state
the monitor can be in.

The program's side is the monitor's lowering itself (``MonitorStage.programs[k]``, the
statements hmi.program.evaluate runs), executed symbolically here (:class:`IrSymbolic`): the
automaton's cells start as z3 values made from the FB's state (the correspondence below), the
task's conditions (``Test`` nodes: the project's expressions) read the FB's inputs, and the two
handlers the lowering calls are stated from hmi.engine.stopwatch (``TaskAutomaton.detect``:
the attempt's fault, counted, latched with its evidence unless a fault is latched;
``Watchdog.trip``: disarmed). The FB's side is tests/st_prove.py's executor on blark's tree.

The correspondence, FB variable = program state: Phase = phase (0 waiting, 1 executing,
2 interrupted); X, Y, LastUs, AttemptStart = x_us, y_us, last_us, attempt_start_us in ms
(times are whole milliseconds: the program's clock is a TIME); AttemptFaultNone = attempt_fault
is None, AttemptFault = its time; Attempt, Faults, Completed = the counts; Armed = the
watchdog's _armed; Fault = a latched detection, Rule/FaultX/FaultY = its rule, x, y (compared
while Fault holds: the evidence of a released fault is not a value of the cell); Location =
3 when Fault, else Phase (MonitorState.location). The state invariant is 0 <= Phase <= 2
(the program's phase is one of three objects); a call keeps it. The fault-reset call (Reset)
is compared with ``TaskAutomaton.reset``: the label released unless the attempt that failed
still runs, nothing else changed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import z3

from hmi.logic import expr as ex
from hmi.program import ir
from tests.st_prove import (
    KeptRuns,
    Proof,
    Symbolic,
    Unsupported,
    _concrete,
    _ite,
    _parsed,
    _valid,
    built_blocks,
    in_bounds,
    keeping,
    kept,
    parse_changed,
    parse_fb,
    pou_text,
)


@dataclass(frozen=True)
class Opt:
    """A value that may be None (the program's ``attempt_fault``, ``latched``): `none`, and
    the fields that matter when it is not."""

    none: Any
    fields: tuple[Any, ...] = ()


NONE = Opt(z3.BoolVal(True))


@dataclass(frozen=True)
class Members:
    """A tuple of small integers the program grows (the GRAFCET's fireable transitions):
    whether each one is in it."""

    flags: tuple[tuple[int, Any], ...] = ()

    def has(self, k: int) -> Any:
        return dict(self.flags).get(k, z3.BoolVal(False))

    def any(self) -> Any:
        return z3.Or(False, *[f for _, f in self.flags])


def _truth(value: Any) -> Any:
    """A value tested by an If (a tuple is true when not empty)."""
    return value.any() if isinstance(value, Members) else value


def _merge_value(cond: Any, a: Any, b: Any) -> Any:
    if isinstance(a, Members) or isinstance(b, Members):
        keys = sorted({k for k, _ in (*a.flags, *b.flags)})
        return Members(tuple((k, _ite(cond, a.has(k), b.has(k))) for k in keys))
    if isinstance(a, Opt) or isinstance(b, Opt):
        a = a if isinstance(a, Opt) else Opt(z3.BoolVal(False), (a,))
        b = b if isinstance(b, Opt) else Opt(z3.BoolVal(False), (b,))
        width = max(len(a.fields), len(b.fields))
        fa = (*a.fields, *[z3.IntVal(0)] * (width - len(a.fields)))
        fb = (*b.fields, *[z3.IntVal(0)] * (width - len(b.fields)))
        return Opt(_ite(cond, a.none, b.none),
                   tuple(_ite(cond, x, y) for x, y in zip(fa, fb, strict=True)))
    return _ite(cond, a, b)


Handler = Callable[["IrSymbolic", list[Any]], Any]  # (its value: a call in a test)


class IrSymbolic:
    """The scan program's statements run on z3 values: `cells` by (id(owner), attr), the
    conditions' reads through `read(name, depth)`, `codes` the objects compared by identity
    (a phase) as integers, `handlers` the calls by (id(owner), method), `ignored` the cells
    that only mark the snapshot (written, never read back by the program)."""

    def __init__(self, cells: dict[tuple[int, Any], Any], read: Callable[[str, int], Any],
                 now: Any, codes: dict[int, int], handlers: dict[tuple[int, str], Handler],
                 ignored: set[tuple[int, Any]], image: dict[int, Any] | None = None,
                 slots: dict[str, int] | None = None, scan: Any = None,
                 step_times: dict[str, int] | None = None):
        # (the image: its slots by index, the values of this scan; `slots` names them;
        # `scan`: the scan's number, when something compares it)
        self.scan = z3.IntVal(0) if scan is None else scan
        self.step_times = step_times or {}  # a step's name -> its time's slot
        self.cells = dict(cells)
        self.image = dict(image or {})
        self.slots = slots or {}
        self.env: dict[str, Any] = {}
        self.read, self.now, self.codes = read, now, codes
        self.handlers, self.ignored = handlers, ignored

    def run(self, stmts: tuple[ir.Stmt, ...]) -> None:
        for s in stmts:
            self.stmt(s)

    def stmt(self, s: ir.Stmt) -> None:
        if isinstance(s, ir.If):
            cond = _truth(self.value(s.test))
            known = _concrete(cond)
            if known is not None:
                self.run(s.then if known else s.orelse)
                return
            self.branch(cond, lambda: self.run(s.then), lambda: self.run(s.orelse))
            return
        if isinstance(s, ir.Switch):
            self._switch(self.number(s.value), list(s.cases), s.default)
            return
        if isinstance(s, ir.Do):
            self.call(s.call)
            return
        if isinstance(s, ir.Assign):
            target = s.target
            if isinstance(target, ir.Item) and isinstance(target.base, ir.Ref) \
                    and (id(target.base.obj), target.index) in self.ignored:
                return
            if isinstance(target, ir.Cell) and (id(target.owner), target.attr) in self.ignored:
                return
            value = self.value(s.value)
            if isinstance(target, ir.Local):
                self.env[target.name] = value
            elif isinstance(target, ir.Item) and isinstance(target.base, ir.Ref):
                key = (id(target.base.obj), target.index)
                if key not in self.cells:
                    raise Unsupported("an item with no counterpart")
                self.cells[key] = value
            elif isinstance(target, ir.Slot):
                if target.index not in self.image:
                    raise Unsupported(f"slot {target.index} with no counterpart")
                self.image[target.index] = value
            elif isinstance(target, ir.Cell):
                key = (id(target.owner), target.attr)
                if key not in self.cells:
                    raise Unsupported(f"a cell {target.attr} with no counterpart")
                self.cells[key] = value
            else:
                raise Unsupported(f"an assignment to {type(target).__name__}")
            return
        raise Unsupported(f"statement {type(s).__name__}")

    def branch(self, cond: Any, then: Callable[[], Any], orelse: Callable[[], Any]) -> None:
        """Both worlds of `cond` run, then merged (a local set on one side only is read only
        on that side)."""
        cells, env, image = dict(self.cells), dict(self.env), dict(self.image)
        then()
        yes = (self.cells, self.env, self.image)
        self.cells, self.env, self.image = cells, env, image
        orelse()
        self.cells = {k: _merge_value(cond, yes[0][k], v) for k, v in self.cells.items()}
        self.image = {k: _merge_value(cond, yes[2][k], v) for k, v in self.image.items()}
        self.env = {k: _merge_value(cond, yes[1][k], self.env[k])
                    if k in yes[1] and k in self.env else yes[1].get(k, self.env.get(k))
                    for k in {*yes[1], *self.env}}

    def _switch(self, chosen: Any, cases: list[tuple[int, tuple[ir.Stmt, ...]]],
                default: tuple[ir.Stmt, ...]) -> None:
        if not cases:
            self.run(default)
            return
        (n, body), rest = cases[0], cases[1:]
        test = chosen == n
        known = _concrete(test)
        if known is not None:
            self.run(body) if known else self._switch(chosen, rest, default)
            return
        self.branch(test, lambda: self.run(body), lambda: self._switch(chosen, rest, default))

    def call(self, call: ir.Call) -> Any:
        """A handler's call: its value (what it returns), its effects on the cells."""
        handler = self.handlers.get((id(call.owner), call.method))
        if handler is None:
            raise Unsupported(f"a call of {call.method}")
        return handler(self, [self.value(a) for a in call.args])

    def _guarded(self, cond: Any, operand: ir.Value) -> Any:
        """`operand` evaluated only where `cond` holds (Python's `and`/`or` stop early: a
        call after them runs only then); its value where it ran, False elsewhere."""
        found: list[Any] = []
        self.branch(cond, lambda: found.append(self.value(operand)), lambda: None)
        return z3.And(cond, found[0])

    def _short(self, operands: tuple[ir.Value, ...], conj: bool) -> Any:
        if not any(isinstance(o, ir.Call) for o in operands[1:]):
            values = [self.value(o) for o in operands]
            return z3.And(*values) if conj else z3.Or(*values)
        so_far = self.value(operands[0])
        for o in operands[1:]:
            if conj:
                so_far = self._guarded(so_far, o)
            else:
                so_far = z3.Or(so_far, self._guarded(z3.Not(so_far), o))
        return so_far

    def value(self, v: ir.Value) -> Any:
        match v:
            case ir.Call():
                return self.call(v)
            case ir.TheImage() | ir.TheHistory():
                return None  # (a handler's argument: the handlers here read their own)
            case ir.Test(node=node):
                return self.expression(node)
            case ir.Now():
                return self.now
            case ir.ScanNumber():
                return self.scan
            case ir.Const(value=None):
                return NONE
            case ir.Const(value=bool() as b):
                return z3.BoolVal(b)
            case ir.Const(value=int() as n):
                return z3.IntVal(n)
            case ir.Const(value=tuple() as items):
                return Members(tuple((k, z3.BoolVal(True)) for k in items))
            case ir.Add(left=a, right=ir.Const(value=tuple() as items)):
                grown = self.value(a)
                assert isinstance(grown, Members)
                return Members(tuple(sorted({**dict(grown.flags),
                                             **{k: z3.BoolVal(True) for k in items}}.items())))
            case ir.Item(base=ir.Ref(obj=obj), index=index) if (id(obj), index) in self.cells:
                return self.cells[(id(obj), index)]
            case ir.Ref(obj=obj) if id(obj) in self.codes:
                return z3.IntVal(self.codes[id(obj)])
            case ir.Local(name=name):
                return self.env[name]
            case ir.Slot(index=index) if index in self.image:
                return self.image[index]
            case ir.Cell(owner=owner, attr=attr):
                key = (id(owner), attr)
                if key in self.ignored or key not in self.cells:
                    raise Unsupported(f"a read of the cell {attr}")
                return self.cells[key]
            case ir.Add(left=a, right=b):
                return self.number(a) + self.number(b)
            case ir.Sub(left=a, right=b):
                return self.number(a) - self.number(b)
            case ir.Compare(op=op, left=a, right=b):
                x, y = self.number(a), self.number(b)
                return {"==": lambda: x == y, "is": lambda: x == y, "!=": lambda: x != y,
                        "<": lambda: x < y, "<=": lambda: x <= y, ">": lambda: x > y,
                        ">=": lambda: x >= y}[op]()
            case ir.IsNone(operand=operand):
                found = self.value(operand)
                return found.none if isinstance(found, Opt) else z3.BoolVal(False)
            case ir.Not(operand=operand):
                return z3.Not(self.value(operand))
            case ir.And(operands=operands):
                return self._short(operands, True)
            case ir.Or(operands=operands):
                return self._short(operands, False)
        raise Unsupported(f"value {type(v).__name__}")

    def number(self, v: ir.Value) -> Any:
        """A value in arithmetic: a maybe-None one is its value (Python would stop on None:
        the program reads it only where it is set)."""
        found = self.value(v)
        if isinstance(found, Opt):
            return found.fields[0] if found.fields else z3.IntVal(0)
        return found

    def expression(self, node: ex.Node) -> Any:
        """A project expression (hmi.logic.expr) on the FB's inputs."""
        match node:
            case ex.Const(value=value):
                return z3.BoolVal(bool(value))
            case ex.Var(name=name, depth=0) if self.slots.get(name) in self.image:
                return self.image[self.slots[name]]  # (this scan's value so far)
            case ex.Var(name=name, depth=depth):
                return self.read(name, depth)
            case ex.Not(operand=operand):
                return z3.Not(self.expression(operand))
            case ex.And(operands=operands):
                return z3.And(*[self.expression(o) for o in operands])
            case ex.Or(operands=operands):
                return z3.Or(*[self.expression(o) for o in operands])
            case ex.StepTime(step=step) if step in self.step_times:
                return self.image[self.step_times[step]]
            case ex.Duration(us=us):
                return z3.IntVal(us)
            case ex.Compare(left=left, op=op, right=right):
                x, y = self.expression(left), self.expression(right)
                return {"==": lambda: x == y, "!=": lambda: x != y, "<": lambda: x < y,
                        "<=": lambda: x <= y, ">": lambda: x > y, ">=": lambda: x >= y}[op]()
        raise Unsupported(f"expression {type(node).__name__}")


MS = 1000  # µs per ms: the program's times are the FB's, in µs


def _executed(text: str, block: Any, tamper: Callable[[str], str] | None
              ) -> tuple[Symbolic, dict[str, Any]]:
    """The exported block's ST (tampered with, when a test asks), run symbolically once."""
    fb_text = pou_text(text, block.pou.name)
    if tamper is None:
        sym = Symbolic(parse_fb(fb_text))
    else:
        sym = Symbolic(parse_changed(fb_text, tamper(fb_text)))
        if keeping():  # (a study: the original's blocks, run once, reused)
            sym.runs = kept(block, ("runs", fb_text), lambda: _recorded(fb_text))
    sym.obligations = []
    return sym, sym.run()


def _recorded(fb_text: str) -> KeptRuns:
    """The blocks of one run of the block as exported, kept for its mutants' runs."""
    sym = Symbolic(_parsed(fb_text))  # (the tree parse_changed shares its nodes with)
    sym.obligations = []
    sym.runs = KeptRuns()
    sym.run()
    sym.runs.recording = False
    return sym.runs


def prove_monitor(project: Any, text: str, task: str,
                  tamper: Callable[[str], str] | None = None, at_once: bool = False
                  ) -> list[Proof]:
    """The exported monitor FB of `task` (in `text`, `tamper`ed if given) against the scan
    program's lowering of that task: a list of proved (or refuted) properties."""
    from hmi.engine.stopwatch import Phase
    from hmi.export.stopwatch_pou import PHASES
    calls = [(args, block) for args, block
             in built_blocks(project, "build_monitor", "hmi.export.stage_blocks")
             if args[2].name == task]
    ((stage, k, _spec, *_rest), block), = calls
    automaton = stage.automata[k]
    sym, out = _executed(text, block, tamper)
    st = sym.initial

    def v(name: str) -> Any:
        return st[name.upper()]

    def read(name: str, depth: int) -> Any:
        return st[block.inputs[(name, depth)].upper()]

    a, w = automaton, automaton.watchdog
    cells = {
        (id(a), "phase"): v("Phase"), (id(a), "x_us"): MS * v("X"),
        (id(a), "y_us"): MS * v("Y"), (id(a), "last_us"): MS * v("LastUs"),
        (id(a), "attempt"): v("Attempt"), (id(a), "attempt_start_us"): MS * v("AttemptStart"),
        (id(a), "attempt_fault"): Opt(v("AttemptFaultNone"), (MS * v("AttemptFault"),)),
        (id(a), "completed"): v("Completed"), (id(a), "faults"): v("Faults"),
        (id(a), "latched"): Opt(z3.Not(v("Fault")),
                                (v("Rule"), MS * v("FaultX"), MS * v("FaultY"))),
        (id(w), "_armed"): v("Armed"),
    }

    def detect(run: IrSymbolic, args: list[Any]) -> None:
        """TaskAutomaton.detect: the attempt's fault, counted; latched (rule, x, y) unless a
        fault is latched already."""
        verdict, now, _scan = args
        c = run.cells
        c[(id(a), "attempt_fault")] = Opt(z3.BoolVal(False), (now,))
        c[(id(a), "faults")] = c[(id(a), "faults")] + 1
        latched = c[(id(a), "latched")]
        mine = Opt(z3.BoolVal(False), (verdict, c[(id(a), "x_us")], c[(id(a), "y_us")]))
        c[(id(a), "latched")] = _merge_value(latched.none, mine, latched)

    def trip(run: IrSymbolic, args: list[Any]) -> None:
        """Watchdog.trip: disarmed (the trip's record is the engine's yardstick)."""
        run.cells[(id(w), "_armed")] = z3.BoolVal(False)

    program = IrSymbolic(cells, read, MS * v("Now"),
                         {id(p): code for p, code in PHASES.items()},
                         {(id(a), "detect"): detect, (id(w), "trip"): trip},
                         {(id(a), "changes"), (id(stage.dirty), k)})
    program.run(stage.programs[k])
    after = program.cells
    assert Phase.IDLE in PHASES
    invariant = z3.And(v("Phase") >= 0, v("Phase") <= 2)

    def o(name: str) -> Any:
        return out[name.upper()]

    reset, fault = v("Reset"), out["FAULT"]
    latched = after[(id(a), "latched")]
    scan = {
        "the task's phase": o("Phase") == after[(id(a), "phase")],
        "the stopwatch x": MS * o("X") == after[(id(a), "x_us")],
        "the stopwatch y": MS * o("Y") == after[(id(a), "y_us")],
        "the time of the last scan": MS * o("LastUs") == after[(id(a), "last_us")],
        "the attempt and its start": z3.And(
            o("Attempt") == after[(id(a), "attempt")],
            MS * o("AttemptStart") == after[(id(a), "attempt_start_us")]),
        "the attempt's fault": z3.And(
            o("AttemptFaultNone") == after[(id(a), "attempt_fault")].none,
            z3.Implies(z3.Not(o("AttemptFaultNone")),
                       MS * o("AttemptFault") == after[(id(a), "attempt_fault")].fields[0])),
        "the counts of faults and completed attempts": z3.And(
            o("Faults") == after[(id(a), "faults")],
            o("Completed") == after[(id(a), "completed")]),
        "the watchdog armed": o("Armed") == after[(id(w), "_armed")],
        "the fault label and its evidence (rule, x, y)": z3.And(
            fault == z3.Not(latched.none),
            z3.Implies(fault, z3.And(o("Rule") == latched.fields[0],
                                     MS * o("FaultX") == latched.fields[1],
                                     MS * o("FaultY") == latched.fields[2]))),
    }
    kept = [n for n in ("Phase", "X", "Y", "LastUs", "Attempt", "AttemptStart",
                        "AttemptFaultNone", "AttemptFault", "Faults", "Completed", "Armed")]
    released = z3.And(v("Fault"), z3.Not(z3.And(v("Phase") != 0,
                                                  z3.Not(v("AttemptFaultNone")))))
    properties = {
        **{f"a scan: {name}": z3.Implies(z3.Not(reset), p) for name, p in scan.items()},
        "a fault reset: the label released unless the attempt that failed still runs":
            z3.Implies(reset, z3.And(fault == z3.And(v("Fault"), z3.Not(released)),
                                     z3.Implies(fault, z3.And(o("Rule") == v("Rule"),
                                                              o("FaultX") == v("FaultX"),
                                                              o("FaultY") == v("FaultY"))))),
        "a fault reset changes nothing else": z3.Implies(
            reset, z3.And(*[o(n) == v(n) for n in kept])),
        "the location: faulty while the label holds, else the phase":
            o("Location") == z3.If(fault, 3, o("Phase")),
        "a call keeps the state invariant (0 <= Phase <= 2)":
            z3.And(o("Phase") >= 0, o("Phase") <= 2),
    }
    return _proofs(properties, invariant, sym, out, at_once)



def _case(sym: Symbolic, out: dict[str, Any]) -> Any:
    from tests.st_prove import Case
    return Case((), sym, out)


def prove_memory(project: Any, text: str, tamper: Callable[[str], str] | None = None,
                 at_once: bool = False) -> list[Proof]:
    """The exported memory FB (timers and observers) against the scan program's memory
    stage (hmi.engine.stages.Memory.program: hmi.program.timers, hmi.program.memories), for
    every input and every state: each output, and each timer's state (q; since, or none)."""
    from hmi.engine.layout import Layout
    from hmi.engine.stages import Memory
    from hmi.project.diagnosers import layout_names
    # (the memory stage's block: hmi.export.stage_blocks builds it)
    ((args, block),) = built_blocks(project, "build_memory", "hmi.export.stage_blocks")
    if block is None:
        return []  # (no timer, no observer: no memory block)
    layout = args[2]
    assert isinstance(layout, Layout)
    assert layout == Layout.build(project, project.control(None), extra=layout_names(project))
    memory = Memory(project, layout)
    sym, out = _executed(text, block, tamper)
    st = sym.initial

    def read(name: str, depth: int) -> Any:
        if depth == 0 and name in block.outputs:
            return st[block.outputs[name].upper()]
        return st[block.inputs[(name, depth)].upper()]

    slots = dict(layout.slots)
    # the image as this stage finds it: what it writes (kept by the FB), what it reads now
    image = {slots[name]: st[ident.upper()] for name, ident in block.outputs.items()}
    image.update({slots[name]: st[ident.upper()] for (name, depth), ident in block.inputs.items()
                  if depth == 0 and name in slots})
    cells: dict[tuple[int, Any], Any] = {}
    names: dict[str, tuple[Any, str]] = {}
    for runtime, _slot, _input in memory.timers:
        prefix = runtime.name.upper()
        cells[(id(runtime), "since")] = Opt(st[f"{prefix}_NONE"], (MS * st[f"{prefix}_SINCE"],))
        cells[(id(runtime), "q")] = st[f"{prefix}_Q"]
        names[runtime.name] = (runtime, prefix)
    program = IrSymbolic(cells, read, MS * st["NOW"], {}, {}, set(), image, slots)
    program.run(memory.program)
    properties = {}
    for name, ident in block.outputs.items():
        properties[f"{name}: the value written"] = out[ident.upper()] == program.image[slots[name]]
    for name, (runtime, prefix) in names.items():
        since = program.cells[(id(runtime), "since")]
        properties[f"timer {name}: its state (q, since)"] = z3.And(
            out[f"{prefix}_Q"] == program.cells[(id(runtime), "q")],
            out[f"{prefix}_NONE"] == since.none,
            z3.Implies(z3.Not(since.none), MS * out[f"{prefix}_SINCE"] == since.fields[0]))
    return _proofs(properties, z3.BoolVal(True), sym, out, at_once)


MODE_CODES = {"observe": 1, "off": 2}  # (hmi.export.diagnoser_pou: any other value is FTC)


def prove_diagnoser(project: Any, text: str, name: str,
                    tamper: Callable[[str], str] | None = None, at_once: bool = False
                    ) -> list[Proof]:
    """The exported diagnoser FB of `name` (in `text`, `tamper`ed if given) against the scan
    program's lowering of that diagnoser in each mode (hmi.program.diagnosers: the gap test,
    the current state's transitions, the High Level Diagnoser's refinement, the settling and
    the reconstruction), with the handlers stated from hmi.engine.diagnoser; the fault-reset
    call against DiagnosisStage.reset. For every input and every state where the block's
    constants (Gap, Period) hold their values and State names a state (a call keeps both).

    The correspondence, FB variable = program state (the stage restricted to this diagnoser,
    as the export lowers it): State = current; Since/SinceNone = since_us (ms, None);
    Dirty = the stage's dirty (or a change of Mode: the block's own, the engine's mode is
    fixed); LastScan/LastScanNone = last_scan; LastNow = last_now; Scan + 1 = the scan's
    number (the block counts its calls); Refined/RefinedTo = the High Level Diagnoser's
    refinement (the label's number from 1), Armed = hld_armed; the flag, filtered and label
    outputs = the image's flag and filtered slots and the record's labels, which keep their
    values until the stage settles. Mode: 1 observe, 2 off, any other value FTC; off never
    sets a flag (the engine's off stage never writes them: they keep their initial 0), so
    the block's settling in off writes 0."""
    from hmi.program.diagnosers import lower_diagnosis, lower_reconstruction, shift_outputs
    calls = [(args, block) for args, block in
             built_blocks(project, "build_diagnoser", "hmi.export.stage_blocks")
             if args[0].runtimes[args[1]].spec.name == name]
    ((stage, k, layout, *_rest), block), = calls
    rt = stage.runtimes[k]
    spec = rt.spec
    hld = tuple(h for h in project.high_level if h.diagnoser == spec.name)
    outputs = frozenset(layout.outputs)
    slots = dict(layout.slots)
    sym, out = _executed(text, block, tamper)
    st = sym.initial
    up: dict[str, str] = {key: ident.upper() for key, ident in block.ports.items()}

    def v(key: str) -> Any:
        return st[key.upper()]

    def o(key: str) -> Any:
        return out[key.upper()]

    def read(name: str, depth: int) -> Any:
        # (the lowering reads an output one scan back; the block's input is the output as
        # written in the project, wired one scan back by the program)
        return st[block.inputs[(name, depth - (name in outputs))].upper()]

    sensors = [(slots[p.filtered], slots[p.sensor], slots[p.estimate], slots[p.flag])
               for p in spec.partitions if p.sensor and p.estimate and p.filtered]
    flag_idents = {slots[p]: ident.upper() for p, ident in block.outputs.items()}
    image = {slot: st[ident] for slot, ident in flag_idents.items()}
    for _f, sensor, estimate, _flag in sensors:
        for slot in (sensor, estimate):
            image[slot] = st[block.inputs[(layout.names[slot], 0)].upper()]
    numbers = {lab: n for n, lab in enumerate(spec.labels, start=1)}
    faulty_states = [n for n, s in enumerate(spec.states) if s.faulty]
    mode = v("Mode")
    in_mode = {"observe": mode == 1, "off": mode == 2,
               "ftc": z3.And(mode != 1, mode != 2)}
    DIRTY, LAST, LAST_NOW, GAP = ((id(stage), a) for a in ("dirty", "last_scan", "last_now",
                                                           "gap_us"))
    ARMED, SINCE, CURRENT = (id(stage), "hld_armed"), (id(rt), "since_us"), (id(rt), "current")
    REFINED = (id(rt), "refined")
    label_cells = {lab: (id(rt), f"label {lab}") for lab in spec.labels}
    FAULTY = (id(rt), "faulty")

    def one_of(value: Any, states: list[int]) -> Any:
        return z3.Or(False, *[value == n for n in states])

    def enter(run: IrSymbolic, target: Any, now: Any) -> None:
        """DiagnoserRuntime.enter: the target state, entered now, its refinement dropped."""
        run.cells[CURRENT] = target
        run.cells[SINCE] = Opt(z3.BoolVal(False), (now,))
        run.cells[REFINED] = NONE

    def begin(run: IrSymbolic, args: list[Any]) -> None:
        """DiagnoserRuntime.begin: the time in the initial state counts from now."""
        run.cells[SINCE] = Opt(z3.BoolVal(False), (args[0],))

    def take(run: IrSymbolic, args: list[Any]) -> None:
        """DiagnoserRuntime.take: transition k's target entered now."""
        number, now, _scan = args
        enter(run, z3.IntVal(rt.index[spec.transitions[_concrete(number)].target]), now)

    def lost_sight(run: IrSymbolic, args: list[Any]) -> Any:
        """DiagnosisStage.lost_sight: a faulty state keeps its decision, its clock moved on
        by max(0, delta - period); a normal state other than the initial one goes back to
        it, entered now (True: a state changed)."""
        now, _scan, delta = args
        current = run.cells[CURRENT]
        faulty = one_of(current, faulty_states)
        moved = delta - stage.period

        def keep() -> None:
            since = run.cells[SINCE]
            run.cells[SINCE] = Opt(since.none, (since.fields[0] + z3.If(moved > 0, moved, 0),))

        def back() -> None:
            run.branch(current != rt.initial,
                       lambda: enter(run, z3.IntVal(rt.initial), now), lambda: None)

        run.branch(faulty, keep, back)
        return z3.And(z3.Not(faulty), current != rt.initial)

    def holds(run: IrSymbolic, lab: str) -> Any:
        """`lab` is in the decision: the state's labels, or the refinement's."""
        current, refined = run.cells[CURRENT], run.cells[REFINED]
        by_state = one_of(current, [n for n, s in enumerate(spec.states) if lab in s.labels])
        if not hld:
            return by_state
        return z3.If(refined.none, by_state, refined.fields[0] == numbers[lab])

    def settler(mode_name: str) -> Handler:
        def settle(run: IrSymbolic, args: list[Any]) -> None:
            """DiagnosisStage.settle: clean; the flags of the decision (0 when off), the
            record's labels, whether a decision to refine holds."""
            run.cells[DIRTY] = z3.BoolVal(False)
            for p in spec.partitions:
                run.image[slots[p.flag]] = (z3.BoolVal(False) if mode_name == "off" else
                                            z3.Or(False, *[holds(run, lab) for lab in p.labels]))
            for lab in spec.labels:
                run.cells[label_cells[lab]] = holds(run, lab)
            run.cells[FAULTY] = z3.Or(False, *[holds(run, lab) for lab in spec.labels])
            if hld:
                decisions = [n for n, s in enumerate(spec.states)
                             if any(s.labels == h.decision for h in hld)]
                run.cells[ARMED] = z3.BoolVal(False) if mode_name == "off" else z3.And(
                    run.cells[REFINED].none, one_of(run.cells[CURRENT], decisions))
        return settle

    def refine(run: IrSymbolic, args: list[Any]) -> Any:
        """DiagnosisStage.refine: while a decision a specification refines holds, not yet
        refined, its rules in order; the first that holds decides its label (True: a
        decision was refined)."""
        was = run.cells[REFINED].none
        for h in hld:
            states = [n for n, s in enumerate(spec.states) if s.labels == h.decision]

            def rules(rest: list[Any]) -> None:
                if rest:
                    label = z3.IntVal(numbers[rest[0].decide])
                    run.branch(run.expression(shift_outputs(rest[0].when.root, outputs)),
                               lambda: run.cells.__setitem__(
                                   REFINED, Opt(z3.BoolVal(False), (label,))),
                               lambda: rules(rest[1:]))

            run.branch(z3.And(run.cells[REFINED].none, one_of(run.cells[CURRENT], states)),
                       lambda h=h: rules(list(h.rules)), lambda: None)
        return z3.And(was, z3.Not(run.cells[REFINED].none))

    cells: dict[tuple[int, Any], Any] = {
        DIRTY: z3.Or(v("Dirty"), mode != v("LastMode")),
        LAST: Opt(v("LastScanNone"), (v("LastScan"),)),
        LAST_NOW: MS * v("LastNow"), GAP: z3.IntVal(stage.gap_us),
        CURRENT: v("State"), SINCE: Opt(v("SinceNone"), (MS * v("Since"),)),
        REFINED: Opt(z3.Not(v("Refined")), (v("RefinedTo"),)) if hld else NONE,
        ARMED: v("Armed") if hld else z3.BoolVal(False),
        FAULTY: v("Faulty"),
        **{cell: st[up[f"label:{lab}"]] for lab, cell in label_cells.items()},
    }
    def lowered() -> dict[str, IrSymbolic]:
        """The program's side, in each mode (the same for every text of the block: its
        variables are z3 constants named after the declarations, which a mutant keeps)."""
        runs: dict[str, IrSymbolic] = {}
        for mode_name in ("observe", "off", "ftc"):
            handlers = {(id(rt), "begin"): begin, (id(rt), "take"): take,
                        (id(stage), "lost_sight"): lost_sight, (id(stage), "refine"): refine,
                        (id(stage), "settle"): settler(mode_name)}
            run = IrSymbolic(cells, read, MS * v("Now"), {}, handlers, set(), image, slots,
                             scan=v("Scan") + 1)
            run.run(lower_diagnosis(stage, [(rt, spec)], mode_name, outputs, bool(hld))
                    + lower_reconstruction(sensors, mode_name))
            runs[mode_name] = run
        return runs

    runs = kept(project, ("lowered diagnoser", name), lowered)

    def after(get: Callable[[IrSymbolic], Any]) -> Any:
        """What the program leaves, in the block's mode."""
        return _merge_value(in_mode["observe"], get(runs["observe"]),
                            _merge_value(in_mode["off"], get(runs["off"]), get(runs["ftc"])))

    since, last = after(lambda r: r.cells[SINCE]), after(lambda r: r.cells[LAST])
    scan = {
        "the state": o("State") == after(lambda r: r.cells[CURRENT]),
        "the time the state was entered": z3.And(
            o("SinceNone") == since.none,
            z3.Implies(z3.Not(since.none), MS * o("Since") == since.fields[0])),
        "the flags must follow (dirty)": o("Dirty") == after(lambda r: r.cells[DIRTY]),
        "the last scan seen (its number and time)": z3.And(
            o("LastScanNone") == last.none, z3.Implies(z3.Not(last.none),
                                                        o("LastScan") == last.fields[0]),
            MS * o("LastNow") == after(lambda r: r.cells[LAST_NOW])),
        "the scan counted, the mode remembered": z3.And(o("Scan") == v("Scan") + 1,
                                                         o("LastMode") == mode),
        "the decision's labels and Faulty": z3.And(
            o("Faulty") == after(lambda r: r.cells[FAULTY]),
            *[out[up[f"label:{lab}"]] == after(lambda r, c=cell: r.cells[c])
              for lab, cell in label_cells.items()]),
        **{f"{p}: the value written (flag or route)": out[ident] == after(
            lambda r, s=slot: r.image[s]) for slot, ident in flag_idents.items()
           for p in [layout.names[slot]]},
    }
    if hld:
        refined = after(lambda r: r.cells[REFINED])
        scan["the High Level Diagnoser's refinement (Refined, RefinedTo, Armed)"] = z3.And(
            o("Refined") == z3.Not(refined.none),
            z3.Implies(o("Refined"), o("RefinedTo") == refined.fields[0]),
            o("Armed") == after(lambda r: r.cells[ARMED]))

    # the fault reset (DiagnosisStage.reset, DiagnoserRuntime.resync): not when off; a
    # faulty diagnoser re-synchronised to the first resync rule that holds on the block's
    # inputs (the values of the scan just ended, as the program wires them), entered now
    reset = IrSymbolic({CURRENT: v("State"), SINCE: Opt(v("SinceNone"), (v("Since"),)),
                        REFINED: Opt(z3.Not(v("Refined")), (v("RefinedTo"),)) if hld else NONE},
                       lambda n, d: st[block.inputs[(n, d)].upper()], v("Now"), {}, {}, set())

    def resync(rules: list[Any]) -> None:
        if rules:
            reset.branch(reset.expression(rules[0].when.root),
                         lambda: enter(reset, z3.IntVal(rt.index[rules[0].target]), v("Now")),
                         lambda: resync(rules[1:]))

    running = mode != 2
    reset.branch(z3.And(running, one_of(v("State"), faulty_states)),
                 lambda: resync(list(spec.resync)), lambda: None)
    r_since, r_refined = reset.cells[SINCE], reset.cells[REFINED]
    fixed = ["Scan", "LastScan", "LastScanNone", "LastNow", "LastMode", "Faulty",
             *[up[f"label:{lab}"] for lab in spec.labels], *flag_idents.values(),
             *(["Armed"] if hld else [])]
    properties = {
        **{f"a scan: {n}": z3.Implies(z3.Not(v("Reset")), p) for n, p in scan.items()},
        "a fault reset: re-synchronised by the first resync rule that holds": z3.Implies(
            v("Reset"), z3.And(
                o("State") == reset.cells[CURRENT], o("SinceNone") == r_since.none,
                z3.Implies(z3.Not(r_since.none), o("Since") == r_since.fields[0]),
                *([o("Refined") == z3.Not(r_refined.none),
                   z3.Implies(o("Refined"), o("RefinedTo") == r_refined.fields[0])]
                  if hld else []))),
        "a fault reset: the flags follow at the next scan (not when off)": z3.Implies(
            v("Reset"), o("Dirty") == z3.Or(v("Dirty"), running)),
        "a fault reset changes nothing else": z3.Implies(
            v("Reset"), z3.And(*[o(n) == v(n) for n in fixed])),
    }
    invariant = z3.And(MS * v("Gap") == stage.gap_us, MS * v("Period") == stage.period,
                       v("State") >= 0, v("State") < len(spec.states))
    properties[f"a call keeps the state invariant (Gap, Period; 0 <= State < "
               f"{len(spec.states)})"] = z3.And(
        MS * o("Gap") == stage.gap_us, MS * o("Period") == stage.period,
        o("State") >= 0, o("State") < len(spec.states))
    return _proofs(properties, invariant, sym, out, at_once)



MARKINGS = 512  # more situations than this (or every set of steps): no invariant on them


def markings(grafcet: Any) -> list[frozenset[str]] | None:
    """The situations (sets of active steps) reachable from the initial one when any
    subset of the enabled transitions fires together (the receptivities left free: a
    superset of what the GRAFCET reaches), or None when they are too many or every set of
    steps (then they say nothing)."""
    from itertools import combinations
    initial = frozenset(grafcet.initial)
    seen, todo = {initial}, [initial]
    while todo:
        marking = todo.pop()
        enabled = [(set(a), set(b)) for a, b in grafcet.transitions if set(a) <= marking]
        for r in range(1, len(enabled) + 1):
            for chosen in combinations(enabled, r):
                off = set().union(*[a for a, _ in chosen])
                on = set().union(*[b for _, b in chosen])
                found = frozenset((marking - (off - on)) | on)
                if found not in seen:
                    seen.add(found)
                    todo.append(found)
                    if len(seen) > MARKINGS:
                        return None
    return None if len(seen) >= 2 ** len(grafcet.names) - 1 else sorted(seen, key=sorted)


def prove_control(project: Any, text: str, tamper: Callable[[str], str] | None = None,
                  at_once: bool = False) -> list[Proof]:
    """The exported control FB (hmi.export.control_pou) against the scan program's control
    law (ControlRuntime.times + .program: hmi.program.grafcet's step times, evolution and
    continuous actions, hmi.program.memories' equations), for every input and every
    reachable state: each output FOV_x, step, step time and memory, each active step's
    activation time, the block's own history, with the handler ``fire`` stated from
    GrafcetRuntime.fire and the first call (``Started`` false) from the engine's first scan
    (GrafcetRuntime.reset, then the history filled with the image).

    The correspondence, FB variable = program state: the image's output slot = the order
    written at the previous scan (the block's reading of the output's global) until the law
    writes it, FOV_x after; a step, a memory = the block's own variable; a step's time
    slot = X_t (ms, the program's µs / 1,000); the runtime's `since` = Xk_since while Xk is
    active, None while inactive; a value of the block's own back in time = its prev_ variable;
    the inputs, timers, flags and filtered sensors = the globals. The reachable states: an
    inactive step's time is 0 (the runtime writes 0 when it deactivates one), and before
    the first call every step is as the GRAFCET's initial situation (the block's initial
    values); a call keeps both (after it, Started holds)."""
    from hmi.export.views import view_name
    ((args, block),) = built_blocks(project, "build_control", "hmi.export.stage_blocks")
    runtime, _project, layout, g = args[:4]
    sym, out = _executed(text, block, tamper)
    st = sym.initial
    grafcet = runtime.grafcet
    kinds = dict(zip(layout.names, layout.kinds, strict=True))
    slots = dict(layout.slots)

    def own(name: str) -> str:
        return (name.replace(".t", "_t") if kinds[name] == "step_time" else name).upper()

    def ident(name: str) -> str:
        """The block's variable for the image's slot `name`."""
        kind = kinds[name]
        if kind == "output":
            return g.idents[f"FOV_{name}"].upper()
        if kind in ("memory", "step", "step_time"):
            return own(name)
        return g.idents[name].upper()

    held = [n for n in layout.names if ident(n) in st]
    history = {(n, d): view_name(n, d).upper() for n in held if kinds[n] in ("memory", "step")
               for d in range(1, 8) if view_name(n, d).upper() in st}
    # the image as the law finds it: an output holds the order written at the previous scan
    image = {slots[n]: st[g.idents[n].upper()] if kinds[n] == "output" else st[ident(n)]
             for n in held}
    for n in held:
        if kinds[n] == "step_time":
            image[slots[n]] = MS * image[slots[n]]

    def read(name: str, depth: int) -> Any:
        if (name, depth) in history:
            return first[(name, depth)]  # (the block's own history, once started)
        return st[block.inputs[(name, depth)].upper()]

    steps = grafcet.names if grafcet is not None else ()
    started = st["STARTED"]
    since_cells: dict[tuple[int, Any], Any] = {}
    if grafcet is not None:
        for k, step in enumerate(steps):
            since_cells[(id(grafcet.since), k)] = Opt(z3.Not(st[own(step)]),
                                                       (MS * st[f"{step}_since".upper()],))

    def fire(run: IrSymbolic, args: list[Any]) -> None:
        """GrafcetRuntime.fire: the transitions in `fire` together; the steps upstream of
        one and downstream of none deactivated (time 0, since None), the steps downstream
        of one activated now (time 0), their stored actions in the order of their names."""
        assert grafcet is not None
        chosen, _image, now = args
        deact = {s: z3.Or(False, *[chosen.has(k) for k, (src, _t) in
                                   enumerate(grafcet.transitions) if s in src]) for s in steps}
        act = {s: z3.Or(False, *[chosen.has(k) for k, (_s, tgt) in
                                 enumerate(grafcet.transitions) if s in tgt]) for s in steps}
        for s in steps:
            k = grafcet.number[s]
            off = z3.And(deact[s], z3.Not(act[s]))
            step, time_ = grafcet.step_slots[s], grafcet.time_slots[s]
            run.image[step] = z3.If(act[s], True, z3.If(off, False, run.image[step]))
            run.image[time_] = z3.If(z3.Or(act[s], off), 0, run.image[time_])
            run.cells[(id(grafcet.since), k)] = _merge_value(
                act[s], Opt(z3.BoolVal(False), (now,)),
                _merge_value(off, NONE, run.cells[(id(grafcet.since), k)]))
        for s in sorted(steps):
            for slot, value in grafcet.stored.get(s, ()):
                run.image[slot] = z3.If(act[s], value, run.image[slot])

    program = IrSymbolic(since_cells, read, MS * st["NOW"], {},
                         {(id(grafcet), "fire"): fire} if grafcet is not None else {},
                         {(id(grafcet), "fired")} if grafcet is not None else set(),
                         image, slots, step_times=dict(layout.step_times))

    def reset() -> None:
        """The engine's first scan (Engine._start): GrafcetRuntime.reset at now, the
        history filled with the image."""
        if grafcet is not None:
            for s in steps:
                program.image[grafcet.step_slots[s]] = z3.BoolVal(s in grafcet.initial)
                if s not in grafcet.initial:
                    program.image[grafcet.time_slots[s]] = z3.IntVal(0)
                program.cells[(id(grafcet.since), grafcet.number[s])] = (
                    Opt(z3.BoolVal(False), (program.now,)) if s in grafcet.initial else NONE)
            for s in grafcet.initial:
                for slot, value in grafcet.stored.get(s, ()):
                    program.image[slot] = z3.BoolVal(value)

    program.branch(z3.Not(started), reset, lambda: None)
    # the history as the law reads it: the block's, or the image after the reset (the
    # engine's first scan fills it with that image)
    first: dict[tuple[str, int], Any] = {}
    first.update({(n, d): z3.If(started, st[var], program.image[slots[n]])
                  for (n, d), var in history.items()})
    program.run(runtime.times + runtime.program)
    after = program.image

    def value_of(name: str) -> Any:
        v = out[ident(name)]
        return MS * v if kinds[name] == "step_time" else v

    properties: dict[str, Any] = {}
    for n in held:
        if kinds[n] in ("output", "memory", "step", "step_time"):
            properties[f"{n}: its value after the call"] = value_of(n) == after[slots[n]]
    unchanged = [ident(n) for n in held if kinds[n] not in ("output", "memory", "step",
                                                            "step_time")]
    properties["the inputs, timers and flags are not written"] = z3.And(
        True, *[out[i] == st[i] for i in unchanged])
    for k, step in enumerate(steps):
        since = program.cells[(id(grafcet.since), k)]
        properties[f"{step}: active with its activation time, or inactive"] = z3.And(
            out[own(step)] == z3.Not(since.none),
            z3.Implies(z3.Not(since.none), MS * out[f"{step}_since".upper()] == since.fields[0]))
    for (n, d), var in history.items():
        # the history after the call: this call's image, then the history it read, shifted
        newer = after[slots[n]] if d == 1 else first[(n, d - 1)]
        properties[f"{view_name(n, d)}: the value {d} scan(s) back"] = out[var] == newer

    def time_var(s: str) -> str:
        return own(layout.names[layout.step_times[s]])

    found = markings(grafcet) if grafcet is not None else None

    def reachable(values: dict[str, Any]) -> Any:
        initial = grafcet.initial if grafcet is not None else ()
        return z3.And(True, *[z3.Implies(z3.Not(values[own(s)]), values[time_var(s)] == 0)
                              for s in steps],
                      z3.Implies(z3.Not(values["STARTED"]), z3.And(True, *[
                          values[own(s)] == (s in initial) for s in steps])),
                      *([z3.Or(*[z3.And(*[values[own(s)] == (s in marking) for s in steps])
                                 for marking in found])] if found else []))
    invariant = reachable(st)
    properties["a call keeps the reachable states (inactive steps' times 0; started" + (
        f"; the active steps one of {len(found)} situations)" if found else ")")] = \
        z3.And(reachable(out), out["STARTED"])
    return _proofs(properties, invariant, sym, out, at_once)


def _proofs(properties: dict[str, Any], invariant: Any, sym: Symbolic, out: dict[str, Any],
            at_once: bool) -> list[Proof]:
    """Each property proved under the invariant, and the bounds; `at_once`: all of them as
    one property (what the mutation study asks: equal, or refuted somewhere)."""
    if at_once:
        bounds = z3.And(True, *[ob for ob, _ in sym.obligations])
        return [_valid("every property", z3.Implies(invariant, z3.And(*properties.values(),
                                                                      bounds)), sym)]
    proofs = [_valid(name, z3.Implies(invariant, p), sym) for name, p in properties.items()]
    proofs.append(in_bounds([_case(sym, out)]))
    return proofs

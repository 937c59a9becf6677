"""A local diagnoser as a function block (scan steps 3-4), printed from the scan program.

The engine's diagnosis stage (hmi.engine.diagnoser.DiagnosisStage) lowers each diagnoser
once into the scan program (hmi.program.diagnosers: the gap test, the current state's
transitions in file order with their windows on the time in the state, the timeout last;
then the reconstruction); this prints one diagnoser's statements (hmi.export.program_st)
with the ST versions of the handlers they call. The PLC switches ``Mode`` at run time, so
the block holds the lowering of each mode under a CASE on it: 1 observe (flags set,
nothing uses them), 2 off (not run, flags 0), any other value FTC (the mode that protects
the plant). A change of mode settles the block again (its flags follow the new mode).

* **Conditions read what the engine reads**: an output O is the order written at the
  previous scan (the lowering reads it one scan further back; the block's input `O` is
  wired by the program to `prev_O`). Inputs, timers and observers are read at this scan.
* **The state is the engine's**: the state's number, the time it was entered (``Since``,
  a TIME with a BOOL "none" until the first scan the diagnoser runs), the last scan's
  number and time (a gap: a scan skipped, or a step longer than 10 nominal periods), and
  whether the flags must follow (``Dirty``). The scan's number is the block's own count of
  its calls; the scan's time the program's clock (``Now``).
* **Handlers**: ``begin`` (the first scan: the time in the initial state counts from
  now), ``take`` (transition k: its target entered now), ``lost_sight`` (a gap: a normal
  state goes back to the initial one, a faulty one keeps its decision with its clock moved
  on by the gap less one period) and ``settle`` (the partition flags and labels of the
  state, flags 0 when off).
* **Fault reset** is a call of its own with `Reset := TRUE`, after the scan (the engine
  resets between scans): a faulty diagnoser re-synchronises to the first resync rule that
  holds on the values of the scan just ended, entered at that scan's time; its flags follow
  at the next scan, as in the engine (DiagnosisStage.reset).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hmi.engine.diagnoser import DiagnoserRuntime, DiagnosisStage
from hmi.engine.layout import Layout
from hmi.export import model as m
from hmi.export import source
from hmi.export.names import Scope
from hmi.export.program_st import (
    BOOL,
    INT,
    NDINT,
    NTIME,
    TIME,
    Handler,
    NotPrintable,
    Place,
    Places,
    StPrinter,
)
from hmi.export.views import Block, Durations, Views, convert
from hmi.program.diagnosers import lower_diagnosis, lower_reconstruction, shift_outputs
from hmi.project.model import HighLevelSpec

FTC, OBSERVE, OFF = 0, 1, 2
MODE_CODES = {"ftc": FTC, "observe": OBSERVE, "off": OFF}


def ftc_mode(mode: m.Expr) -> m.Expr:
    """FTC unless the mode says observe or off (an unknown value is FTC)."""
    return m.and_(m.Binary("<>", mode, m.IntLit(OBSERVE)), m.Binary("<>", mode, m.IntLit(OFF)))


FIXED = ("Now", "Mode", "Reset", "State", "Faulty", "Scan", "LastMode", "Dirty", "LastScan",
         "LastScanNone", "LastNow", "Gap", "Period", "Since", "SinceNone", "Armed", "Refined",
         "RefinedTo")


def build_diagnoser(stage: DiagnosisStage, k: int, layout: Layout, pou_name: str,
                    scope: Scope, durations: Durations,
                    high_level: Sequence[HighLevelSpec] = ()) -> Block:
    """Diagnoser `k` of `stage` as FB `pou_name`: its inputs (the values its conditions
    read, by (name, depth) as written in the project: the program shifts the outputs) for
    the program to wire. `high_level`: the High Level Diagnoser's specifications that
    refine this diagnoser's decisions (the stage's ``refine``, after its transitions)."""
    rt = stage.runtimes[k]
    spec = rt.spec
    hld = tuple(h for h in high_level if h.diagnoser == spec.name)
    sc = scope.child()
    t = {key: sc.take(key) for key in FIXED}
    labels = {lab: sc.take(lab) for lab in spec.labels}
    flags = {p.flag: sc.take(p.flag) for p in spec.partitions}
    filtered = {p.filtered: sc.take(p.filtered) for p in spec.partitions if p.filtered}
    views = Views(sc)
    outputs = frozenset(layout.outputs)

    def v(key: str) -> m.Name:
        return m.Name(t[key])

    def slot(index: int) -> Place:
        name = layout.names[index]
        if name in flags:
            return Place(flags[name], BOOL)
        if name in filtered:
            return Place(filtered[name], BOOL)
        return Place(views.get(name), BOOL)  # (a sensor, an estimate: as the program wires)

    def read(name: str, depth: int) -> m.Expr:
        # the lowering reads an output one scan further back; the block's input stands for
        # it as written in the project, the program wires it one scan back
        return views.name(name, depth - (name in outputs))

    places = Places(slot=slot, read=read, step_time=lambda step: _no_step_time(spec.name, step),
                    now=v("Now"), scan=v("Scan"))
    places.cell(stage, "dirty", Place(t["Dirty"], BOOL))
    places.cell(stage, "last_scan", Place(t["LastScan"], NDINT, t["LastScanNone"]))
    places.cell(stage, "last_now", Place(t["LastNow"], TIME))
    places.cell(stage, "gap_us", Place(t["Gap"], TIME))
    places.cell(rt, "since_us", Place(t["Since"], NTIME, t["SinceNone"]))
    places.cell(rt, "current", Place(t["State"], INT))
    places.cell(stage, "hld_armed", Place(t["Armed"], BOOL))
    began = _entered(v, False)
    entered = _entered(v, bool(hld))  # (entering a state drops a refinement)
    places.handler(rt, "begin", Handler(lambda printer, args: began(args[0])))
    places.handler(rt, "take", Handler(lambda printer, args: [
        m.Comment(spec.transitions[args[0].value].text()),
        m.Assign(v("State"), m.IntLit(rt.index[spec.transitions[args[0].value].target])),
        *entered(args[1])]))
    places.handler(stage, "lost_sight", Handler(
        value=lambda printer, args, result: _lost_sight(rt, v, args, result, entered)))
    places.handler(stage, "refine", Handler(
        value=lambda printer, args, result: _refine(rt, v, hld, printer, outputs, result)))
    printer = StPrinter(places, sc, durations, spec.pos, f"a window of diagnoser {spec.name!r}")
    sensors = [(layout.slots[p.filtered], layout.slots[p.sensor], layout.slots[p.estimate],
                layout.slots[p.flag])
               for p in spec.partitions if p.sensor and p.estimate and p.filtered]
    per_mode: dict[str, list[m.Stmt]] = {}
    for mode in ("observe", "off", "ftc"):
        def settle(printer: StPrinter, args: tuple[Any, ...], mode: str = mode
                   ) -> list[m.Stmt]:
            return _settle(rt, v, labels, flags, mode, hld)
        places.handler(stage, "settle", Handler(settle))
        per_mode[mode] = printer.program(
            lower_diagnosis(stage, [(rt, spec)], mode, outputs, bool(hld))
            + lower_reconstruction(sensors, mode))

    resync: list[tuple[m.Expr, tuple[m.Stmt, ...]]] = []
    reset_reads: dict[tuple[str, int], None] = {}
    for number, rule in enumerate(spec.resync, start=1):
        for ref in source.refs(rule.when):
            reset_reads.setdefault(ref)
        resync.append((convert(rule.when.root, views.name), (
            m.Comment(f"resync rule {number}: {rule.when} -> {rule.target}"),
            m.Assign(v("State"), m.IntLit(rt.index[rule.target])), *entered(v("Now")))))
    reset: list[m.Stmt] = []
    if resync and _faulty(rt, v) != m.FALSE:
        reset.append(m.if_(_faulty(rt, v), m.If(tuple(resync))))
    reset.append(m.Assign(v("Dirty"), m.TRUE))  # (the flags follow at the next scan)
    body = (m.If((
        (v("Reset"), (m.Comment("fault reset: re-synchronise a faulty diagnoser (not when "
                                "off)"),
                      m.if_(m.Binary("<>", v("Mode"), m.IntLit(OFF)), *reset))),),
        (m.Assign(v("Scan"), m.Binary("+", v("Scan"), m.IntLit(1))),
         m.Comment("a change of mode: the flags follow the new one"),
         m.if_(m.Binary("<>", v("Mode"), v("LastMode")), m.Assign(v("Dirty"), m.TRUE),
               m.Assign(v("LastMode"), v("Mode"))),
         m.Case(v("Mode"), (((OBSERVE,), (m.Comment("observe: flags set, nothing uses them"),
                                          *per_mode["observe"])),
                            ((OFF,), (m.Comment("off: not run, flags 0"), *per_mode["off"]))),
                (m.Comment("FTC (and any other value)"), *per_mode["ftc"])))),)

    state_list = ", ".join(f"{n} {s.name}" + (f" {{{', '.join(s.labels)}}}" if s.labels else "")
                           for n, s in enumerate(spec.states))
    period = stage.period
    blocks = (
        m.VarBlock("input", (
            m.Var(t["Now"], m.TIME, comment="the program's clock"),
            m.Var(t["Mode"], m.INT, comment="0 FTC, 1 observe, 2 off (other values: FTC)"),
            m.Var(t["Reset"], m.BOOL, comment="TRUE: a fault reset (a call of its own)"),
            *(m.Var(ident, m.BOOL) for ident in views.idents.values()),
        )),
        m.VarBlock("output", (
            m.Var(t["State"], m.INT, m.IntLit(rt.initial), comment="see the state numbers "
                  "above"),
            m.Var(t["Faulty"], m.BOOL, comment="the decision holds a label"),
            *(m.Var(ident, m.BOOL, comment=spec.label_text(lab)) for lab, ident in
              labels.items()),
            *(m.Var(ident, m.BOOL, comment=f"partition {p.name}") for p, ident in
              zip(spec.partitions, flags.values(), strict=True)),
            *(m.Var(ident, m.BOOL) for ident in filtered.values()),
        )),
        m.VarBlock("local", (
            m.Var(t["Scan"], m.DINT, comment="the calls of this block: the scan's number"),
            m.Var(t["LastMode"], m.INT, m.IntLit(-1), comment="the mode of the last scan"),
            m.Var(t["Dirty"], m.BOOL, m.TRUE, comment="the flags must follow the state"),
            m.Var(t["LastScan"], m.DINT, comment="the last scan the diagnoser ran"),
            m.Var(t["LastScanNone"], m.BOOL, m.TRUE, comment="it never ran"),
            m.Var(t["LastNow"], m.TIME, comment="the time of that scan"),
            m.Var(t["Gap"], m.TIME, durations.time(stage.gap_us, spec.pos, "the gap"),
                  comment="a longer step is a gap in the observation (10 periods)"),
            m.Var(t["Period"], m.TIME, durations.time(period, spec.pos, "the scan period"),
                  comment="the task's nominal period (the project's scan period)"),
            m.Var(t["Since"], m.TIME, comment="when the current state was entered"),
            m.Var(t["SinceNone"], m.BOOL, m.TRUE, comment="the diagnoser has not run yet"),
            *((m.Var(t["Armed"], m.BOOL, comment="a decision the High Level Diagnoser "
                     "refines holds, not yet refined"),
               m.Var(t["Refined"], m.BOOL, comment="the High Level Diagnoser refined the "
                     "decision"),
               m.Var(t["RefinedTo"], m.INT, comment="to this label (its number in the "
                     "list of labels, from 1)")) if hld else ()),
            *printer.locals,
        )),
    )
    comment = (f"Scan steps 3-4: local diagnoser {spec.name}"
               + (f" ({spec.description})" if spec.description else "") + ", as the "
               "engine's scan program runs it.\n"
               f"States: {state_list}.\n"
               "An output O among the inputs is the order written at the previous scan.")
    pou = m.Pou(pou_name, "functionBlock", blocks, body, comment)
    ports = {key: t[key] for key in ("Now", "Mode", "Reset", "State", "Faulty")}
    ports.update({f"label:{lab}": ident for lab, ident in labels.items()})
    return Block(pou, dict(views.idents), {**flags, **filtered}, ports, tuple(reset_reads))


def _entered(v: Any, refined: bool) -> Any:
    """The statements entering a state at `now` (DiagnoserRuntime.enter, begin), and
    dropping a refinement (`refined`: the diagnoser has one)."""
    def entered(now: m.Expr) -> list[m.Stmt]:
        return [m.Assign(v("Since"), now), m.Assign(v("SinceNone"), m.FALSE),
                *((m.Assign(v("Refined"), m.FALSE),) if refined else ())]
    return entered


def _in_states(v: Any, numbers: list[int]) -> m.Expr:
    return m.or_(*(m.eq(v("State"), m.IntLit(n)) for n in numbers))


def _faulty(rt: DiagnoserRuntime, v: Any) -> m.Expr:
    """The current state holds a decision (DiagState.faulty)."""
    return _in_states(v, [n for n, s in enumerate(rt.spec.states) if s.faulty])


def _lost_sight(rt: DiagnoserRuntime, v: Any, args: tuple[Any, ...], result: m.Name,
                entered: Any) -> list[m.Stmt]:
    """DiagnosisStage.lost_sight for this diagnoser, its value into `result`: a faulty state
    keeps its decision, its clock moved on by the gap less one period; a normal state
    other than the initial one goes back to it, entered now."""
    now, _scan, delta = args
    branches: list[tuple[m.Expr, tuple[m.Stmt, ...]]] = []
    faulty = _faulty(rt, v)
    if faulty != m.FALSE:
        branches.append((faulty, (m.if_(
            m.and_(m.not_(v("SinceNone")), m.Binary(">", delta, v("Period"))),
            m.Assign(v("Since"), m.Binary("+", v("Since"),
                                          m.Binary("-", delta, v("Period"))))),)))
    branches.append((m.Binary("<>", v("State"), m.IntLit(rt.initial)), (
        m.Comment("the plant was not observed: re-synchronising"),
        m.Assign(v("State"), m.IntLit(rt.initial)), *entered(now), m.Assign(result, m.TRUE))))
    return [m.Assign(result, m.FALSE), m.If(tuple(branches))]


def _settle(rt: DiagnoserRuntime, v: Any, labels: dict[str, str], flags: dict[str, str],
            mode: str, hld: tuple[HighLevelSpec, ...]) -> list[m.Stmt]:
    """DiagnosisStage.settle for this diagnoser: the flags of its decision (the state's, or
    the High Level Diagnoser's refinement of it; 0 when off), its labels, whether a
    decision to refine holds; the routes are the reconstruction's, after it."""
    spec = rt.spec
    numbers = {lab: n for n, lab in enumerate(spec.labels, start=1)}

    def decides(labs: set[str]) -> m.Expr:
        """The decision holds one of `labs`: the state's, or the refined one."""
        by_state = _in_states(v, [n for n, s in enumerate(spec.states) if labs & set(s.labels)])
        if not hld:
            return by_state
        refined = m.or_(*(m.eq(v("RefinedTo"), m.IntLit(numbers[lab]))
                          for lab in spec.labels if lab in labs))
        return m.or_(m.and_(m.not_(v("Refined")), by_state), m.and_(v("Refined"), refined))

    out: list[m.Stmt] = [m.Assign(v("Dirty"), m.FALSE)]
    for p, ident in zip(spec.partitions, flags.values(), strict=True):
        out.append(m.Assign(m.Name(ident), m.FALSE if mode == "off" else decides(set(p.labels))))
    for lab, ident in labels.items():
        out.append(m.Assign(m.Name(ident), decides({lab})))
    out.append(m.Assign(v("Faulty"), decides(set(spec.labels))))
    if hld:
        armed = m.FALSE if mode == "off" else m.and_(m.not_(v("Refined")), _in_states(
            v, [n for n, s in enumerate(spec.states) if any(s.labels == h.decision
                                                            for h in hld)]))
        out.append(m.Assign(v("Armed"), armed))
    return out


def _refine(rt: DiagnoserRuntime, v: Any, hld: tuple[HighLevelSpec, ...], printer: StPrinter,
            outputs: frozenset[str], result: m.Name) -> list[m.Stmt]:
    """DiagnosisStage.refine for this diagnoser's specifications, its value into `result`:
    while the decision a specification refines holds, not yet refined, its rules in order;
    the first that holds decides its label."""
    spec = rt.spec
    numbers = {lab: n for n, lab in enumerate(spec.labels, start=1)}
    out: list[m.Stmt] = [m.Assign(result, m.FALSE)]
    for h in hld:
        states = [n for n, s in enumerate(spec.states) if s.labels == h.decision]
        rules = tuple((printer.test(shift_outputs(r.when.root, outputs)), (
            m.Comment(f"{h.name}: {r.when} -> {r.decide}"),
            m.Assign(v("Refined"), m.TRUE), m.Assign(v("RefinedTo"), m.IntLit(numbers[r.decide])),
            m.Assign(result, m.TRUE))) for r in h.rules)
        if states and rules:
            out.append(m.if_(m.and_(m.not_(v("Refined")), _in_states(v, states)),
                             m.If(rules)))
    return out


def _no_step_time(name: str, step: str) -> m.Expr:
    raise NotPrintable(f"diagnoser {name!r} reads {step}.t (the loader keeps step times "
                       "to the control law)")

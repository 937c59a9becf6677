"""A proof, with z3, that one call of the exported safety program (hmi.export.program_pou:
`PRG_<P>_Safety`), as blark parses it, is one scan of the engine's scan program: the
function blocks called in the scan's order (hmi.program.order), each given the values the
engine's stage reads at that point of the scan, the output image, the history shifted, the
first cycle's history, the fault reset after the scan, the program's clock.

How. The program is run by tests/st_prove.py's executor; each function block it calls is an
*uninterpreted function* (:class:`UfBlock`): one z3 function per variable of the block (and
per global it writes), of every variable of the instance (inputs, outputs, locals: an
instance keeps them all between calls, an input a call does not give keeps its value) and of
every global it reads. The reference (:func:`engine_scan`) is the engine's scan
(hmi.engine.scan, hmi.program.order) on the same values: the image (this scan's inputs, then
what each part writes), the history (`prev(x, d)`: d scans back; at the first scan, every
depth is the image as the input scan left it, Engine._start), each block called with the same
functions at its stage's part of the scan, its inputs given what the stage's lowering reads,
the output scan, the monitors, then the history shifted (Engine._conclude) and a fault reset
read on that image and history (Engine.fault_reset, between scans). A property is valid for
every interpretation of those functions, every input and every state satisfying the
invariant: whatever a block computes, the program hands it what the engine's stage is handed
and makes of its results what the engine makes of them. (A counterexample is one to that:
some block is handed another value; whether the real block can tell, e.g. an input it never
reads, is its own proof's business.)

Why the composition is sound: tests/st_prove.py (the filter) and tests/ir_prove.py (the
memory, the diagnosers, the control, the monitors) prove each block, for every input and
every state (satisfying its invariant), equal to its stage's lowering in the engine's scan
program, its inputs keyed (x, depth) reading what the lowering reads; here each block is any
function, called on exactly the engine's values. Together: one program call is one engine
scan, by induction over the cycles from the first. It rests on:

* the block proofs' correspondence of a block input to what the lowering reads: (x, d) reads
  x d scans back; a diagnoser's input (x, d) for an output x reads it d + 1 scans back (its
  lowering reads an output one scan further back, what the plant received), its reset reads
  the resync rules' (x, d) as Engine.fault_reset does, on the history with this scan's image
  first; the control reads the globals themselves (the image at its point of the scan);
* a block called once where its stage's parts run: the control's step times (order.STEP_TIMES,
  before the diagnosers) with its law, the diagnosers each with its reconstruction (the engine
  runs every diagnoser, then every reconstruction). Sound because no diagnoser reads a step
  time, a flag or a filtered sensor (the loader refuses them; checked here on the blocks'
  inputs);
* the blocks' invariants holding at every call (each block proof shows a call keeps its own,
  from the PLC's initial values);
* the standard TON `Clock`, called once a cycle with IN TRUE, its elapsed time the program's
  clock (every block is handed the same `Now`, its ET after this cycle's call);
* the state invariant: once started, a value the program keeps one scan back equals its
  global (the shift is the cycle's last statement); before, each global holds the engine's
  initial image (checked on the CONFIGURATION's initial values); a call keeps it;
* no located register word (no example project has one: the read and write of register bits
  is not covered).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import z3

from tests.st_prove import (
    BITS,
    INTS,
    Proof,
    Symbolic,
    Unsupported,
    VarType,
    _ite,
    _parsed,
    _valid,
    declarations,
    parse_changed,
)


def _sort(vtype: str) -> Any:
    if vtype == "BOOL":
        return z3.BoolSort()
    if vtype in BITS:
        return z3.BitVecSort(BITS[vtype])
    if vtype in INTS or vtype == "TIME":
        return z3.IntSort()
    raise Unsupported(f"type {vtype}")


def _flat(variables: dict[str, Any]) -> list[Any]:
    return [x for v in variables.values() for x in (v if isinstance(v, list) else [v])]


@dataclass
class UfBlock:
    """A function block as uninterpreted functions (tests/st_prove.BlockModel): each variable
    after a call, and each global it writes, a z3 function of the instance's variables and
    the globals it reads."""

    name: str
    variables: dict[str, VarType]
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    types: dict[str, str] = field(default_factory=dict)  # a global's type
    _fns: dict[str, Any] = field(default_factory=dict)

    def _fn(self, key: str, domain: list[Any], vtype: str) -> Any:
        if key not in self._fns:
            self._fns[key] = z3.Function(f"{self.name}.{key}'", *domain, _sort(vtype))
        return self._fns[key]

    def call(self, variables: dict[str, Any], globals_: dict[str, Any]
             ) -> tuple[dict[str, Any], dict[str, Any]]:
        args = _flat(variables) + [globals_[g] for g in self.reads]
        domain = [a.sort() for a in args]
        after: dict[str, Any] = {}
        for v, vt in self.variables.items():
            if vt.low is not None:
                after[v] = [self._fn(f"{v}[{k}]", domain, vt.name)(*args)
                            for k in range(vt.high - vt.low + 1)]  # type: ignore[operator]
            else:
                after[v] = self._fn(v, domain, vt.name)(*args)
        written = {g: self._fn(g, domain, self.types[g])(*args) for g in self.writes}
        return after, written


def ton() -> UfBlock:
    """IEC 61131-3's TON: IN, PT, Q, ET and the start time it keeps (hidden)."""
    return UfBlock("TON", {"IN": VarType("BOOL"), "PT": VarType("TIME"), "Q": VarType("BOOL"),
                           "ET": VarType("TIME"), "START": VarType("TIME")})


def _section(text: str, kind: str, name: str) -> str:
    start = re.search(rf"^{kind} {re.escape(name)}\s*$", text, re.MULTILINE)
    if start is None:
        raise KeyError(name)
    end = text.index(f"END_{kind}", start.start()) + len(f"END_{kind}")
    return text[start.start():end] + "\n"


def block_model(text: str, name: str) -> UfBlock:
    """The function block `name` of the exported `text` as a UfBlock: its variables from its
    declarations (blark parses them alone: the body is what the block proofs are about), the
    globals it reads (VAR_EXTERNAL) and those its body assigns."""
    fb = _section(text, "FUNCTION_BLOCK", name)
    head = fb[:fb.rindex("END_VAR") + len("END_VAR")]
    body = fb[len(head):]
    decl = declarations(_parsed(head + "\nEND_FUNCTION_BLOCK\n"))
    variables = {v: decl.types[v] for v in decl.order
                 if decl.sections[v] in ("input", "output", "local")}
    externals = [v for v in decl.order if decl.sections[v] == "external"]
    writes = tuple(v for v in externals
                   if re.search(rf"^\s*{re.escape(v)}\s*:=", body, re.MULTILINE | re.IGNORECASE))
    return UfBlock(name.upper(), variables, tuple(externals), writes,
                   {v: decl.types[v].name for v in externals})


@dataclass(frozen=True)
class Export:
    """What hmi.export.build handed build_program, and what it built."""

    project: Any
    g: Any  # hmi.export.image.Globals
    blocks: Any  # hmi.export.program_pou.Blocks
    pou: Any  # the program's model
    instances: dict[str, str]  # key (Memory, Diag_V1 ...) -> the instance's name


def exported(project: Any) -> Export:
    from tests.ir_prove import built_blocks
    ((args, (pou, instances)),) = built_blocks(project, "build_program")
    return Export(project, args[2], args[3], pou, instances)


def history_vars(pou: Any) -> dict[tuple[str, int], str]:
    """The program's locals holding a value back in time, (name, depth) -> identifier (read
    from their declarations' comments, `x, 2 scans back`)."""
    found = {}
    for block in pou.blocks:
        for v in block.vars:
            got = re.fullmatch(r"(.+), (\d+) scans? back", v.comment or "")
            if got:
                found[(got.group(1), int(got.group(2)))] = v.name.upper()
    return found


def initial_globals(text: str) -> dict[str, str]:
    """The CONFIGURATION's global variables' initial values as written (identifier in upper
    case -> the literal; a variable without one is absent)."""
    config = text[text.index("CONFIGURATION"):]
    return {got.group(1).upper(): got.group(2).upper() for got in re.finditer(
        r"^\s*(\w+)\s*(?:AT\s+%\S+\s*)?:\s*\w+\s*:=\s*([^;]+);", config, re.MULTILINE)}


def prove_program(project: Any, text: str, tamper: Callable[[str], str] | None = None
                  ) -> list[Proof]:
    """The exported program of `project` (in `text`, its POU `tamper`ed if given) against
    one engine scan (see the module docstring): a list of proved (or refuted) properties."""
    from hmi.engine.layout import Layout
    from hmi.export.views import TMAX_MS
    from hmi.project.diagnosers import layout_names
    ex = exported(project)
    g = ex.g
    if g.registers:
        raise Unsupported("located register words")
    prg_text = _section(text, "PROGRAM", ex.pou.name)
    tree = _parsed(prg_text) if tamper is None else parse_changed(prg_text, tamper(prg_text))
    prg_decl = declarations(tree)
    models: dict[str, UfBlock] = {"TON": ton()}
    for name in {t.name for t in prg_decl.types.values() if t.name.startswith("FB_")}:
        models[name] = block_model(text, next(
            p for p in re.findall(r"^FUNCTION_BLOCK (\S+)", text, re.MULTILINE)
            if p.upper() == name))
    sym = Symbolic(tree, blocks=models)
    sym.obligations = []
    st = sym.initial
    out = sym.run()

    layout = Layout.build(project, project.control(None), extra=layout_names(project))
    ref, invariant = engine_scan(ex, layout, st, models, prg_decl, TMAX_MS)

    started, fr = st["STARTED"], st[g.idents["FaultReset"].upper()]
    instances = {key: ident.upper() for key, ident in ex.instances.items()}
    instances["Clock"] = "CLOCK"

    def same(keys: list[str]) -> Any:
        pairs = []
        for k in keys:
            a, r = out[k], ref[k]
            pairs += list(zip(a, r, strict=True)) if isinstance(a, list) else [(a, r)]
        return z3.And(True, *[x == y for x, y in pairs])

    def of(inst: str) -> list[str]:
        return [k for k in out if k.startswith(f"{inst}.")]

    by_kind: dict[str, list[str]] = {}
    for name, ident in g.idents.items():
        by_kind.setdefault(g.kinds[name], []).append(ident.upper())
    history = history_vars(ex.pou)
    all_keys = [k for k in ref]
    properties: dict[str, Any] = {
        "the first cycle: the history is the initial image, every block called as at the "
        "engine's first scan": z3.Implies(z3.Not(started), same(all_keys))}
    for key, inst in instances.items():
        properties[f"{key}: called once, at its point of the scan, with the engine's values"] \
            = z3.Implies(z3.And(started, z3.Not(fr)), same(of(inst)))
        properties[f"{key}: after a fault reset"] = z3.Implies(z3.And(started, fr),
                                                              same(of(inst)))
    properties.update({
        "the output image: each output the filter's": z3.Implies(started, same(
            by_kind.get("output", []))),
        "the image: timers, observers, flags, filtered sensors, FOV_x as the scan wrote them":
            z3.Implies(started, same([k for kind in ("timer", "observer", "flag", "filtered",
                                                       "fov") for k in by_kind.get(kind, [])])),
        "the monitors' labels and the filter's words": z3.Implies(started, same(
            [*by_kind.get("label", []), *[g.idents[n].upper() for n in (
                "Violations", "FilterLatched", "FilterFallback")]])),
        "the inputs and the operator's words kept; a fault reset clears FaultReset":
            z3.Implies(started, same([*by_kind.get("input", []), *[g.idents[n].upper() for n in (
                "FaultReset", "FilterPolicy", "DiagnosisMode")]])),
        "the history: each value kept d scans back, shifted": z3.Implies(started, same(
            list(history.values()))),
        "a call keeps the state invariant (started; each value kept one scan back is its "
        "global)": z3.And(out["STARTED"], _invariant(ex, layout, out, history)),
    })
    # (a counterexample shows the globals and the program's own variables, not the blocks')
    proofs = [_valid(name, z3.Implies(invariant, p), sym, lambda n: "." not in n)
              for name, p in properties.items()]
    proofs.append(_initial_values(ex, layout, text))
    return proofs


def _invariant(ex: Export, layout: Any, values: dict[str, Any],
               history: dict[tuple[str, int], str]) -> Any:
    """Once started, a value the program keeps one scan back is its global (the inputs
    apart: the PLC reads them before the cycle); before, each global is the engine's initial
    image."""
    g = ex.g
    initial = layout.initial_image(ex.project)
    kept = [(g.idents[n].upper(), var) for (n, d), var in history.items()
            if d == 1 and g.kinds[n] != "input"]
    first = [values[g.idents[n].upper()] == z3.BoolVal(bool(initial[layout.slots[n]]))
             for n in layout.names if n in g.idents and g.kinds[n] != "input"]
    started = values["STARTED"]
    return z3.And(z3.Implies(started, z3.And(True, *[values[a] == values[v] for a, v in kept])),
                  z3.Implies(z3.Not(started), z3.And(True, *first)))


def _initial_values(ex: Export, layout: Any, text: str) -> Proof:
    """The invariant at the PLC's start: each global of the image declared with the engine's
    initial value (a BOOL without one is FALSE), the program not started."""
    initial = layout.initial_image(ex.project)
    declared = initial_globals(text)
    wrong = [n for n in layout.names if n in ex.g.idents
             and ex.g.kinds[n] != "input"
             and declared.get(ex.g.idents[n].upper(), "FALSE") != str(
                 bool(initial[layout.slots[n]])).upper()]
    name = "the globals' initial values are the engine's initial image"
    return Proof(name, not wrong, "proved" if not wrong else f"differ: {wrong}")


def engine_scan(ex: Export, layout: Any, st: dict[str, Any], models: dict[str, UfBlock],
                decl: Any, tmax_ms: int) -> tuple[dict[str, Any], Any]:
    """One engine scan on the program's state `st` (the module docstring), the blocks the
    same functions: the state it leaves, keyed as the program's variables (globals, instance
    variables INST.V, the history), and the invariant over `st`."""
    from hmi.export import source
    from hmi.logic.expr import Var, walk
    from hmi.program import order
    from hmi.project.diagnosers import diagnosers_of
    project, g, b = ex.project, ex.g, ex.blocks
    outputs = set(layout.outputs)
    up = {name: ident.upper() for name, ident in g.idents.items()}
    initial = layout.initial_image(project)
    started = st["STARTED"]
    history = history_vars(ex.pou)
    fresh: dict[tuple[str, int], Any] = {}

    def image0(n: str) -> Any:
        """The image as the input scan leaves it at the first scan (Engine._start)."""
        if g.kinds[n] == "input":
            return st[up[n]]
        return z3.BoolVal(bool(initial[layout.slots[n]]))

    # the engine's image, by the program's global names: the inputs as read, the rest as
    # the last scan left it (the initial image before the first)
    glob = {k: v for k, v in st.items() if decl.sections.get(k) == "external"}
    for n in layout.names:
        if n in up and g.kinds[n] != "input":
            glob[up[n]] = _ite(started, st[up[n]], image0(n))

    def back(n: str, d: int) -> Any:
        """The history: n, d >= 1 scans back (the first scan: the image, at every depth)."""
        if (n, d) in history:
            kept = st[history[(n, d)]]
        else:  # (a value the program does not keep: the engine's, unknown)
            kept = fresh.setdefault((n, d), z3.Bool(f"history {n} {d}"))
        return _ite(started, kept, image0(n))

    # the law's vector in the image's output slots, from the law to the output scan (the
    # PLC keeps it in FOV_x: a read of an output there is the engine's vector)
    law_vector: dict[str, Any] = {}

    def value(n: str, d: int) -> Any:
        return law_vector.get(n, glob[up[n]]) if d == 0 else back(n, d)

    insts: dict[str, dict[str, Any]] = {}

    def inst_of(key: str) -> str:
        return "CLOCK" if key == "Clock" else ex.instances[key].upper()

    def call(key: str, given: dict[str, Any]) -> dict[str, Any]:
        inst = inst_of(key)
        model = models[decl.types[inst].name]
        vars_ = insts.setdefault(inst, {v: st[f"{inst}.{v}"] for v in model.variables})
        vars_ = {**vars_, **{k.upper(): v for k, v in given.items()}}
        after, written = model.call(vars_, {r: glob[r] for r in model.reads})
        insts[inst] = after
        glob.update(written)
        return after

    def wired(block: Any, depth: Any) -> dict[str, Any]:
        return {ident: value(n, depth(n, d)) for (n, d), ident in block.inputs.items()}

    def results(block: Any, after: dict[str, Any]) -> None:
        for n, port in block.outputs.items():
            glob[up[n]] = after[port.upper()]

    now: Any = None
    mode = glob[up["DiagnosisMode"]]
    parts = {at for at, _ in b.stages}
    if not parts <= {order.MEMORY, order.DIAGNOSERS, order.LAW, order.FILTER, order.MONITORS}:
        raise Unsupported(f"an added stage's blocks: {parts}")
    # the filter's block and the monitors' (modelled below as the engine runs them)
    (f,) = (c.block for at, calls in b.stages if at == order.FILTER for c in calls)
    monitors = [c.block for at, calls in b.stages if at == order.MONITORS for c in calls]
    flags = {n for n in g.kinds if g.kinds[n] in ("flag", "filtered")}
    for at, calls in b.stages:
        for c in calls:
            if at == order.DIAGNOSERS and any(n in flags or n.endswith(".t")
                                              for n, _ in c.block.inputs):
                raise Unsupported(f"{c.key} reads a flag, a filtered sensor or a step time")
    for part in order.placed(order.SCAN, b.places):
        if part == order.INPUTS:
            clock = call("Clock", {"IN": z3.BoolVal(True), "PT": z3.IntVal(tmax_ms)})
            now = clock["ET"]
        for at, calls in b.stages:
            if at != part or at in (order.FILTER, order.MONITORS):
                continue
            for c in calls:
                block, ports = c.block, c.block.ports
                given: dict[str, Any] = {ports["Now"]: now}
                if at == order.DIAGNOSERS:
                    given.update({ports["Reset"]: z3.BoolVal(False), ports["Mode"]: mode})
                    given.update(wired(block, lambda n, d: d + (n in outputs)))
                else:
                    given.update(wired(block, lambda n, d: d))
                results(block, call(c.key, given))
                if at == order.LAW:
                    law_vector.update({x: glob[up[f"FOV_{x}"]] for x in layout.outputs})
        if part == order.FILTER:
            p = f.ports
            given = {p["Reset"]: z3.BoolVal(False), p["Policy"]: glob[up["FilterPolicy"]],
                     p["Ftc"]: z3.And(mode != 1, mode != 2),
                     **{p[f"FOV_{x}"]: glob[up[f"FOV_{x}"]] for x in layout.outputs},
                     **wired(f, lambda n, d: d)}
            after = call("Filter", given)
            decided = {x: after[f.outputs[x].upper()] for x in layout.outputs}
            for key, port in (("Violations", "Violations"), ("FilterLatched", "Latched"),
                              ("FilterFallback", "Fallback")):
                glob[up[key]] = after[p[port].upper()]
        if part == order.OUTPUTS:
            law_vector.clear()
            for x in layout.outputs:
                glob[up[x]] = decided[x]
        if part == order.MONITORS:
            for task, block in zip(source.monitors(project), monitors, strict=True):
                p = block.ports
                after = call(f"Mon_{task.name}", {p["Now"]: now, p["Reset"]: z3.BoolVal(False),
                                                  **wired(block, lambda n, d: d)})
                glob[up[task.label]] = after[p["Fault"].upper()]

    # the history: this scan's image first (Engine._conclude)
    shifted = {(n, d): glob[up[n]] if d == 1 else back(n, d - 1) for (n, d) in history}

    def at_reset(n: str, d: int) -> Any:
        return glob[up[n]] if d == 0 else (glob[up[n]] if d == 1 else back(n, d - 1))

    # the fault reset, between scans (Engine.fault_reset, in its order): the filter's
    # latch released, each monitor's label, each diagnoser re-synchronised on the image
    # and the history just left (its resync rules' reads, an output one scan further back)
    scan_insts, scan_glob = dict(insts), dict(glob)
    call("Filter", {f.ports["Reset"]: z3.BoolVal(True)})
    for task, block in zip(source.monitors(project), monitors, strict=True):
        call(f"Mon_{task.name}", {block.ports["Reset"]: z3.BoolVal(True)})
    specs = {f"Diag_{d.name}": d for d in diagnosers_of(project)}
    for at, calls in b.stages:
        for c in calls:
            if at == order.DIAGNOSERS:
                reads = {(node.name, node.depth) for rule in specs[c.key].resync
                         for node in walk(rule.when.root) if isinstance(node, Var)}
                call(c.key, {c.block.ports["Reset"]: z3.BoolVal(True),
                             **{c.block.inputs[(n, d)]: at_reset(n, d + (n in outputs))
                                for n, d in reads}})
    glob[up["FaultReset"]] = z3.BoolVal(False)
    fr = st[up["FaultReset"]]
    ref: dict[str, Any] = {}
    for k in scan_glob:
        ref[k] = _ite(fr, glob[k], scan_glob[k])
    for inst, after in insts.items():
        before = scan_insts.get(inst, after)
        for v, x in after.items():
            y = before[v]
            ref[f"{inst}.{v}"] = ([_ite(fr, a, c) for a, c in zip(x, y, strict=True)]
                                  if isinstance(x, list) else _ite(fr, x, y))
    for (n, d), var in history.items():
        ref[var] = shifted[(n, d)]
    ref["STARTED"] = z3.BoolVal(True)
    return ref, _invariant(ex, layout, st, history)

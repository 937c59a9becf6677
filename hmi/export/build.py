"""A project's safety layer as one PLC model: the POUs, the global variables and the task.

    FB_<P>_Memory       timers and observers                         (scan step 2)
    FB_<P>_Diag_<D>     each local diagnoser, with reconstruction    (steps 3-4)
    FB_<P>_Control      a stub for the functional control: yours     (step 5)
    FB_<P>_Filter       the safety filter                            (step 6)
    FB_Stopwatch        the stopwatch monitor of one task            (after the output scan)
    PRG_<P>_Safety      the cycle: calls them in the engine's order, keeps the previous
                        values (prev_x), applies a fault reset after the scan

The program keeps the project's values in global variables (the I/O at the plant map's
addresses, timers, observers, flags, filtered sensors, the program's outputs FOV_x) and the
history its function blocks read (`prev_x` = x at the previous scan). At the first scan the
history is the engine's initial image: inputs as first read, outputs at their safe values,
observers at their initial values, everything else 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from hmi.errors import ProjectError
from hmi.export import model as m
from hmi.export import source
from hmi.export.diagnoser_pou import MODE_CODES, build_diagnoser, ftc_mode
from hmi.export.filter_pou import POLICY_CODES, build_filter, max_distance, vectors_bound
from hmi.export.memory_pou import build_memory
from hmi.export.names import Scope
from hmi.export.stopwatch_pou import build_stopwatch
from hmi.export.views import Block, Durations, convert, view_name
from hmi.project.model import PlantAddress, Project
from hmi.timefmt import format_duration

STOPWATCH = "FB_Stopwatch"


@dataclass
class _Globals:
    """The global variables: every project value the safety layer reads or writes."""

    scope: Scope
    vars: list[m.Var] = field(default_factory=list)
    idents: dict[str, str] = field(default_factory=dict)  # project name -> identifier
    kinds: dict[str, str] = field(default_factory=dict)  # project name -> kind
    initial: dict[str, bool] = field(default_factory=dict)
    kind_of: dict[str, str] = field(default_factory=dict)  # identifier -> kind

    def add(self, name: str, kind: str, type_: m.PlcType = m.BOOL, initial: m.Expr | None = None,
            address: str | None = None, comment: str = "") -> str:
        ident = self.scope.take(name)
        self.idents[name] = ident
        self.kinds[name] = kind
        self.kind_of[ident] = kind
        self.vars.append(m.Var(ident, type_, initial, address, comment))
        return ident

    def name(self, name: str) -> m.Name:
        return m.Name(self.idents[name])


def build(project: Project) -> m.PlcProject:
    """The project's filter, diagnosers and monitors as one PLC model."""
    durations = Durations()
    prefix = Scope().take(source.name(project))
    pous = Scope()
    names = {
        "memory": pous.take(f"FB_{prefix}_Memory"),
        "filter": pous.take(f"FB_{prefix}_Filter"),
        "control": pous.take(f"FB_{prefix}_Control"),
        "program": pous.take(f"PRG_{prefix}_Safety"),
        "stopwatch": pous.take(STOPWATCH),
    }
    diag_names = {d.name: pous.take(f"FB_{prefix}_Diag_{d.name}")
                  for d in source.diagnosers(project)}
    bound = source.filter_bound(project)

    g = _Globals(pous.child())
    for v in source.inputs(project):
        g.add(v.name, "input", address=_address(project, v.address, "input"),
              comment=v.description)
    for v in source.outputs(project):
        g.add(v.name, "output", initial=m.BoolLit(True) if v.safe else None,
              address=_address(project, v.address, "output"), comment=v.description)
    for t in source.timers(project):
        g.add(t.name, "timer", comment=t.description)
    for o in source.observers(project):
        g.add(o.name, "observer", initial=m.BoolLit(True) if o.initial else None,
              comment=o.description)
        g.initial[o.name] = o.initial
    for d in source.diagnosers(project):
        for p in d.partitions:
            g.add(p.flag, "flag", comment=f"{d.name}: partition {p.name} distrusted")
    for d in source.diagnosers(project):
        for p in d.partitions:
            if p.filtered:
                g.add(p.filtered, "filtered", comment=f"{p.sensor} as the filter reads it")
    for v in source.outputs(project):
        g.add(f"FOV_{v.name}", "fov", comment=f"the program's {v.name}, before the filter")
    for t in source.monitors(project):
        g.add(t.label, "label", comment=f"stopwatch monitor of task {t.name}: fault")
    control = {key: g.add(key, "control", type_, initial, comment=comment) for key, type_,
               initial, comment in (
        ("FaultReset", m.BOOL, None, "set TRUE to reset; the safety program clears it"),
        ("FilterPolicy", m.INT, m.IntLit(POLICY_CODES[source.policy(project)]),
         "0 monitor, 1 block, 2 correct (other values: correct)"),
        ("DiagnosisMode", m.INT, m.IntLit(MODE_CODES["ftc"]),
         "0 FTC, 1 observe, 2 off (other values: FTC)"),
        ("Violations", m.bits_type(max(len(source.constraints(project)), 1)), None,
         "bit j: constraint j violated by the program's outputs"),
        ("FilterLatched", m.BOOL, None, "block policy: outputs latched safe"),
        ("FilterFallback", m.BOOL, None, "correct policy: no safe vector, safe state"))}
    registers = _registers(project, g)

    memory = build_memory(project, names["memory"], pous, durations)
    diagnosers = [build_diagnoser(project, d, diag_names[d.name], pous, durations)
                  for d in source.diagnosers(project)]
    filt = build_filter(project, names["filter"], pous, bound)
    stopwatch, ports = build_stopwatch(names["stopwatch"], pous)
    control_fb = _control_stub(names["control"], g)

    prog_scope = g.scope.child()
    instances: dict[str, str] = {}

    def instance(key: str) -> str:
        if key not in instances:
            instances[key] = prog_scope.take(key)
        return instances[key]

    history: dict[tuple[str, int], str] = {}

    def value(name: str, depth: int) -> m.Expr:
        """`name` as it stands `depth` scans back, at this point of the program."""
        if depth == 0:
            return g.name(name)
        for d in range(1, depth + 1):
            if (name, d) not in history:
                history[(name, d)] = prog_scope.take(view_name(name, d))
        return m.Name(history[(name, depth)])

    started = prog_scope.take("Started")
    body: list[m.Stmt] = []
    if memory is not None:
        inst = instance("Memory")
        body.append(m.Comment("2. Memory: timers and observers"))
        body.append(m.FbCall(inst, _wire(memory, value)))
        for name, out in memory.outputs.items():
            body.append(m.Assign(g.name(name), m.Member(m.Name(inst), out)))
    outputs_set = {v.name for v in source.outputs(project)}
    for spec, block in zip(source.diagnosers(project), diagnosers, strict=True):
        inst = instance(f"Diag_{spec.name}")
        body.append(m.Comment(f"3-4. Diagnoser {spec.name}: an output is read as written at "
                              "the previous scan"))
        body.append(m.FbCall(inst, (
            (block.ports["Reset"], m.FALSE), (block.ports["Mode"], g.name("DiagnosisMode")),
            *_wire(block, lambda n, d: value(n, d + (n in outputs_set))))))
        for name, out in block.outputs.items():
            body.append(m.Assign(g.name(name), m.Member(m.Name(inst), out)))
    ctl = instance("Control")
    body.append(m.Comment("5. The functional control (FB_..._Control: your program) writes "
                          "the FOV_ variables"))
    body.append(m.FbCall(ctl))
    finst = instance("Filter")
    body.append(m.Comment("6. The safety filter"))
    body.append(m.FbCall(finst, (
        (filt.ports["Reset"], m.FALSE), (filt.ports["Policy"], g.name("FilterPolicy")),
        (filt.ports["Ftc"], ftc_mode(g.name("DiagnosisMode"))),
        *((filt.ports[f"FOV_{v.name}"], g.name(f"FOV_{v.name}"))
          for v in source.outputs(project)),
        *_wire(filt, value))))
    for v in source.outputs(project):
        body.append(m.Assign(g.name(v.name), m.Member(m.Name(finst), filt.outputs[v.name])))
    for key, port in (("Violations", "Violations"), ("FilterLatched", "Latched"),
                      ("FilterFallback", "Fallback")):
        body.append(m.Assign(m.Name(control[key]), m.Member(m.Name(finst), filt.ports[port])))
    body += registers.write
    monitors = source.monitors(project)
    mon_insts = []
    if monitors:
        body.append(m.Comment("7. The output scan (the PLC writes the outputs after the "
                              "cycle); 8. the stopwatch monitors, on the I/O of this scan"))
    for task in monitors:
        inst = instance(f"Mon_{task.name}")
        mon_insts.append(inst)

        def cond(expr) -> m.Expr:
            return convert(expr.root, value)
        if task.interrupted is not None:
            suspend, resume = cond(task.interrupted), m.not_(cond(task.interrupted))
        elif task.interrupt is not None and task.resume is not None:
            suspend, resume = cond(task.interrupt), cond(task.resume)
        else:
            suspend = resume = m.FALSE
        what = f"the window of monitor {task.name!r}"
        body.append(m.FbCall(inst, (
            (ports["Reset"], m.FALSE), (ports["Start"], cond(task.start)),
            (ports["Finish"], cond(task.end)), (ports["Suspend"], suspend),
            (ports["Resume"], resume),
            (ports["Alpha"], durations.time(task.alpha_us, task.pos, what)),
            (ports["Beta"], durations.time(task.beta_us, task.pos, what)),
            (ports["Gamma"], durations.time(task.gamma_us, task.pos, what)))))
        body.append(m.Assign(g.name(task.label), m.Member(m.Name(inst), ports["Fault"])))

    reset: list[m.Stmt] = [m.Assign(g.name("FaultReset"), m.FALSE),
                           m.FbCall(finst, ((filt.ports["Reset"], m.TRUE),))]
    for spec, block in zip(source.diagnosers(project), diagnosers, strict=True):
        # The engine resets between scans, on the image of the scan just ended, which is
        # also the newest history entry: a read at depth d (outputs one deeper) is the
        # value d - 1 scans back, at least this scan's.
        def back(n: str, d: int) -> m.Expr:
            return value(n, max(d + (n in outputs_set) - 1, 0))
        reset.append(m.FbCall(instance(f"Diag_{spec.name}"), (
            (block.ports["Reset"], m.TRUE),
            *((block.inputs[key], back(*key)) for key in block.reset_reads))))
    for inst in mon_insts:
        reset.append(m.FbCall(inst, ((ports["Reset"], m.TRUE),)))
    body.append(m.Comment("A fault reset, after the scan (the engine resets between scans)"))
    body.append(m.if_(g.name("FaultReset"), *reset))

    shift: list[m.Stmt] = []
    for (name, depth), ident in sorted(history.items(), key=lambda kv: (kv[0][0], -kv[0][1])):
        source_value = g.name(name) if depth == 1 else m.Name(history[(name, depth - 1)])
        shift.append(m.Assign(m.Name(ident), source_value))
    body.append(m.Comment("The history: this scan's values become the previous ones"))
    body += shift
    init = [m.Assign(m.Name(ident), _initial(project, g, name))
            for (name, _depth), ident in history.items()]
    first = [m.Comment("The first scan: the history is the initial image (inputs as read, "
                       "outputs safe, observers initial, the rest 0)"),
             m.if_(m.not_(m.Name(started)), *init, m.Assign(m.Name(started), m.TRUE))]
    durations.raise_if_any()

    externals = tuple(m.Var(v.name, v.type) for v in (*registers.vars, *g.vars))
    locals_ = [m.Var(started, m.BOOL)]
    if memory is not None:
        locals_.append(m.Var(instances["Memory"], m.Derived(memory.pou.name)))
    for spec, block in zip(source.diagnosers(project), diagnosers, strict=True):
        locals_.append(m.Var(instances[f"Diag_{spec.name}"], m.Derived(block.pou.name)))
    locals_.append(m.Var(ctl, m.Derived(control_fb.name)))
    locals_.append(m.Var(finst, m.Derived(filt.pou.name)))
    locals_ += [m.Var(inst, m.Derived(stopwatch.name)) for inst in mon_insts]
    locals_ += [m.Var(ident, m.BOOL, comment=f"{name}, {depth} scan{'s' if depth > 1 else ''} "
                      "back") for (name, depth), ident in history.items()]
    program = m.Pou(names["program"], "program", (
        m.VarBlock("external", externals), m.VarBlock("local", tuple(locals_))),
        tuple(registers.read + first + body),
        "The safety layer's cycle, in the engine's order. Call it once per PLC cycle from "
        "the task; put the functional control in FB_..._Control.")

    period_ms = source.scan_period_us(project) // 1000
    if source.scan_period_us(project) % 1000:
        raise ProjectError.single(project.pos, "the scan period is not a whole number of "
                                  "milliseconds", "a scan period in whole milliseconds")
    config = m.Configuration(
        "Config0", "Res0", (m.VarBlock("global", (*registers.vars, *g.vars)),),
        (m.Task("MainTask", period_ms, 1),),
        (m.ProgramInstance("Safety", "MainTask", program.name),))
    all_pous = [p for p in (memory.pou if memory else None,) if p is not None]
    all_pous += [b.pou for b in diagnosers]
    all_pous += [control_fb, filt.pou]
    if monitors:
        all_pous.append(stopwatch)
    all_pous.append(program)
    summary = _summary(project, bound, all_pous, g, pous)
    header = _header(project, summary)
    symbols = {name: ident for name, ident in g.idents.items() if g.kinds[name] != "control"}
    symbols.update({key: ident for key, ident in control.items()})
    symbols.update(instances)
    for spec, block in zip(source.diagnosers(project), diagnosers, strict=True):
        symbols.update({f"{spec.name}.{lab}": block.ports[f"label:{lab}"]
                        for lab in spec.labels})
    return m.PlcProject(prefix, tuple(all_pous), config, header, tuple(summary), symbols)


def _wire(block: Block, value: Callable[[str, int], m.Expr]) -> list[tuple[str, m.Expr]]:
    return [(ident, value(name, depth)) for (name, depth), ident in block.inputs.items()]


def _initial(project: Project, g: _Globals, name: str) -> m.Expr:
    kind = g.kinds[name]
    if kind == "input":
        return g.name(name)
    if kind == "output":
        safe = next(v.safe for v in source.outputs(project) if v.name == name)
        return m.BoolLit(safe)
    if kind == "observer":
        return m.BoolLit(g.initial[name])
    return m.FALSE


def _address(project: Project, address: PlantAddress | None, kind: str) -> str | None:
    """The plant map's address as an IEC direct address (OpenPLC's Modbus mapping)."""
    if address is None or address.table in ("hr", "ir"):
        return None  # a register bit: the whole register is located, see _registers
    if (kind == "input") != (address.table == "di"):
        raise ProjectError.single(project.pos, f"an {kind} at {address}: the export maps "
                                  "inputs to di (%IX) and ir (%IW), outputs to coil (%QX) and "
                                  "hr (%QW)", "inputs on di or ir, outputs on coil or hr")
    area = "I" if kind == "input" else "Q"
    return f"%{area}X{address.index // 8}.{address.index % 8}"


@dataclass
class _Registers:
    vars: list[m.Var] = field(default_factory=list)
    read: list[m.Stmt] = field(default_factory=list)
    write: list[m.Stmt] = field(default_factory=list)


def _registers(project: Project, g: _Globals) -> _Registers:
    """Register bits (`ir:N.B` inputs, `hr:N.B` outputs): one located WORD per register."""
    regs = _Registers()
    words: dict[tuple[str, int], str] = {}
    for kind, variables in (("input", source.inputs(project)),
                            ("output", source.outputs(project))):
        for v in variables:
            a = source.address(v)
            if a is None or a.table not in ("hr", "ir"):
                continue
            if (kind == "input") != (a.table == "ir"):
                raise ProjectError.single(v.pos, f"an {kind} at {a}: the export maps input "
                                          "bits to ir (%IW) and output bits to hr (%QW)",
                                          "inputs on di or ir, outputs on coil or hr")
            key = (a.table, a.index)
            if key not in words:
                area = "I" if kind == "input" else "Q"
                words[key] = g.scope.take(f"{area}W{a.index}")
                regs.vars.append(m.Var(words[key], m.Elementary("WORD"), None,
                                       f"%{area}W{a.index}", f"{a.table} register {a.index}"))
            word = m.Name(words[key])
            mask = m.BitsLit(1 << (a.bit or 0), "WORD")
            if kind == "input":
                regs.read.append(m.Assign(g.name(v.name), m.Binary(
                    "<>", m.Binary("AND", word, mask), m.BitsLit(0, "WORD"))))
            else:
                regs.write.append(m.If(((g.name(v.name), (
                    m.Assign(word, m.Binary("OR", word, mask)),)),),
                    (m.Assign(word, m.Binary("AND", word, m.not_(mask))),)))
    return regs


def _control_stub(name: str, g: _Globals) -> m.Pou:
    """Where the functional control goes: it reads the I/O and safety values, writes FOV_."""
    readable = [v for v in g.vars if g.kind_of[v.name] in
                ("input", "timer", "observer", "flag", "filtered", "fov")]
    body: list[m.Stmt] = [m.Comment(
        "Replace this body with the functional control (or call your program from here). It "
        "reads the inputs, timers, observers, partition flags and filtered sensors (x_filter) "
        "and writes the program's outputs FOV_x; the filter decides what reaches the plant. "
        "As exported, every order is 0 (safe).")]
    body += [m.Assign(m.Name(v.name), m.FALSE) for v in readable if g.kind_of[v.name] == "fov"]
    return m.Pou(name, "functionBlock",
                 (m.VarBlock("external", tuple(m.Var(v.name, v.type) for v in readable)),),
                 tuple(body), "Scan step 5: the functional control (yours).")


def _summary(project: Project, bound: source.FilterBound, pous: list[m.Pou], g: _Globals,
             scope: Scope) -> list[str]:
    limit = max_distance(bound)
    constraints = source.constraints(project)
    combined = sum(c.kind == "combined" for c in constraints)
    vectors = vectors_bound(bound.combined_outputs, limit)
    lines = [f"{len(pous)} POUs: " + ", ".join(p.name for p in pous),
             f"task MainTask every {format_duration(source.scan_period_us(project))}",
             f"corrector: at most {vectors} vector{'s' if vectors != 1 else ''} tested per "
             f"scan ({bound.combined_outputs} outputs in combined constraints, search limit "
             f"{limit}: " + ("plchmi check's proven worst case" if bound.proven else
                             "every output, the static check being sampled")
             + f"), each a loop over the {len(constraints)} constraints ({combined} combined)"]
    renamed = {**scope.renamed, **g.scope.renamed}
    if renamed:
        lines.append("renamed for IEC 61131-3: " + ", ".join(
            f"{a} -> {b}" for a, b in sorted(renamed.items())))
    return lines


def _header(project: Project, summary: list[str]) -> str:
    files = ", ".join(source.source_files(project))
    return "\n".join([
        f"plchmi export of project {source.name(project)}: "
        f"{source.description(project)}".rstrip(": "),
        f"Generated from {files}; do not edit, export again.",
        "The safety filter, local diagnosers and stopwatch monitors, run in the engine's "
        "order by the program; see docs/plc-export.md.",
        *summary])

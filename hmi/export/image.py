"""The global variables: every project value the safety layer reads or writes, located.

The inputs and outputs sit at the plant map's addresses (OpenPLC's Modbus mapping: `di:N`
-> `%IX`, `coil:N` -> `%QX`, register bits through a located WORD `%IW` / `%QW`); then the
timers, observers, partition flags, filtered sensors, the program's outputs `FOV_x`, the
monitors' labels, and the operator's and the filter's status words.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hmi.errors import ProjectError
from hmi.export import model as m
from hmi.export import source
from hmi.export.diagnoser_pou import MODE_CODES
from hmi.export.names import Scope
from hmi.program.constraints import POLICY_CODES
from hmi.project.model import PlantAddress, Project, Variable

CONTROL = ("FaultReset", "FilterPolicy", "DiagnosisMode", "Violations", "FilterLatched",
           "FilterFallback")


@dataclass
class Globals:
    scope: Scope
    vars: list[m.Var] = field(default_factory=list)
    idents: dict[str, str] = field(default_factory=dict)  # project name -> identifier
    kinds: dict[str, str] = field(default_factory=dict)  # project name -> kind
    kind_of: dict[str, str] = field(default_factory=dict)  # identifier -> kind
    initial: dict[str, m.Expr] = field(default_factory=dict)  # the first scan's history
    registers: list[m.Var] = field(default_factory=list)  # located WORDs, read and written
    read: list[m.Stmt] = field(default_factory=list)  # register bits -> inputs
    write: list[m.Stmt] = field(default_factory=list)  # outputs -> register bits

    def add(self, name: str, kind: str, type_: m.PlcType = m.BOOL,
            initial: m.Expr | None = None, address: str | None = None,
            comment: str = "") -> str:
        ident = self.scope.take(name)
        self.idents[name] = ident
        self.kinds[name] = kind
        self.kind_of[ident] = kind
        self.vars.append(m.Var(ident, type_, initial, address, comment))
        return ident

    def name(self, name: str) -> m.Name:
        return m.Name(self.idents[name])

    @property
    def all(self) -> tuple[m.Var, ...]:
        return (*self.registers, *self.vars)


def build_globals(project: Project, scope: Scope) -> Globals:
    g = Globals(scope)
    for v in source.inputs(project):
        g.add(v.name, "input", address=_address(project, v, "input"), comment=v.description)
        g.initial[v.name] = g.name(v.name)  # as first read
    for v in source.outputs(project):
        safe = m.BoolLit(v.safe)
        g.add(v.name, "output", initial=safe if v.safe else None,
              address=_address(project, v, "output"), comment=v.description)
        g.initial[v.name] = safe
    for t in source.timers(project):
        g.add(t.name, "timer", comment=t.description)
    for o in source.observers(project):
        g.add(o.name, "observer", initial=m.TRUE if o.initial else None,
              comment=o.description)
        g.initial[o.name] = m.BoolLit(o.initial)
    for d in source.diagnosers(project):
        for p in d.partitions:
            g.add(p.flag, "flag", comment=f"{d.name}: partition {p.name} distrusted")
    for d in source.diagnosers(project):
        for p in d.partitions:
            if p.filtered:
                g.add(p.filtered, "filtered", comment=f"{p.sensor} as the filter reads it")
    for v in source.outputs(project):
        g.add(f"FOV_{v.name}", "fov", comment=f"the program's {v.name}, before the filter")
    for task in source.monitors(project):
        g.add(task.label, "label", comment=f"stopwatch monitor of task {task.name}: fault")
    for key, type_, initial, comment in (
            ("FaultReset", m.BOOL, None, "set TRUE to reset; the safety program clears it"),
            ("FilterPolicy", m.INT, m.IntLit(POLICY_CODES[source.policy(project)]),
             "0 monitor, 1 block, 2 correct (other values: correct)"),
            ("DiagnosisMode", m.INT, m.IntLit(MODE_CODES["ftc"]),
             "0 FTC, 1 observe, 2 off (other values: FTC)"),
            ("Violations", m.bits_type(max(len(source.constraints(project)), 1)), None,
             "bit j: constraint j violated by the program's outputs"),
            ("FilterLatched", m.BOOL, None, "block policy: outputs latched safe"),
            ("FilterFallback", m.BOOL, None, "correct policy: no safe vector, safe state")):
        g.add(key, "control", type_, initial, comment=comment)
    _registers(project, g)
    return g


def _address(project: Project, v: Variable, kind: str) -> str | None:
    """The plant map's bit address as an IEC direct address, or None (none, or a register)."""
    address = source.address(v)
    if address is None or address.table in ("hr", "ir"):
        return None
    if (kind == "input") != (address.table == "di"):
        raise _wrong_table(v, kind, address)
    area = "I" if kind == "input" else "Q"
    return f"%{area}X{address.index // 8}.{address.index % 8}"


def _wrong_table(v: Variable, kind: str, address: PlantAddress) -> ProjectError:
    return ProjectError.single(v.pos, f"{kind} {v.name!r} at {address}: the export maps inputs "
                               "to di (%IX) and ir (%IW), outputs to coil (%QX) and hr (%QW)",
                               "inputs on di or ir, outputs on coil or hr")


def _registers(project: Project, g: Globals) -> None:
    """Register bits (`ir:N.B` inputs, `hr:N.B` outputs): one located WORD per register."""
    words: dict[tuple[str, int], str] = {}
    for kind, variables in (("input", source.inputs(project)),
                            ("output", source.outputs(project))):
        for v in variables:
            a = source.address(v)
            if a is None or a.table not in ("hr", "ir"):
                continue
            if (kind == "input") != (a.table == "ir"):
                raise _wrong_table(v, kind, a)
            key = (a.table, a.index)
            if key not in words:
                area = "I" if kind == "input" else "Q"
                words[key] = g.scope.take(f"{area}W{a.index}")
                g.registers.append(m.Var(words[key], m.Elementary("WORD"), None,
                                         f"%{area}W{a.index}", f"{a.table} register {a.index}"))
            word = m.Name(words[key])
            mask = m.BitsLit(1 << (a.bit or 0), "WORD")
            if kind == "input":
                g.read.append(m.Assign(g.name(v.name), m.Binary(
                    "<>", m.Binary("AND", word, mask), m.BitsLit(0, "WORD"))))
            else:
                g.write.append(m.If(((g.name(v.name), (
                    m.Assign(word, m.Binary("OR", word, mask)),)),),
                    (m.Assign(word, m.Binary("AND", word, m.not_(mask))),)))

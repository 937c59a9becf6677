"""The declared names' sections: `inputs:`, `outputs:`, `memories:`, `timers:`, `observers:`.

I/O and memories are read first (their names are what everything else reads); timers and
observers are declared with them, then read once every name is known (hmi/project/loader.py
calls each pass). A variable's plant address (`di:0`, `hr:10.4`) is parsed here and checked
for clashes once the plant is known.
"""

from __future__ import annotations

import re

from hmi.errors import SourcePos
from hmi.project.model import (
    READ_ONLY_TABLES,
    TABLES,
    Observer,
    PlantAddress,
    Timer,
    Variable,
    VariableKind,
)
from hmi.project.reader import ProjectReader
from hmi.project.yamlnodes import NodeError, YNode
from hmi.timefmt import DURATION_HINT

# What each kind of expression may read. Outputs at the current scan are only known once the
# control law has run, so timers and observers (updated before it) read them through prev();
# so are partition flags and filtered sensors (hmi/project/diagnosers.py), computed after them.
GLOBAL_KINDS = {"input", "output", "timer", "observer", "flag", "filtered"}
PREV_ONLY = {"output", "flag", "filtered"}  # for timers and observers


def read_variables(reader: ProjectReader, key: str, kind: VariableKind,
                   allowed: set[str]) -> list[Variable]:
    out = []
    for name, node, kpos in reader.section_items(key):
        if not reader.declare(str(name), kind, kpos):
            continue
        var = reader.guard(lambda n=node, nm=str(name), p=kpos: _variable(
            reader, n, nm, kind, allowed, p))
        if var is not None:
            out.append(var)
    return out


def _variable(reader: ProjectReader, node: YNode, name: str, kind: VariableKind, allowed: set[str],
              kpos: SourcePos) -> Variable:
    """A declared variable, even when one of its fields is wrong: that field's error is
    reported and a neutral value stands in, so that the rest of the project is checked
    against a variable that exists (not "'C' is not an output" after "bad safe value")."""
    if node.kind == "scalar" and node.tag.endswith(":str"):
        return Variable(name, kind, node.value, pos=kpos)
    fields = node.check_keys(f"{kind} {name!r}", allowed)
    guard = reader.guard
    description = guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    safe = False
    if "safe" in fields:
        safe = guard(lambda: fields["safe"].as_bool("safe value"), False)
    if "initial" in fields:
        safe = guard(lambda: fields["initial"].as_bool("initial value"), False)
    address = None
    if "address" in fields:
        address = guard(lambda: parse_address(fields["address"], kind))
    device = guard(lambda: fields["device"].as_str("device")) if "device" in fields \
        else None
    fault = guard(lambda: fields["fault"].as_bool("fault"), False) if "fault" in fields \
        else False
    return Variable(name, kind, description, safe, address, kpos, device, bool(fault))


def declare_items(reader: ProjectReader, key: str, kind: str) -> list[tuple[str, YNode, SourcePos]]:
    declared = []
    for name, node, kpos in reader.section_items(key):
        if reader.declare(str(name), kind, kpos):
            declared.append((str(name), node, kpos))
    return declared


def read_timer(reader: ProjectReader, name: str, node: YNode, kpos: SourcePos) -> Timer | None:
    fields = reader.guard(lambda: node.check_keys(
        f"timer {name!r}", {"type", "input", "preset", "description"}, ["type", "input"]))
    if fields is None:
        return None
    if "preset" not in fields:
        reader.diag.error(node.pos, f"timer {name!r} has no preset",
                          "'preset:' with " + DURATION_HINT)
        return None
    kind = reader.guard(lambda: reader.choice(fields["type"], "timer type", ("TON", "TOF")))
    preset = reader.guard(lambda: fields["preset"].as_duration("preset"))
    description = reader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    expr = reader.expr(fields["input"], f"the input of timer {name!r}", GLOBAL_KINDS,
                       prev_only=PREV_ONLY)
    if kind is None or preset is None or expr is None:
        return None
    return Timer(name, kind, expr, preset, description, kpos)


def read_observer(reader: ProjectReader, name: str, node: YNode,
                  kpos: SourcePos) -> Observer | None:
    what = f"observer {name!r}"
    if node.kind == "scalar":
        expr = reader.expr(node, what, GLOBAL_KINDS, prev_only=PREV_ONLY)
        return Observer(name, "", expr=expr, pos=kpos) if expr else None
    fields = reader.guard(lambda: node.check_keys(
        what, {"expr", "set", "reset", "initial", "description"}))
    if fields is None:
        return None
    description = reader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    initial = reader.guard(lambda: fields["initial"].as_bool("initial"), False) \
        if "initial" in fields else False
    has_expr = "expr" in fields
    has_sr = "set" in fields or "reset" in fields
    if has_expr == has_sr:
        reader.diag.error(node.pos, f"{what} needs either 'expr' or a 'set'/'reset' pair",
                          "expr: ... , or set: ... and reset: ...")
        return None
    if has_expr:
        expr = reader.expr(fields["expr"], what, GLOBAL_KINDS, prev_only=PREV_ONLY)
        return Observer(name, description, expr=expr, initial=initial, pos=kpos) \
            if expr else None
    if "set" not in fields or "reset" not in fields:
        reader.diag.error(node.pos, f"{what} has a {'set' if 'set' in fields else 'reset'} "
                          "but no " + ("reset" if "set" in fields else "set"),
                          "both set: and reset:")
        return None
    set_ = reader.expr(fields["set"], f"the set of {what}", GLOBAL_KINDS,
                       prev_only=PREV_ONLY)
    reset = reader.expr(fields["reset"], f"the reset of {what}", GLOBAL_KINDS,
                        prev_only=PREV_ONLY)
    if set_ is None or reset is None:
        return None
    return Observer(name, description, set=set_, reset=reset, initial=initial, pos=kpos)


def check_addresses(reader: ProjectReader, inputs: list[Variable], outputs: list[Variable]) -> None:
    used: dict[tuple[str, int, int | None], Variable] = {}
    for var in (*inputs, *outputs):
        if var.address is None:
            continue
        key = (var.address.table, var.address.index, var.address.bit)
        if key in used:
            reader.diag.error(var.pos, f"{var.name!r} uses address {var.address}, already "
                              f"used by {used[key].name!r}", "one variable per address")
        whole = (var.address.table, var.address.index, None)
        if var.address.bit is not None and whole in used:
            reader.diag.error(var.pos, f"{var.name!r} overlaps {used[whole].name!r}",
                              "distinct addresses")
        used[key] = var
        if var.kind == "output" and var.address.table in READ_ONLY_TABLES:
            reader.diag.error(var.pos, f"output {var.name!r} is mapped to a read-only table "
                              f"({TABLES[var.address.table]})", "coil or hr")


_ADDRESS_RE = re.compile(r"(coil|di|hr|ir):([0-9]{1,6})(?:\.([0-9]{1,3}))?\Z")


def parse_address(node: YNode, kind: str) -> PlantAddress:
    text = node.as_str("address")
    match = _ADDRESS_RE.match(text.strip())
    hint = "TABLE:INDEX with TABLE coil, di, hr or ir (e.g. di:0, coil:3, hr:10.4)"
    if not match:
        raise NodeError(node.pos, f"address {text!r} is not a plant address", hint)
    table, index, bit = match.group(1), int(match.group(2)), match.group(3)
    if index > 65535:
        raise NodeError(node.pos, f"address index {index} is out of range", "0 to 65535")
    if table in ("hr", "ir"):
        if bit is None:
            raise NodeError(node.pos, f"a {TABLES[table]} address needs a bit number",
                            f"{table}:{index}.BIT with BIT 0 to 15")
        if int(bit) > 15:
            raise NodeError(node.pos, f"bit {bit} is out of range", "a bit from 0 to 15")
        return PlantAddress(table, index, int(bit))
    if bit is not None:
        raise NodeError(node.pos, f"a {TABLES[table]} address has no bit", f"{table}:{index}")
    return PlantAddress(table, index)

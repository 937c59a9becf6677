"""The `constraints:` section: the safety constraints, monomials the filter keeps false.

Each is a product of literals (000 eq. 1-2) with at least one output at the current scan;
one such output makes it simple (CSs), several combined (CSc).
"""

from __future__ import annotations

from hmi.errors import SourcePos
from hmi.limits import MAX_CONSTRAINTS
from hmi.logic.expr import NotMonomial, monomial_literals
from hmi.logic.names import NAME_HINT, name_problem
from hmi.project.model import (
    Constraint,
    ConstraintKind,
)
from hmi.project.reader import ProjectReader
from hmi.project.yamlnodes import YNode

# What a safety constraint may read: the filter knows no memories nor GRAFCET steps.
CONSTRAINT_KINDS = {"input", "output", "timer", "observer", "flag", "filtered"}


def parse_constraints(reader: ProjectReader) -> list[Constraint]:
    out: list[Constraint] = []
    seen: dict[str, SourcePos] = {}
    items = reader.section_items("constraints")
    if len(items) > MAX_CONSTRAINTS:
        reader.diag.error(reader.section_pos.get("constraints", items[0][2]),
                          f"the project has {len(items):,} safety constraints",
                          f"at most {MAX_CONSTRAINTS:,} (a limit of plchmi)")
        return out
    for name, node, kpos in items:
        name = str(name)
        if name in seen:
            continue  # YAML duplicate keys are already refused
        seen[name] = kpos
        problem = name_problem(name)
        if problem is not None:
            reader.diag.error(kpos, f"{name!r} is not a valid constraint name"
                              if problem == "is not a valid name"
                              else f"constraint name {name[:40]!r} {problem}", NAME_HINT)
            continue
        constraint = parse_constraint(reader, name, node, kpos)
        if constraint:
            out.append(constraint)
    return out


def parse_constraint(reader: ProjectReader, name: str, node: YNode,
                kpos: SourcePos) -> Constraint | None:
    what = f"constraint {name!r}"
    description = ""
    if node.kind == "map":
        fields = reader.guard(lambda: node.check_keys(what, {"expr", "description"},
                                                      ["expr"]))
        if fields is None:
            return None
        if "description" in fields:
            description = reader.guard(lambda: fields["description"].as_str("description"),
                                       "")
        enode = fields["expr"]
    else:
        enode = node
    expr = reader.expr(enode, what, CONSTRAINT_KINDS,
                       context="in a safety constraint (the filter may only read inputs, "
                       "outputs, timers, observers and flags)")
    if expr is None:
        return None
    try:
        literals = monomial_literals(expr)
    except NotMonomial as exc:
        reader.diag.error(expr.pos_of(exc.node), f"{what} is not a monomial: {exc.reason}",
                          "a product of literals such as 'C and not fsc and prev(C)'")
        return None
    if literals is None:
        reader.diag.error(expr.pos, f"{what} can never be true (it holds a variable and its "
                          "negation, or False), so it constrains nothing",
                          "a satisfiable product of literals")
        return None
    outputs = []
    for lit in literals:
        if lit.depth == 0 and reader.namespace.get(lit.name) == "output":
            outputs.append(lit.name)
    if not outputs:
        reader.diag.error(expr.pos, f"{what} has no output at the current scan, so the "
                          "filter cannot enforce it",
                          "at least one output without prev(), e.g. 'C and fsc'")
        return None
    kind: ConstraintKind = "simple" if len(outputs) == 1 else "combined"
    positive = None
    if kind == "simple":
        positive = next(lit.positive for lit in literals
                        if lit.depth == 0 and lit.name == outputs[0])
    return Constraint(name, expr, literals, kind, tuple(outputs), description, kpos,
                      positive)

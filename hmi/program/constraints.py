"""The safety constraints' test, written once: whether a candidate output vector violates
any constraint (stage 6's first question: most scans violate none, and then the filter has
nothing else to do; when one is violated, the filter's own handler reports and decides).

A constraint is a monomial that must be false (000 eq. 1-2): violated when every literal
is true. A literal over an output at this scan reads the candidate vector (``f[k]``), any
other (inputs, memories, earlier scans) the image and the history.
"""

from __future__ import annotations

from collections.abc import Sequence

from hmi.logic.expr import Var
from hmi.program import ir
from hmi.project.model import Constraint

CANDIDATE = ir.Local("f")


def lower_violated(constraints: Sequence[Constraint], outputs: Sequence[str]) -> ir.Value:
    """True when the candidate vector (the local ``f``, `outputs` in order) violates one of
    `constraints`, tested in order."""
    index = {name: k for k, name in enumerate(outputs)}
    terms: list[ir.Value] = []
    for c in constraints:
        parts: list[ir.Value] = []
        for lit in c.literals:
            read: ir.Value
            if lit.depth == 0 and lit.name in index:
                read = ir.Item(CANDIDATE, index[lit.name])
            else:
                read = ir.Test(Var(0, lit.name, lit.depth))
            parts.append(read if lit.positive else ir.Not(read))
        terms.append(ir.all_of(*parts))
    return ir.any_of(*terms)

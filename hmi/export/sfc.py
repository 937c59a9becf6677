"""The control law's GRAFCET as an IEC 61131-3 SFC network, for the PLCopen XML.

The cycle runs `FB_<P>_Control`, the law printed as Structured Text from the engine's scan
program (hmi/export/control_pou.py): that is the code that agrees with the engine scan by
scan. The same GRAFCET is also given to the PLC's editor as a chart, `SFC_<P>_Grafcet`, a
function block whose body is an SFC network (steps, transitions with their receptivities,
action blocks), so the sequence can be read and edited as a sequence there. It is not
instantiated in the cycle: two programs driving the same FOV would fight.

GRAFCET to SFC, element by element:

* a step is an SFC step of the same name, `initialStep` for the initial ones;
* a transition is an SFC transition whose condition is the receptivity in ST (inline): a
  step's time `X2.t >= 2s` is the SFC step's elapsed time `X2.T >= T#2s`; `prev(x)` and the
  edges read the value one scan back, an input of the block (`prev_x`), as the control FB
  does;
* several steps upstream of one transition meet in a simultaneous convergence, several
  downstream leave through a simultaneous divergence; a step with several transitions
  after it opens a selection divergence, one with several before it closes a selection
  convergence;
* a continuous action (N) is an N action on the output's FOV variable; a conditional one is
  an N action whose inline ST writes the FOV with its condition (GRAFCET's conditional action
  has no IEC qualifier of its own); a stored action is an S or R action on the output.

The IEC SFC's own evolution rules are GRAFCET's where the examples need them (all the
transitions that can fire fire together; one evolution per cycle); the engine's exact
semantics are the control FB's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hmi.export import model as m
from hmi.export.model import SfcAction, SfcChart, SfcStep, SfcTransition
from hmi.export.views import view_name
from hmi.logic.expr import And, Compare, Const, Duration, Node, Not, Or, StepTime, Var
from hmi.project.model import ControlLaw

IEC_COMPARE = {"<": "<", "<=": "<=", ">": ">", ">=": ">=", "==": "=", "!=": "<>"}


def build_chart(law: ControlLaw, pou_name: str, globals_: dict[str, str],
                types: dict[str, m.PlcType], time_text: Callable[[int], str]) -> SfcChart | None:
    """`law`'s GRAFCET as a chart (None: the law has none). `globals_`: project name -> the
    global's identifier; `time_text(us)` a TIME literal."""
    grafcet = law.grafcet
    if grafcet is None:
        return None
    externals: dict[str, None] = {}
    inputs: dict[str, None] = {}
    own: dict[str, None] = {}
    steps = {s.name for s in grafcet.steps}

    def name(ident: str, depth: int) -> str:
        if depth == 0:
            if ident in steps:
                return f"{ident}.X"
            found = globals_.get(ident)
            if found is None:  # a memory: the chart's own, as the control FB keeps it
                own[ident] = None
                return ident
            externals[found] = None
            return found
        found = view_name(globals_.get(ident, ident), depth)
        inputs[found] = None
        return found

    def text(node: Node) -> str:
        if isinstance(node, Const):
            return "TRUE" if node.value else "FALSE"
        if isinstance(node, Var):
            return name(node.name, node.depth)
        if isinstance(node, Not):
            return f"NOT {atom(node.operand)}"
        if isinstance(node, And):
            return " AND ".join(atom(op) for op in node.operands)
        if isinstance(node, Or):
            return " OR ".join(atom(op) for op in node.operands)
        if isinstance(node, Compare):
            return f"{text(node.left)} {IEC_COMPARE[node.op]} {text(node.right)}"
        if isinstance(node, StepTime):
            return f"{node.step}.T"
        if isinstance(node, Duration):
            return time_text(node.us)
        raise TypeError(f"not in a receptivity: {node!r}")

    def atom(node: Node) -> str:
        inner = text(node)
        return inner if isinstance(node, Var | Const | StepTime | Duration) else f"({inner})"

    def target(output: str) -> str:
        """The variable an action drives: an output's FOV, else (a memory) the chart's own."""
        key = f"FOV_{output}" if f"FOV_{output}" in globals_ else output
        found = globals_.get(key)
        if found is None:
            own[output] = None
            return output
        externals[found] = None
        return found

    out_steps = []
    for s in grafcet.steps:
        actions = []
        for a in s.actions:
            variable = target(a.target)
            condition = text(a.condition.root) if a.condition is not None else None
            actions.append(SfcAction(a.kind, variable, condition))
        out_steps.append(SfcStep(s.name, s.initial, tuple(actions),
                                 f"step {s.number}: {s.description}"))
    transitions = tuple(SfcTransition(t.sources, t.targets, text(t.receptivity.root),
                                      f"transition {t.number}: {t.description}")
                        for t in grafcet.transitions)
    blocks = (
        m.VarBlock("input", tuple(m.Var(i, m.BOOL, comment="the value one or more scans back")
                                  for i in inputs)),
        m.VarBlock("external", tuple(m.Var(e, types[e]) for e in externals)),
        m.VarBlock("local", tuple(m.Var(v, m.BOOL, comment="a memory the law keeps")
                                  for v in own)),
    )
    comment = (f"The GRAFCET of law {law.name!r} as an SFC chart, for the editor: the cycle "
               "runs the control FB (the same GRAFCET in ST, the engine's semantics); this "
               "block is not called.")
    return SfcChart(pou_name, tuple(out_steps), transitions, blocks, comment)


# --------------------------------------------------------------------------------------------
# The network: localIds and connections
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Element:
    """One element of the SFC network as the XML writes it: `kind` is step, transition,
    selectionDivergence, selectionConvergence, simultaneousDivergence,
    simultaneousConvergence or actionBlock; `inputs` the (localId, formalParameter) pairs
    it is connected to; `outputs` the number of branches it opens (divergences)."""

    kind: str
    local_id: int
    inputs: tuple[tuple[int, str], ...]
    name: str = ""  # a step's
    initial: bool = False
    condition: str = ""  # a transition's
    outputs: int = 1
    actions: tuple[SfcAction, ...] = ()
    comment: str = ""


def network(chart: SfcChart) -> list[Element]:
    """The chart's elements with their connections: each step's input from the transitions
    before it (through a selection convergence when several), each transition's input from
    the steps before it (through a simultaneous convergence when several), a step's output
    to several transitions through a selection divergence, a transition's to several steps
    through a simultaneous divergence."""
    ids = iter(range(1, 1_000_000))
    step_id = {s.name: next(ids) for s in chart.steps}
    trans_id = [next(ids) for _ in chart.transitions]
    after = {s.name: [k for k, t in enumerate(chart.transitions) if s.name in t.sources]
             for s in chart.steps}
    before = {s.name: [k for k, t in enumerate(chart.transitions) if s.name in t.targets]
              for s in chart.steps}
    elements: list[Element] = []
    # a step's way out toward transition k: the step, or its selection divergence's branch
    step_out: dict[tuple[str, int], tuple[int, str]] = {}
    for s in chart.steps:
        ks = after[s.name]
        if len(ks) > 1:
            div = next(ids)
            elements.append(Element("selectionDivergence", div, ((step_id[s.name], ""),),
                                    outputs=len(ks)))
            for branch, k in enumerate(ks):
                step_out[(s.name, k)] = (div, f"out{branch}")
        else:
            for k in ks:
                step_out[(s.name, k)] = (step_id[s.name], "")
    # a transition's way out toward step s: the transition, or its simultaneous divergence
    trans_out: dict[tuple[int, str], tuple[int, str]] = {}
    for k, t in enumerate(chart.transitions):
        if len(t.targets) > 1:
            div = next(ids)
            elements.append(Element("simultaneousDivergence", div, ((trans_id[k], ""),),
                                    outputs=len(t.targets)))
            for branch, target in enumerate(t.targets):
                trans_out[(k, target)] = (div, f"out{branch}")
        else:
            trans_out[(k, t.targets[0])] = (trans_id[k], "")
    for k, t in enumerate(chart.transitions):
        ins = tuple(step_out[(source, k)] for source in t.sources)
        if len(ins) > 1:
            conv = next(ids)
            elements.append(Element("simultaneousConvergence", conv, ins))
            ins = ((conv, ""),)
        elements.append(Element("transition", trans_id[k], ins, condition=t.condition,
                                comment=t.comment))
    for s in chart.steps:
        ins = tuple(trans_out[(k, s.name)] for k in before[s.name])
        if len(ins) > 1:
            conv = next(ids)
            elements.append(Element("selectionConvergence", conv, ins))
            ins = ((conv, ""),)
        elements.append(Element("step", step_id[s.name], ins, name=s.name, initial=s.initial,
                                comment=s.comment))
        if s.actions:
            elements.append(Element("actionBlock", next(ids), ((step_id[s.name], ""),),
                                    actions=s.actions))
    return sorted(elements, key=lambda e: e.local_id)

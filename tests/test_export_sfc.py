"""The control law's GRAFCET as an SFC body in the PLCopen XML, read back and checked.

The XML is read by the tests' own reader (tests/plcopen_reader.py, ElementTree: it follows
the network's connections through the divergences and convergences) and compared with the
project's GRAFCET, not with what the writer was given: the steps and the initial ones, each
transition's upstream and downstream steps, its receptivity (the ST condition evaluated by
the tests' interpreter's parser against the project's expression, on every assignment of the
values it reads, or 256 random ones when they are more than 8), and each step's actions.
"""

from __future__ import annotations

import itertools
import random
import re

import pytest

from hmi.export.build import build
from hmi.export.plcopen import write_plcopen
from hmi.logic.expr import And, Compare, Const, Duration, Node, Not, Or, StepTime, Var
from hmi.project.loader import load_project
from hmi.project.model import Project
from tests.conftest import PROJECTS
from tests.plcopen_reader import Chart, sfc_from_plcopen
from tests.stsubset import Parser, parse_time

EXAMPLES = ("cispi_valve", "conveyor_robot", "sorting", "palletizer", "cispi_subsystem")
OPS = {"<": lambda a, b: a < b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
       ">=": lambda a, b: a >= b, "==": lambda a, b: a == b, "!=": lambda a, b: a != b,
       "=": lambda a, b: a == b, "<>": lambda a, b: a != b}


def _project_value(node: Node, env: dict) -> object:
    """The project's expression on `env` ((name, depth) -> bool, step -> its time in us)."""
    if isinstance(node, Const):
        return node.value
    if isinstance(node, Var):
        return env[(node.name, node.depth)]
    if isinstance(node, Not):
        return not _project_value(node.operand, env)
    if isinstance(node, And):
        return all(_project_value(op, env) for op in node.operands)
    if isinstance(node, Or):
        return any(_project_value(op, env) for op in node.operands)
    if isinstance(node, Compare):
        return OPS[node.op](_project_value(node.left, env), _project_value(node.right, env))
    if isinstance(node, StepTime):
        return env[node.step]
    if isinstance(node, Duration):
        return node.us
    raise TypeError(node)


def _st_value(tree: tuple, env: dict) -> object:
    """An ST condition's tree (tests/stsubset.py's parser) on `env` (identifier -> value)."""
    kind = tree[0]
    if kind == "lit":
        return tree[3]
    if kind == "name":
        return env[tree[2]]
    if kind == "member":  # X2.T (elapsed time), X2.X (active)
        return env[f"{tree[2][2]}.{tree[3]}"]
    if kind == "not":
        return not _st_value(tree[2], env)
    if kind == "bin":
        a, b = _st_value(tree[3], env), _st_value(tree[4], env)
        if tree[2] == "AND":
            return a and b
        if tree[2] == "OR":
            return a or b
        return OPS[tree[2]](a, b)
    raise TypeError(tree)


def _reads(node: Node) -> tuple[set[tuple[str, int]], set[str], set[int]]:
    names: set[tuple[str, int]] = set()
    steps: set[str] = set()
    durations: set[int] = set()
    stack = [node]
    while stack:
        n = stack.pop()
        if isinstance(n, Var):
            names.add((n.name, n.depth))
        elif isinstance(n, StepTime):
            steps.add(n.step)
        elif isinstance(n, Duration):
            durations.add(n.us)
        stack += [getattr(n, f) for f in ("operand", "left", "right") if hasattr(n, f)]
        stack += list(getattr(n, "operands", ()))
    return names, steps, durations


def _same_condition(project_node: Node, st_text: str, ident: dict[str, str],
                    step_names: set[str]) -> bool:
    """The ST condition says what the project's expression says, on every assignment."""
    tree = Parser(st_text).expr()
    names, steps, durations = _reads(project_node)
    # a step time around each duration it is compared with
    times = sorted({0, *(d + e for d in durations for e in (-1000, 0, 1000) if d + e >= 0)})
    keys: list = sorted(names) + sorted(steps)
    domains = [[False, True]] * len(names) + [times] * len(steps)
    space = list(itertools.product(*domains)) if len(keys) <= 8 else [
        tuple(random.Random(k).choice(d) for d in domains) for k in range(256)]
    for values in space:
        env = dict(zip(keys, values, strict=True))
        st_env = {}
        for (name, depth), value in ((k, v) for k, v in env.items() if isinstance(k, tuple)):
            if name in step_names and depth == 0:
                st_env[f"{name.upper()}.X"] = value
            else:
                base = ident.get(name, name)  # (a memory keeps its name)
                st_env[(base if depth == 0 else f"PREV_{base}" if depth == 1
                        else f"PREV{depth}_{base}").upper()] = value
        for step in steps:
            st_env[f"{step.upper()}.T"] = env[step]
        if bool(_project_value(project_node, env)) != bool(_st_value(tree, st_env)):
            return False
    return True


def chart_mismatches(project: Project, chart: Chart, symbols: dict[str, str]) -> list[str]:
    """Everything in which the chart read back differs from the project's GRAFCET."""
    grafcet = project.control(None).grafcet
    assert grafcet is not None
    out = []
    want_steps = {s.name: s.initial for s in grafcet.steps}
    if chart.steps != want_steps:
        out.append(f"steps {chart.steps} != {want_steps}")
    step_names = set(want_steps)
    # (a step is read as Xn.X in ST: its activity)
    ident = {name: value for name, value in symbols.items()}
    got = list(chart.transitions)
    for t in grafcet.transitions:
        key = (frozenset(t.sources), frozenset(t.targets))
        match = next((g for g in got if (g[0], g[1]) == key
                      and _same_condition(t.receptivity.root, g[2], ident, step_names)),
                     None)
        if match is None:
            out.append(f"transition {t.number} ({t.receptivity.source}) not in the chart")
        else:
            got.remove(match)
    out += [f"a transition the GRAFCET has not: {g}" for g in got]
    for s in grafcet.steps:
        want = []
        for a in s.actions:
            variable = symbols.get(f"FOV_{a.target}", a.target)
            if a.condition is None:
                want.append((a.kind, variable))
            else:
                want.append((a.kind, f"{variable} := {a.condition.source}"))
        have = chart.actions.get(s.name, [])
        if len(have) != len(want):
            out.append(f"{s.name}: actions {have} != {want}")
            continue
        for (q, body), (wq, wbody), a in zip(have, want, s.actions, strict=True):
            if q != wq:
                out.append(f"{s.name}: qualifier {q} != {wq}")
            elif a.condition is None and body != wbody:
                out.append(f"{s.name}: action on {body}, not {wbody}")
            elif a.condition is not None:
                target, _, cond = body.partition(" := ")
                if target != symbols.get(f"FOV_{a.target}", a.target) or not _same_condition(
                        a.condition.root, cond.rstrip(";"), ident, step_names):
                    out.append(f"{s.name}: conditional action {body!r} != {wbody!r}")
    return out


def _chart(project: Project, xml: str) -> Chart:
    charts = sfc_from_plcopen(xml)
    (name,) = charts
    assert re.fullmatch(r"SFC_\w+_Grafcet", name)
    return charts[name]


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_xml_carries_the_grafcet_as_an_sfc_network(name):
    project = load_project(PROJECTS / name)
    model = build(project)
    chart = _chart(project, write_plcopen(model))
    assert chart_mismatches(project, chart, model.symbols) == []
    grafcet = project.control(None).grafcet
    assert len(chart.transitions) == len(grafcet.transitions)
    assert any(chart.steps.values())


def test_a_wrong_chart_is_told_apart():
    """The check can fail: a receptivity's AND read as OR, a connection moved to another
    step, an initial step dropped, an action's qualifier changed: each is a mismatch."""
    project = load_project(PROJECTS / "conveyor_robot")
    model = build(project)
    xml = write_plcopen(model)
    sfc = xml.index("<SFC>")
    head, body = xml[:sfc], xml[sfc:]
    tampered = [
        body.replace("<![CDATA[B AND e]]>", "<![CDATA[B OR e]]>", 1),
        re.sub(r'(<step localId="3" name="X1">.*?<connection refLocalId=")(\d+)',
               lambda mt: mt.group(1) + "8", body, count=1, flags=re.S),
        body.replace(' initialStep="true"', "", 1),
        body.replace('qualifier="N"', 'qualifier="S"', 1),
    ]
    for wrong in tampered:
        assert wrong != body
        assert chart_mismatches(project, _chart(project, head + wrong), model.symbols)


def test_a_step_time_and_an_edge_are_read_back():
    """The valve's `X0.t >= 1s` is the SFC step's elapsed time X0.T >= T#1s; the sorting
    cell's `fall(tt_back)` reads the value one scan back, an input of the chart."""
    for name, wanted in (("cispi_valve", "X0.T >= T#1s"), ("sorting", "PREV_")):
        project = load_project(PROJECTS / name)
        chart = _chart(project, write_plcopen(build(project)))
        assert any(wanted.upper() in t[2].upper() for t in chart.transitions), chart
    assert parse_time("T#1s") == 1_000_000


@pytest.mark.parametrize("name", EXAMPLES)
def test_an_independent_reader_of_the_schema_reads_the_whole_file(name):
    """`plcopen` (PyPI: the TC6 2.01 schema's classes, generated by xsdata) reads every
    exported file strictly (an element or attribute the schema does not have is an error),
    and finds in the chart what the tests' reader found: the steps, the initial ones, the
    transitions' conditions, the actions."""
    from plcopen import Project as PlcopenProject
    from xsdata.formats.dataclass.parsers import XmlParser
    from xsdata.formats.dataclass.parsers.config import ParserConfig

    project = load_project(PROJECTS / name)
    model = build(project)
    xml = write_plcopen(model)
    parser = XmlParser(config=ParserConfig(fail_on_unknown_properties=True,
                                           fail_on_unknown_attributes=True,
                                           fail_on_converter_warnings=True))
    read = parser.from_string(xml, PlcopenProject)
    pous = {pou.name: pou for pou in read.types.pous.pou}
    assert {p.name for p in model.pous} | {c.name for c in model.charts} == set(pous)
    chart = _chart(project, xml)
    (sfc,) = [pou.body[0].sfc for pou in pous.values() if pou.body[0].sfc is not None]
    assert {s.name: bool(s.initial_step) for s in sfc.step} == chart.steps
    conditions = sorted(t.condition.inline.st.w3_org_1999_xhtml_element.text
                        for t in sfc.transition)
    assert conditions == sorted(t[2] for t in chart.transitions)
    actions = sorted((a.qualifier.value, a.reference.name if a.reference is not None else
                      a.inline.st.w3_org_1999_xhtml_element.text)
                     for block in sfc.action_block for a in block.action)
    assert actions == sorted(a for acts in chart.actions.values() for a in acts)

"""The PLC model as PLCopen TC6 XML (version 2.01), which CODESYS, TwinCAT and OpenPLC's
editor import: the POUs with their interfaces and Structured Text bodies, the global
variables at the plant map's addresses, the configuration with its task.

Written by hand rather than through ElementTree, because bodies go in CDATA sections (what
the importers expect and a reader can read) and the output must be byte-for-byte stable.
The bodies are the Structured Text writer's (hmi.export.st), so both targets carry the very
same code. The file header's date is fixed, for the same reason.
"""

from __future__ import annotations

from xml.sax.saxutils import escape, quoteattr

from hmi.export import model as m
from hmi.export.sfc import network
from hmi.export.st import ascii_text, body_text, expr_text, time_text

NAMESPACE = "http://www.plcopen.org/xml/tc6_0201"
XHTML = "http://www.w3.org/1999/xhtml"
CREATED = "2000-01-01T00:00:00"  # fixed: two exports of one project are identical files
LISTS = {"input": "inputVars", "output": "outputVars", "inout": "inOutVars",
         "external": "externalVars", "local": "localVars", "global": "globalVars"}


def _cdata(text: str) -> str:
    return "<![CDATA[" + text.replace("]]>", "]]]]><![CDATA[>") + "]]>"


def _attr(value: str | int) -> str:
    return quoteattr(str(value))


class _Xml:
    def __init__(self) -> None:
        self.lines: list[str] = ['<?xml version="1.0" encoding="utf-8"?>']
        self.depth = 0

    def line(self, text: str) -> None:
        self.lines.append("  " * self.depth + text)

    def open(self, text: str) -> None:
        self.line(text)
        self.depth += 1

    def close(self, tag: str) -> None:
        self.depth -= 1
        self.line(f"</{tag}>")

    def documentation(self, text: str) -> None:
        if text:
            self.line(f"<documentation><xhtml:p>{_cdata(ascii_text(text))}</xhtml:p>"
                      "</documentation>")


def _type(x: _Xml, t: m.PlcType) -> None:
    if isinstance(t, m.Array):
        x.open("<type>")
        x.open("<array>")
        x.line(f"<dimension lower={_attr(t.lower)} upper={_attr(t.upper)}/>")
        x.line(f"<baseType><{t.element.name}/></baseType>")
        x.close("array")
        x.close("type")
    elif isinstance(t, m.Derived):
        x.line(f"<type><derived name={_attr(t.name)}/></type>")
    else:
        x.line(f"<type><{t.name}/></type>")


def _variable(x: _Xml, v: m.Var) -> None:
    address = f" address={_attr(v.address)}" if v.address else ""
    x.open(f"<variable name={_attr(v.name)}{address}>")
    _type(x, v.type)
    if isinstance(v.initial, m.ArrayInit):
        x.open("<initialValue>")
        x.open("<arrayValue>")
        for value in v.initial.values:
            x.line(f"<value><simpleValue value={_attr(expr_text(value))}/></value>")
        x.close("arrayValue")
        x.close("initialValue")
    elif v.initial is not None:
        x.line(f"<initialValue><simpleValue value={_attr(expr_text(v.initial))}/>"
               "</initialValue>")
    x.documentation(v.comment)
    x.close("variable")


def _var_lists(x: _Xml, blocks: tuple[m.VarBlock, ...]) -> None:
    for b in blocks:
        if not b.vars:
            continue
        constant = ' constant="true"' if b.constant else ""
        x.open(f"<{LISTS[b.section]}{constant}>")
        for v in b.vars:
            _variable(x, v)
        x.close(LISTS[b.section])


def _pou_head(x: _Xml, name: str, kind: str, blocks: tuple[m.VarBlock, ...]) -> None:
    """A POU's opening, its interface and the opening of its body."""
    x.open(f"<pou name={_attr(name)} pouType={_attr(kind)}>")
    x.open("<interface>")
    _var_lists(x, blocks)
    x.close("interface")
    x.open("<body>")


def _pou(x: _Xml, p: m.Pou) -> None:
    _pou_head(x, p.name, p.kind, p.blocks)
    x.line(f"<ST><xhtml:p>{_cdata(chr(10).join(body_text(p.body)))}</xhtml:p></ST>")
    x.close("body")
    x.documentation(p.comment)
    x.close("pou")


def _connections(x: _Xml, inputs: tuple[tuple[int, str], ...], apart: bool) -> None:
    """An element's inputs: one connectionPointIn holding them (a step, a transition), or
    one per branch (`apart`: a convergence)."""
    groups = [(i,) for i in inputs] if apart else [inputs]
    for group in groups:
        x.open("<connectionPointIn>")
        for ref, formal in group:
            parameter = f" formalParameter={_attr(formal)}" if formal else ""
            x.line(f"<connection refLocalId={_attr(ref)}{parameter}/>")
        x.close("connectionPointIn")


def _chart(x: _Xml, chart: m.SfcChart) -> None:
    """A GRAFCET as a POU whose body is an SFC network (hmi/export/sfc.py)."""
    _pou_head(x, chart.name, "functionBlock", chart.blocks)
    x.open("<SFC>")
    for e in network(chart):
        position = f'<position x="0" y={_attr(40 * e.local_id)}/>'
        if e.kind == "step":
            initial = ' initialStep="true"' if e.initial else ""
            x.open(f"<step localId={_attr(e.local_id)} name={_attr(e.name)}{initial}>")
            x.line(position)
            if e.inputs:
                _connections(x, e.inputs, apart=False)
            x.line('<connectionPointOut formalParameter=""/>')
            x.documentation(e.comment)
            x.close("step")
        elif e.kind == "transition":
            x.open(f"<transition localId={_attr(e.local_id)}>")
            x.line(position)
            _connections(x, e.inputs, apart=False)
            x.line("<connectionPointOut/>")
            x.open("<condition>")
            x.line(f'<inline name=""><ST><xhtml:p>{_cdata(e.condition)}</xhtml:p></ST></inline>')
            x.close("condition")
            x.documentation(e.comment)
            x.close("transition")
        elif e.kind == "actionBlock":
            x.open(f"<actionBlock localId={_attr(e.local_id)}>")
            x.line(position)
            _connections(x, e.inputs, apart=False)
            for k, a in enumerate(e.actions):
                x.open(f"<action localId={_attr(k)} qualifier={_attr(a.qualifier)}>")
                x.line('<relPosition x="0" y="0"/>')
                if a.condition is None:
                    x.line(f"<reference name={_attr(a.variable)}/>")
                else:
                    x.line(f"<inline><ST><xhtml:p>{_cdata(f'{a.variable} := {a.condition};')}"
                           "</xhtml:p></ST></inline>")
                x.close("action")
            x.close("actionBlock")
        else:  # the divergences and convergences
            x.open(f"<{e.kind} localId={_attr(e.local_id)}>")
            x.line(position)
            _connections(x, e.inputs, apart=e.kind.endswith("Convergence"))
            if e.kind.endswith("Divergence"):
                for branch in range(e.outputs):
                    x.line(f"<connectionPointOut formalParameter={_attr(f'out{branch}')}/>")
            else:
                x.line("<connectionPointOut/>")
            x.close(e.kind)
    x.close("SFC")
    x.close("body")
    x.documentation(chart.comment)
    x.close("pou")


def write_plcopen(project: m.PlcProject) -> str:
    x = _Xml()
    x.open(f"<project xmlns={_attr(NAMESPACE)} xmlns:xhtml={_attr(XHTML)}>")
    x.line(f"<fileHeader companyName=\"plchmi\" productName=\"plchmi export\" "
           f"productVersion=\"1\" creationDateTime={_attr(CREATED)}/>")
    x.open(f"<contentHeader name={_attr(project.name)} modificationDateTime="
           f"{_attr(CREATED)}>")
    x.line(f"<Comment>{escape(ascii_text(project.comment))}</Comment>")
    x.open("<coordinateInfo>")
    for language in ("fbd", "ld", "sfc"):
        x.line(f'<{language}><scaling x="1" y="1"/></{language}>')
    x.close("coordinateInfo")
    x.close("contentHeader")
    x.open("<types>")
    x.line("<dataTypes/>")
    x.open("<pous>")
    for p in project.pous:
        _pou(x, p)
    for chart in project.charts:
        _chart(x, chart)
    x.close("pous")
    x.close("types")
    c = project.configuration
    x.open("<instances>")
    x.open("<configurations>")
    x.open(f"<configuration name={_attr(c.name)}>")
    x.open(f"<resource name={_attr(c.resource)}>")
    for t in c.tasks:
        x.open(f"<task name={_attr(t.name)} priority={_attr(t.priority)} "
               f"interval={_attr(time_text(t.interval_ms))}>")
        for i in c.instances:
            if i.task == t.name:
                x.line(f"<pouInstance name={_attr(i.name)} typeName={_attr(i.program)}/>")
        x.close("task")
    x.close("resource")
    _var_lists(x, c.globals)
    x.close("configuration")
    x.close("configurations")
    x.close("instances")
    x.close("project")
    return "\n".join(x.lines) + "\n"

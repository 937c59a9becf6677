"""Read an exported PLCopen TC6 XML file back into Structured Text, for the tests.

The tests' own reader (ElementTree, not the writer's code): it rebuilds each POU from its
interface and its ST body, and the configuration from its task, instances and globals, so the
XML target can be compared with the ST target and run in the tests' interpreter.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

NS = {"p": "http://www.plcopen.org/xml/tc6_0201", "x": "http://www.w3.org/1999/xhtml"}
SECTIONS = {"inputVars": "VAR_INPUT", "outputVars": "VAR_OUTPUT", "localVars": "VAR",
            "externalVars": "VAR_EXTERNAL", "inOutVars": "VAR_IN_OUT",
            "globalVars": "VAR_GLOBAL"}
KINDS = {"functionBlock": "FUNCTION_BLOCK", "program": "PROGRAM"}


def _type(node: ET.Element) -> str:
    (inner,) = list(node)
    tag = inner.tag.split("}")[1]
    if tag == "derived":
        return inner.attrib["name"]
    if tag == "array":
        dim = inner.find("p:dimension", NS)
        (base,) = list(inner.find("p:baseType", NS))
        return (f"ARRAY[{dim.attrib['lower']}..{dim.attrib['upper']}] OF "
                f"{base.tag.split('}')[1]}")
    return tag


def _variable(v: ET.Element) -> str:
    address = f" AT {v.attrib['address']}" if "address" in v.attrib else ""
    text = f"{v.attrib['name']}{address} : {_type(v.find('p:type', NS))}"
    init = v.find("p:initialValue", NS)
    if init is not None:
        simple = init.find("p:simpleValue", NS)
        if simple is not None:
            text += f" := {simple.attrib['value']}"
        else:
            values = [s.attrib["value"] for s in init.findall("p:arrayValue/p:value/"
                                                              "p:simpleValue", NS)]
            text += " := [" + ", ".join(values) + "]"
    return text + ";"


def _lists(parent: ET.Element, indent: str = "") -> list[str]:
    lines = []
    for child in parent:
        tag = child.tag.split("}")[1]
        if tag not in SECTIONS:
            continue
        constant = " CONSTANT" if child.attrib.get("constant") == "true" else ""
        lines.append(indent + SECTIONS[tag] + constant)
        lines += [indent + "    " + _variable(v) for v in child.findall("p:variable", NS)]
        lines.append(indent + "END_VAR")
    return lines


def st_from_plcopen(text: str) -> str:
    root = ET.fromstring(text)
    lines: list[str] = []
    for pou in root.findall("p:types/p:pous/p:pou", NS):
        if pou.find("p:body/p:SFC", NS) is not None:
            continue  # a chart for the editor (read by sfc_from_plcopen), not in the cycle
        word = KINDS[pou.attrib["pouType"]]
        lines.append(f"{word} {pou.attrib['name']}")
        lines += _lists(pou.find("p:interface", NS))
        lines.append(pou.find("p:body/p:ST/x:p", NS).text or "")
        lines.append(f"END_{word}")
        lines.append("")
    config = root.find("p:instances/p:configurations/p:configuration", NS)
    resource = config.find("p:resource", NS)
    lines.append(f"CONFIGURATION {config.attrib['name']}")
    lines += _lists(config, "    ")
    lines.append(f"    RESOURCE {resource.attrib['name']} ON PLC")
    for task in resource.findall("p:task", NS):
        lines.append(f"        TASK {task.attrib['name']}(INTERVAL := "
                     f"{task.attrib['interval']}, PRIORITY := {task.attrib['priority']});")
        for inst in task.findall("p:pouInstance", NS):
            lines.append(f"        PROGRAM {inst.attrib['name']} WITH {task.attrib['name']} : "
                         f"{inst.attrib['typeName']};")
    lines += ["    END_RESOURCE", "END_CONFIGURATION"]
    return "\n".join(lines) + "\n"


def code_only(st_text: str) -> list[str]:
    """The text's lines without comments and blank lines: what two targets must share."""
    out = []
    for line in st_text.splitlines():
        line = re.sub(r"\s*\(\*.*?\*\)", "", line).rstrip()
        if line.strip():
            out.append(line.strip())
    return out


@dataclass(frozen=True)
class Chart:
    """An SFC body read back: steps (name -> initial), transitions (sources, targets,
    condition in ST, in file order), actions (step -> (qualifier, variable or inline ST))."""

    steps: dict[str, bool]
    transitions: list[tuple[frozenset[str], frozenset[str], str]]
    actions: dict[str, list[tuple[str, str]]]


def sfc_from_plcopen(text: str) -> dict[str, Chart]:
    """Every POU with an SFC body, its network followed through the connections."""
    root = ET.fromstring(text)
    return {pou.attrib["name"]: _read_chart(pou.find("p:body/p:SFC", NS))
            for pou in root.findall("p:types/p:pous/p:pou", NS)
            if pou.find("p:body/p:SFC", NS) is not None}


def _read_chart(sfc: ET.Element) -> Chart:
    """A transition's sources are the steps reached going back through divergences and
    convergences, its targets the steps whose inputs lead back to it."""
    elements = {e.attrib["localId"]: e for e in sfc}
    kind = {i: e.tag.split("}")[1] for i, e in elements.items()}

    def inputs(e: ET.Element) -> list[str]:
        return [c.attrib["refLocalId"] for c in e.findall("p:connectionPointIn/p:connection", NS)]

    def before(i: str, wanted: str, stop: str) -> set[str]:
        """The elements of kind `wanted` an element's inputs come from, through the
        divergences and convergences (not through `stop`)."""
        out: set[str] = set()
        for ref in inputs(elements[i]):
            if kind[ref] == wanted:
                out.add(ref)
            elif kind[ref] != stop:
                out |= before(ref, wanted, stop)
        return out

    step_of = {i: e.attrib["name"] for i, e in elements.items() if kind[i] == "step"}
    steps = {e.attrib["name"]: e.attrib.get("initialStep") == "true"
             for i, e in elements.items() if kind[i] == "step"}
    transitions = []
    for i, e in elements.items():
        if kind[i] != "transition":
            continue
        sources = frozenset(step_of[j] for j in before(i, "step", "transition"))
        targets = frozenset(step_of[j] for j in step_of if i in before(j, "transition", "step"))
        condition = e.find("p:condition/p:inline/p:ST/x:p", NS).text or ""
        transitions.append((sources, targets, condition))
    actions: dict[str, list[tuple[str, str]]] = {}
    for i, e in elements.items():
        if kind[i] != "actionBlock":
            continue
        (step_id,) = inputs(e)
        for a in e.findall("p:action", NS):
            ref = a.find("p:reference", NS)
            body = (ref.attrib["name"] if ref is not None
                    else a.find("p:inline/p:ST/x:p", NS).text or "")
            actions.setdefault(step_of[step_id], []).append((a.attrib["qualifier"], body))
    return Chart(steps, transitions, actions)

"""Read an exported PLCopen TC6 XML file back into Structured Text, for the tests.

The tests' own reader (ElementTree, not the writer's code): it rebuilds each POU from its
interface and its ST body, and the configuration from its task, instances and globals, so the
XML target can be compared with the ST target and run in the tests' interpreter.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

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

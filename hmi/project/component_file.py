"""A component file read and validated on its own (hmi/project/components.py instantiates it).

A component is checked once, whatever the number of its instances, so that an error in it is
reported once, at its line and column: its structure, its names (valid, unique, not reserved),
every expression (it parses and reads only the component's parameters and own names: nothing
leaks in from a project, and no GRAFCET step, which belongs to a project's control law), the
`{placeholders}` of its descriptions and label texts, and that its explanations are about its
own constraints, labels and partitions. What depends on a binding (kinds, monomials, the
diagnoser's determinism...) is left to the loader, per instance.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.errors import ProjectError, SourcePos, display_path
from hmi.logic.expr import ExprError, StepTime, Var, parse_expr, walk
from hmi.logic.names import NAME_RE, RESERVED, STEP_RE
from hmi.project.model import FLAG_PREFIX, ComponentDef, Parameter
from hmi.project.yamlnodes import NodeError, YNode, expr_start, text_start

if TYPE_CHECKING:
    from hmi.project.reader import ProjectReader

COMPONENT_KEYS = {"component", "description", "parameters", "timers", "observers",
                  "constraints", "diagnoser", "explanations"}
PARAMETER_KINDS = ("input", "output")
EXPLANATION_KINDS = ("constraints", "labels", "partitions")
PLACEHOLDER = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")


def read_component(loader: ProjectReader, path: Path) -> ComponentDef | None:
    """Read and validate one component file; report its errors once, return None if any."""
    from hmi.project.yamlcompose import load_yaml  # PyYAML: not for a project read back

    display = display_path(path)
    try:
        root = load_yaml(path, display)
    except ProjectError as exc:
        loader.diag.items.extend(exc.errors)
        return None
    before = len(loader.diag.errors)
    guard = loader.guard
    fields = guard(lambda: root.check_keys("a component file", COMPONENT_KEYS,
                                           ["component", "parameters"]))
    if fields is None:
        return None
    cname = guard(lambda: fields["component"].as_str("component"), "") or display
    description = guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    params = _parameters(loader, fields["parameters"])
    local: dict[str, SourcePos] = {p.name: p.pos for p in params.values()}
    items: dict[str, list[str]] = {}
    for key in ("timers", "observers", "constraints"):
        items[key] = _item_names(loader, fields.get(key), key, local,
                                 declare=key != "constraints")
    partitions, labels = _diagnoser_shape(loader, fields.get("diagnoser"), params)
    comp = ComponentDef(cname, description, display, path, params, tuple(items["timers"]),
                        tuple(items["observers"]), tuple(items["constraints"]),
                        tuple(partitions), tuple(labels))
    _check_expressions(loader, fields, comp)
    _check_placeholders(loader, fields, comp)
    if "explanations" in fields:
        _check_explanation_names(loader, fields["explanations"], comp)
    return comp if len(loader.diag.errors) == before else None


def _valid_name(loader: ProjectReader, name: str, pos: SourcePos, what: str) -> bool:
    if not NAME_RE.match(name):
        loader.diag.error(pos, f"{name!r} is not a valid {what} name",
                          "letters, digits and _, not starting with a digit")
    elif name in RESERVED:
        loader.diag.error(pos, f"{name!r} is a reserved word", "another name")
    elif STEP_RE.match(name):
        loader.diag.error(pos, f"{name!r} looks like a GRAFCET step variable",
                          "a name not of the form X<number>")
    elif name.startswith(FLAG_PREFIX):
        loader.diag.error(pos, f"{name!r} starts with def_, reserved for partition flags",
                          "another name")
    else:
        return True
    return False


def _parameters(loader: ProjectReader, node: YNode) -> dict[str, Parameter]:
    mapping = loader.guard(lambda: node.as_map("parameters"), {})
    out: dict[str, Parameter] = {}
    for name, pnode in mapping.items():
        name = str(name)
        kpos = node.key_pos.get(name, node.pos)
        if not _valid_name(loader, name, kpos, "parameter"):
            continue
        fields = loader.guard(lambda n=pnode, nm=name: n.check_keys(
            f"parameter {nm!r}", {"kind", "description"}, ["kind"]))
        if fields is None:
            continue
        kind = loader.guard(lambda f=fields: f["kind"].as_str("kind"))
        if kind is not None and kind not in PARAMETER_KINDS:
            loader.diag.error(fields["kind"].pos, f"parameter kind {kind!r} is not known",
                              "input or output")
            continue
        description = loader.guard(lambda f=fields: f["description"].as_str("description"),
                                   "") if "description" in fields else ""
        if kind is not None:
            out[name] = Parameter(name, kind, description, kpos)
    if not mapping and node.kind == "map":
        loader.diag.error(node.pos, "the component has no parameter",
                          "parameters: {name: {kind: input, description: ...}}")
    return out


def _item_names(loader: ProjectReader, node: YNode | None, key: str,
                local: dict[str, SourcePos], declare: bool) -> list[str]:
    """The names of a timers / observers / constraints map, checked like a project's."""
    if node is None:
        return []
    mapping = loader.guard(lambda: node.as_map(key), {})
    names = []
    for name in mapping:
        name = str(name)
        kpos = node.key_pos.get(name, node.pos)
        if not _valid_name(loader, name, kpos, key[:-1]):
            continue
        if declare:
            if name in local:
                loader.diag.error(kpos, f"{name!r} is already declared in this component at "
                                  f"{local[name]}", "unique names across parameters, timers "
                                  "and observers")
                continue
            local[name] = kpos
        names.append(name)
    return names


def _diagnoser_shape(loader: ProjectReader, node: YNode | None,
                     params: dict[str, Parameter]
                     ) -> tuple[list[tuple[str, str | None]], list[str]]:
    """The partitions (and the formal sensor of each) and labels of the component's
    diagnoser; the rest of it is checked per instance by hmi/project/diagnosers.py."""
    if node is None:
        return [], []
    fields = loader.guard(lambda: node.as_map("the diagnoser of a component"))
    if fields is None:
        return [], []
    if "device" in fields:
        loader.diag.error(node.key_pos.get("device", node.pos), "a component's diagnoser "
                          "takes its device from each instance",
                          "device: in the project's components: entry")
    labels = []
    lnode = fields.get("labels")
    if lnode is not None and lnode.kind == "map":
        labels = [str(lab) for lab in lnode.value]
    partitions: list[tuple[str, str | None]] = []
    pnode = fields.get("partitions")
    if pnode is None:
        loader.diag.error(node.pos, "the component's diagnoser has no partitions",
                          "partitions: {...}")
        return [], labels
    pmap = loader.guard(lambda: pnode.as_map("partitions"), {})
    for pname, part in pmap.items():
        pname = str(pname)
        if not _valid_name(loader, pname, pnode.key_pos.get(pname, pnode.pos), "partition"):
            continue
        sensor = None
        if part.kind == "map":
            for key, kinds in (("sensor", ("input",)), ("estimate", None)):
                ref = part.value.get(key)
                if ref is None or ref.kind != "scalar" or not isinstance(ref.value, str):
                    continue
                if kinds and (ref.value not in params or params[ref.value].kind not in kinds):
                    loader.diag.error(ref.pos, f"the {key} of partition {pname!r} is "
                                      f"{ref.value!r}, not an input parameter of the component",
                                      "an input parameter (the project binds it)")
                elif key == "sensor":
                    sensor = ref.value
            acts = part.value.get("actuators")
            for act in (acts.value if acts is not None and acts.kind == "seq" else []):
                if act.kind == "scalar" and (act.value not in params
                                             or params[act.value].kind != "output"):
                    loader.diag.error(act.pos, f"actuator {act.value!r} of partition {pname!r} "
                                      "is not an output parameter of the component",
                                      "an output parameter (the project binds it)")
        partitions.append((pname, sensor))
    return partitions, labels


def _expression_nodes(fields: dict[str, YNode]) -> list[YNode]:
    """Every node of a component file that holds an expression."""
    out: list[YNode] = []
    for key, subkeys in (("timers", ("input",)), ("observers", ("expr", "set", "reset")),
                         ("constraints", ("expr",))):
        section = fields.get(key)
        if section is None or section.kind != "map":
            continue
        for item in section.value.values():
            if item.kind == "scalar":
                out.append(item)
            elif item.kind == "map":
                out += [item.value[k] for k in subkeys if k in item.value]
    diag = fields.get("diagnoser")
    if diag is not None and diag.kind == "map":
        for key in ("transitions", "resync"):
            seq = diag.value.get(key)
            for item in (seq.value if seq is not None and seq.kind == "seq" else []):
                if item.kind == "map" and "when" in item.value:
                    out.append(item.value["when"])
    return out


def _check_expressions(loader: ProjectReader, fields: dict[str, YNode],
                       comp: ComponentDef) -> None:
    """Each expression parses and reads only the component's own names and parameters."""
    namespace = comp.namespace()
    for node in _expression_nodes(fields):
        if node.kind != "scalar":
            continue  # the loader reports the shape per instance
        try:
            text = node.as_text("an expression")
            parsed = parse_expr(text, expr_start(node, text))
        except ExprError as exc:
            loader.diag.error(exc.pos, exc.message, exc.expected)
            continue
        except NodeError:  # an empty value: reported per instance by the loader
            continue
        for sub in walk(parsed.root):
            if isinstance(sub, Var) and sub.name not in namespace:
                loader.diag.error(parsed.pos_of(sub), f"unknown name {sub.name!r} in component "
                                  f"{comp.name}", "a parameter of the component or one of its "
                                  "own names: " + ", ".join(sorted(namespace)))
            elif isinstance(sub, StepTime):
                loader.diag.error(parsed.pos_of(sub), f"{sub.step}.t reads a GRAFCET step; a "
                                  "component cannot read the control law (it is the project's)",
                                  "a timer of the component")


def text_nodes(fields: dict[str, YNode]) -> list[YNode]:
    """Descriptions and label texts: operator text filled per instance."""
    out: list[YNode] = []

    def visit(node: YNode) -> None:
        if node.kind == "map":
            for key, value in node.value.items():
                if key == "description" and value.kind == "scalar":
                    out.append(value)
                else:
                    visit(value)
        elif node.kind == "seq":
            for item in node.value:
                visit(item)

    for key in ("timers", "observers", "constraints", "diagnoser"):
        if key in fields:
            visit(fields[key])
    diag = fields.get("diagnoser")
    labels = diag.value.get("labels") if diag is not None and diag.kind == "map" else None
    if labels is not None and labels.kind == "map":
        out += [v for v in labels.value.values() if v.kind == "scalar"]
    return out


def _check_placeholders(loader: ProjectReader, fields: dict[str, YNode],
                        comp: ComponentDef) -> None:
    known = {"device", "instance", *comp.parameters}
    for node in text_nodes(fields):
        if not isinstance(node.value, str):
            continue
        for match in PLACEHOLDER.finditer(node.value):
            if match.group(1) not in known:
                loader.diag.error(text_start(node, node.value).shifted(match.start()),
                                  f"unknown placeholder {{{match.group(1)}}} in a component's "
                                  "text", "one of " + ", ".join("{" + k + "}" for k in known))


def _check_explanation_names(loader: ProjectReader, node: YNode, comp: ComponentDef) -> None:
    kinds = loader.guard(lambda: node.check_keys("the explanations of a component",
                                                 set(EXPLANATION_KINDS)), {})
    own = {"constraints": set(comp.constraints), "labels": set(comp.labels),
           "partitions": {p for p, _ in comp.partitions}}
    for kind, knode in kinds.items():
        entries = loader.guard(lambda n=knode, k=kind: n.as_map(f"explanations of {k}"), {})
        for name in entries:
            if str(name) not in own[kind]:
                loader.diag.error(knode.key_pos.get(name, knode.pos), f"explanations for "
                                  f"{kind[:-1]} {name!r}, which component {comp.name} does not "
                                  "declare", "one of " + (", ".join(sorted(own[kind]))
                                                          or f"(it has no {kind})"))

"""Component models: a device written once, instantiated by projects (000 §2.2, §3.3).

000 §2.1 builds one local diagnoser per plant element and notes that "the choice of an
automaton to represent a local diagnoser permits to compose a library of commonly
components"; §2.2 writes the safety constraints per component. A *component file* holds what
one kind of device brings to a project — its timers, observers (the reconstructions of its
sensors), safety constraints, local diagnoser and explanations — written in terms of formal
parameters; a project instantiates it once per device, binding each parameter to one of its
own variables:

    # components/valve.yaml                       # a library file
    component: valve
    parameters:
      fsc: {kind: input, description: closed end switch}
      C:   {kind: output, description: close order}
    timers:      {TON2: {type: TON, input: prev(C), preset: 2100ms}}
    constraints: {CSs1: {expr: C and fsc_filter, description: ...}}
    diagnoser:   {labels: ..., partitions: {fsc: {labels: [...], sensor: fsc, ...}}, ...}
    explanations: {constraints: {CSs1: ...}, labels: {...}, partitions: {...}}

    # projects/x/project.yaml
    components:
      V1: {use: ../../components/valve.yaml, device: Valve V1,
           bind: {fsc: fsc1, fso: fso1, C: C1, O: O1}}

**Naming.** Instance `V1` renames every name of the component: a bound parameter becomes the
project variable it is bound to (`fsc` -> `fsc1`); the component's own timers, observers,
constraints and partitions get the prefix `V1_` (`V1_TON2`, `V1_fso_hat`, `V1_CSs1`,
partition `V1_fsc` hence flag `def_V1_fsc`); the filtered sensor follows its bound sensor
(`fsc_filter` -> `fsc1_filter`); the diagnoser is named after the instance (`V1`). Labels
(F1...) and diagnoser states keep their names: they live inside their diagnoser.

**How.** Each expression of the component is parsed once to validate the component on its own
(hmi/project/component_file.py: every name it reads must be a parameter or one of its own
names, so nothing leaks in from the project), then, per instance, its parsed tree is renamed
node by node (:meth:`ComponentInstance.rename_expr`); the text is never edited to rename. Each
instance reads its own copy of the component's YAML nodes, whose positions carry the instance
(``SourcePos.context``): an error found in an instance — a constraint that is not a monomial
once bound, a clash — names the component file's line and column *and* the instance, e.g.
``components/valve.yaml:12:9: error: ... (in component V1 of projects/x/project.yaml:20:3)``.
The renamed sections are then handed to the loader as if the project had written them, so they
pass every check a project's own sections pass.

`{device}`, `{instance}` and `{<parameter>}` in a component's descriptions and label texts are
filled per instance ("Valve V1", "V1", "fsc1"); explanation texts keep their run-time
placeholders (hmi/project/texts.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.errors import SourcePos, display_path
from hmi.logic.names import NAME_RE
from hmi.project.component_file import (
    PLACEHOLDER,
    read_component,
    text_nodes,
)
from hmi.project.confine import Refused, component_roots, confined_file
from hmi.project.model import (
    FILTERED_SUFFIX,
    FLAG_PREFIX,
    ComponentDef,
    ComponentInstance,
)
from hmi.project.reader import Components
from hmi.project.texts import ProjectTexts, TextSpec
from hmi.project.yamlnodes import YNode

if TYPE_CHECKING:
    from hmi.project.reader import ProjectReader

INSTANCE_KEYS = {"use", "bind", "device"}



# --------------------------------------------------------------------------------------------
# What a project's `components:` section gives the loader
# --------------------------------------------------------------------------------------------


def merge_texts(loader: ProjectReader, parts: list[tuple[ComponentInstance | None, ProjectTexts]]
                ) -> ProjectTexts:
    """The explanation texts of the instances, then the project's, which win on a name.

    Label texts are shared by every diagnoser deciding that label (hmi/explain keys them by
    label), so two *different* component files explaining one label is ambiguous: an error.
    """
    by_kind: dict[str, dict[str, TextSpec]] = {}
    label_source: dict[str, str] = {}
    for owner, texts in parts:
        for kind, entries in texts.by_kind.items():
            target = by_kind.setdefault(kind, {})
            for name, spec in entries.items():
                if owner is not None and kind == "labels":
                    first = label_source.setdefault(name, owner.component.file)
                    if first != owner.component.file:
                        loader.diag.error(spec.pos or owner.pos, f"label {name!r} is explained "
                                          f"by {first} and by {owner.component.file}",
                                          "the text in one place: labels' explanations are "
                                          "shared by every diagnoser with that label (or in "
                                          "the project, which wins)")
                        continue
                    if name in target:
                        continue  # the same component's text, from an earlier instance
                target[name] = spec
    return ProjectTexts(by_kind)


def load_components(loader: ProjectReader) -> Components:
    """Read the `components:` section: validate each component file once, bind and check
    each instance, and build the renamed sections it adds. Problems are reported on the
    loader's diagnostics; an instance with a problem adds nothing (no cascade of errors)."""
    result = Components()
    node = loader.sections.get("components")
    if node is None:
        return result
    mapping = loader.guard(lambda: node.as_map("components"), {})
    definitions: dict[Path, ComponentDef | None] = {}
    taken = _project_names(loader)
    for name, inode in mapping.items():
        name = str(name)
        kpos = node.key_pos.get(name, node.pos)
        if not NAME_RE.match(name):
            loader.diag.error(kpos, f"{name!r} is not a valid component instance name",
                              "letters, digits and _ (it prefixes the instance's names)")
            continue
        instance = _instance(loader, name, inode, kpos, definitions, result)
        if instance is None or not _claim_names(loader, instance, taken):
            continue
        _add_sections(loader, instance, result)
        result.instances.append(instance)
    return result


def _project_names(loader: ProjectReader) -> dict[str, tuple[str, SourcePos]]:
    """Every name the project itself declares (variables, items, flags), to find clashes."""
    taken: dict[str, tuple[str, SourcePos]] = {
        name: (kind, loader.declared_at[name]) for name, kind in loader.namespace.items()}
    for key, what in (("timers", "timer"), ("observers", "observer"),
                      ("constraints", "constraint"), ("diagnosers", "diagnoser")):
        for name, _node, kpos in loader.section_items(key):
            taken.setdefault(str(name), (what, kpos))
    for _name, dnode, _kpos in loader.section_items("diagnosers"):
        parts = dnode.value.get("partitions") if dnode.kind == "map" else None
        if parts is None or parts.kind != "map":
            continue
        for pname, pnode in parts.value.items():
            ppos = parts.key_pos.get(pname, parts.pos)
            taken.setdefault(FLAG_PREFIX + str(pname), ("partition flag", ppos))
            sensor = pnode.value.get("sensor") if pnode.kind == "map" else None
            if sensor is not None and sensor.kind == "scalar" and isinstance(sensor.value, str):
                taken.setdefault(sensor.value + FILTERED_SUFFIX, ("filtered sensor", sensor.pos))
    return taken


def _instance(loader: ProjectReader, name: str, inode: YNode, kpos: SourcePos,
              definitions: dict[Path, ComponentDef | None],
              result: Components) -> ComponentInstance | None:
    what = f"component {name!r}"
    fields = loader.guard(lambda: inode.check_keys(what, INSTANCE_KEYS, ["use", "bind"]))
    if fields is None:
        return None
    use = loader.guard(lambda: fields["use"].as_str(f"the file of {what}"))
    device = loader.guard(lambda: fields["device"].as_str("device"), None) \
        if "device" in fields else name
    if use is None or device is None:
        return None
    try:
        path = confined_file(loader.folder, use, component_roots(loader.folder),
                             "the component file")
    except Refused as exc:
        loader.diag.error(fields["use"].pos, exc.message, exc.expected)
        return None
    if not path.exists():
        loader.diag.error(fields["use"].pos, f"component file {use!r} not found",
                          f"a component YAML file, relative to {display_path(loader.folder)}")
        return None
    if path not in definitions:
        definitions[path] = read_component(loader, path)
        if definitions[path] is not None:
            result.files.append(definitions[path].file)  # type: ignore[union-attr]
    comp = definitions[path]
    if comp is None:
        return None  # the component's own errors are reported once, at the component
    bind = _bindings(loader, name, comp, fields["bind"], kpos)
    if bind is None:
        return None
    return ComponentInstance(name, comp, device, bind, kpos)


def _bindings(loader: ProjectReader, name: str, comp: ComponentDef, node: YNode,
              kpos: SourcePos) -> dict[str, str] | None:
    """formal -> project variable, every parameter bound once, each to a variable of its kind."""
    mapping = loader.guard(lambda: node.as_map(f"the bindings of component {name!r}"))
    if mapping is None:
        return None
    ok = True
    bind: dict[str, str] = {}
    bound_by: dict[str, str] = {}
    for formal, vnode in mapping.items():
        formal = str(formal)
        fpos = node.key_pos.get(formal, node.pos)
        param = comp.parameters.get(formal)
        if param is None:
            loader.diag.error(fpos, f"component {name!r}: {comp.name} has no parameter "
                              f"{formal!r}", "one of " + ", ".join(comp.parameters))
            ok = False
            continue
        var = loader.guard(lambda n=vnode, f=formal: n.as_str(f"the variable bound to {f}"))
        if var is None:
            ok = False
            continue
        kind = loader.namespace.get(var)
        if kind is None:
            loader.diag.error(vnode.pos, f"component {name!r}: parameter {formal!r} is bound "
                              f"to {var!r}, which is not declared",
                              f"an {param.kind} of the project")
            ok = False
        elif kind != param.kind:
            loader.diag.error(vnode.pos, f"component {name!r}: parameter {formal!r} is an "
                              f"{param.kind} of {comp.name} ({param.description or formal}), "
                              f"bound to {var!r}, which is {_article(kind)} {kind}",
                              f"an {param.kind} of the project")
            ok = False
        elif var in bound_by:
            loader.diag.error(vnode.pos, f"component {name!r}: parameters {bound_by[var]!r} "
                              f"and {formal!r} are both bound to {var!r}",
                              "a distinct variable for each parameter")
            ok = False
        else:
            bind[formal] = var
            bound_by[var] = formal
    missing = [p for p in comp.parameters if p not in mapping]
    if missing:
        loader.diag.error(node.pos if node.kind == "map" else kpos,
                          f"component {name!r} leaves parameter"
                          f"{'s' if len(missing) > 1 else ''} {', '.join(missing)} of "
                          f"{comp.name} unbound", "every parameter bound: " + ", ".join(
                              f"{p}: <{comp.parameters[p].kind}>" for p in missing))
        ok = False
    return {p: bind[p] for p in comp.parameters if p in bind} if ok else None


def _claim_names(loader: ProjectReader, inst: ComponentInstance,
                 taken: dict[str, tuple[str, SourcePos]]) -> bool:
    """Check the names the instance adds against the project's and earlier instances'."""
    ok = True
    for name, what, origin in inst.declared():
        if name in taken:
            kind, where = taken[name]
            loader.diag.error(inst.pos, f"component {inst.name!r} would declare the {what} "
                              f"{name!r} ({origin} of {inst.component.file}), already "
                              f"declared as {kind} at {where}",
                              "names unique across the project and its components (an "
                              f"instance's names are {inst.prefix}<name>)")
            ok = False
    if ok:
        for name, what, _ in inst.declared():
            taken[name] = (f"{what} of component {inst.name}", inst.pos)
    return ok


def _article(kind: str) -> str:
    return "an" if kind[0] in "aeiou" else "a"


# --------------------------------------------------------------------------------------------
# Building an instance's sections
# --------------------------------------------------------------------------------------------


def _add_sections(loader: ProjectReader, inst: ComponentInstance, result: Components) -> None:
    """Read the component's YAML again for this instance (positions carrying the instance),
    rename its items and references, and queue them for the loader's sections."""
    from hmi.project.yamlcompose import load_yaml  # PyYAML: not for a project read back

    comp = inst.component
    root = load_yaml(comp.path, comp.file)  # read cleanly once already
    _set_context(root, inst.context)
    fields = root.value
    subst = {"device": inst.device, "instance": inst.name, **inst.bind}
    for node in text_nodes(fields):
        if isinstance(node.value, str):
            node.value = PLACEHOLDER.sub(lambda m: subst.get(m.group(1), m.group(0)),
                                          node.value)
    for key in ("timers", "observers", "constraints"):
        section = fields.get(key)
        if section is None or section.kind != "map":
            continue
        result.items.setdefault(key, []).extend(
            (inst.own(str(name)), item, section.key_pos[name])
            for name, item in section.value.items())
    if "diagnoser" in fields:
        dnode = _diagnoser_node(inst, fields["diagnoser"])
        result.items.setdefault("diagnosers", []).append(
            (inst.name, dnode, root.key_pos["diagnoser"]))
    if "explanations" in fields:
        result.explanations.append((inst, _explanations_node(inst, fields["explanations"])))
    _register(root, inst, result.scopes)


def _set_context(node: YNode, context: str) -> None:
    node.pos = replace(node.pos, context=context)
    if node.kind == "map":
        node.key_pos = {k: replace(p, context=context) for k, p in node.key_pos.items()}
        for child in node.value.values():
            _set_context(child, context)
    elif node.kind == "seq":
        for child in node.value:
            _set_context(child, context)


def _register(node: YNode, inst: ComponentInstance,
              scopes: dict[int, tuple[YNode, ComponentInstance]]) -> None:
    scopes[id(node)] = (node, inst)
    children = node.value.values() if node.kind == "map" else (
        node.value if node.kind == "seq" else ())
    for child in children:
        _register(child, inst, scopes)


def _scalar(like: YNode, value: str) -> YNode:
    """A text node standing where `like` stood (same position), holding `value`."""
    node = YNode("scalar", value, like.pos, "tag:yaml.org,2002:str")
    node.style = like.style
    return node


def _renamed_map(node: YNode, rename: Callable[[str], str]) -> YNode:
    return YNode("map", {rename(str(k)): v for k, v in node.value.items()}, node.pos, node.tag,
                 {rename(str(k)): p for k, p in node.key_pos.items()})


def _diagnoser_node(inst: ComponentInstance, node: YNode) -> YNode:
    """The component's diagnoser with its partitions and their references renamed."""
    if node.kind != "map":
        return node
    renames = inst.renames
    value = dict(node.value)
    key_pos = dict(node.key_pos)
    parts = value.get("partitions")
    if parts is not None and parts.kind == "map":
        new_parts = _renamed_map(parts, inst.own)
        for pname, part in new_parts.value.items():
            if part.kind != "map":
                continue
            pvalue = dict(part.value)
            for key in ("sensor", "estimate"):
                ref = pvalue.get(key)
                if ref is not None and ref.kind == "scalar" and isinstance(ref.value, str):
                    pvalue[key] = _scalar(ref, renames.get(ref.value, ref.value))
            acts = pvalue.get("actuators")
            if acts is not None and acts.kind == "seq":
                pvalue["actuators"] = YNode("seq", [
                    _scalar(a, renames.get(a.value, a.value)) if isinstance(a.value, str) else a
                    for a in acts.value], acts.pos, acts.tag)
            new_parts.value[pname] = YNode("map", pvalue, part.pos, part.tag, part.key_pos)
        value["partitions"] = new_parts
    value["device"] = _scalar(node, inst.device)
    key_pos["device"] = node.pos
    return YNode("map", value, node.pos, node.tag, key_pos)


def _explanations_node(inst: ComponentInstance, node: YNode) -> YNode:
    """The component's explanations, keyed by the instance's constraint and partition names
    (labels keep theirs)."""
    if node.kind != "map":
        return node
    value = {}
    for kind, knode in node.value.items():
        value[kind] = _renamed_map(knode, inst.own) if kind in ("constraints", "partitions") \
            and knode.kind == "map" else knode
    return YNode("map", value, node.pos, node.tag, node.key_pos)

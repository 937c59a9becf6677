"""Components (hmi/project/components.py): a device model written once, instantiated by
projects — the naming of instances, renaming at the expression-tree level, errors with the
component's file:line:column and the instance, and the valve component against
projects/cispi_valve (the model it was taken from)."""

from __future__ import annotations

import os
import shutil
import textwrap
from pathlib import Path

import pytest

from hmi.cli import main
from hmi.engine.scan import Engine
from hmi.errors import ProjectError
from hmi.logic.expr import parse_expr, to_text
from hmi.logic.rename import rename_node, renamed_source
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.studies.diagnosability import analyse
from tests.conftest import PROJECTS

ROOT = PROJECTS.parent
VALVE = ROOT / "components" / "valve.yaml"

TWO_VALVES = """
name: two_valves
scan_period: 10ms
inputs:
  fsc1: {description: V1 closed, device: Valve V1}
  fso1: {description: V1 open, device: Valve V1}
  fsc2: {description: V2 closed, device: Valve V2}
  fso2: {description: V2 open, device: Valve V2}
outputs:
  C1: {description: V1 close, device: Valve V1}
  O1: {description: V1 open, device: Valve V1}
  C2: {description: V2 close, device: Valve V2}
  O2: {description: V2 open, device: Valve V2}
components:
  V1: {use: USE, device: Valve V1, bind: {fsc: fsc1, fso: fso1, C: C1, O: O1}}
  V2: {use: USE, device: Valve V2, bind: {fsc: fsc2, fso: fso2, C: C2, O: O2}}
control:
  equations: {O1: fsc1_filter, C1: False, O2: False, C2: False}
plant:
  kind: sim
  devices:
    V1: {model: valve, ports: {fsc: fsc1, fso: fso1, C: C1, O: O1}}
    V2: {model: valve, ports: {fsc: fsc2, fso: fso2, C: C2, O: O2}}
"""


def write_project(folder: Path, text: str, component: Path = VALVE) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    use = os.path.relpath(component, folder)
    (folder / "project.yaml").write_text(textwrap.dedent(text).lstrip().replace("USE", use),
                                         encoding="utf-8")
    return folder


def errors_of(folder: Path) -> list[str]:
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    return [str(d) for d in info.value.errors]


def where(path: Path, needle: str, shift: int = 0) -> str:
    """`file:line:col` of the first `needle` outside comments, plus `shift` columns."""
    from hmi.errors import display_path
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        col = line.find(needle)
        if col >= 0 and not line.lstrip().startswith("#"):
            return f"{display_path(path)}:{number}:{col + 1 + shift}"
    raise AssertionError(f"{needle!r} not in {path}")


# -- instantiation semantics ----------------------------------------------------------------


@pytest.fixture(scope="module")
def two_valves(tmp_path_factory):
    return load_project(write_project(tmp_path_factory.mktemp("c") / "p", TWO_VALVES))


def test_each_instance_gets_its_own_prefixed_names(two_valves):
    p = two_valves
    assert [t.name for t in p.timers] == ["V1_TON1", "V1_TON2", "V2_TON1", "V2_TON2"]
    assert [o.name for o in p.observers] == ["V1_fso_hat", "V1_fsc_hat", "V2_fso_hat",
                                             "V2_fsc_hat"]
    assert [c.name for c in p.constraints][:7] == [f"V1_{n}" for n in (
        "CSs1", "CSs2", "CSs3", "CSs4", "CSs5", "CSs6", "CSc1")]
    diags = p.diagnosers
    assert [(d.name, d.device) for d in diags] == [("V1", "Valve V1"), ("V2", "Valve V2")]
    assert [(q.name, q.flag, q.sensor, q.estimate, q.filtered, q.actuators)
            for q in diags[1].partitions] == [
        ("V2_fsc", "def_V2_fsc", "fsc2", "V2_fsc_hat", "fsc2_filter", ()),
        ("V2_fso", "def_V2_fso", "fso2", "V2_fso_hat", "fso2_filter", ()),
        ("V2_V", "def_V2_V", None, None, None, ("C2", "O2"))]
    # Labels and states keep their names: they live inside their diagnoser.
    assert list(diags[0].labels) == list(diags[1].labels) == [f"F{k}" for k in range(1, 14)]


def test_expressions_are_renamed_as_trees_and_read_as_text(two_valves):
    by_name = {c.name: c for c in two_valves.constraints}
    cs5 = by_name["V2_CSs5"]
    assert cs5.expr.source == "rise(C2) and not fso2_filter"
    assert [str(lit) for lit in cs5.literals] == ["C2", "not prev(C2)", "not fso2_filter"]
    assert cs5.kind == "simple" and cs5.outputs == ("C2",)
    assert by_name["V1_CSc1"].kind == "combined" and by_name["V1_CSc1"].outputs == ("C1", "O1")
    observer = {o.name: o for o in two_valves.observers}["V1_fso_hat"]
    assert str(observer.set) == "V1_TON1 or prev(fso1) and not prev(def_V1_fso)"
    assert str(observer.reset) == "prev(C1)"
    # The position stays the component's, and says which instance.
    assert observer.pos.file.endswith("components/valve.yaml")
    assert observer.pos.context.startswith("in component V1 of ")
    assert observer.pos.context.endswith(where(Path(two_valves.files[0]), "V1: {"))


def test_descriptions_and_label_texts_are_filled_per_instance(two_valves):
    timer = {t.name: t for t in two_valves.timers}["V2_TON2"]
    assert timer.description == "Valve V2: close order held for a full travel (estimate of fsc2)"
    v1 = two_valves.diagnosers[0]
    assert v1.description == "Local diagnoser of Valve V1 (000 §3.1, Fig. 3)"
    assert v1.labels["F4"] == "sensor fso1 stuck at 1"


def test_component_explanations_are_keyed_by_the_instance_names(two_valves):
    texts = two_valves.explanations
    assert texts.get("constraints", "V2_CSc1").severity == "medium"
    assert texts.get("constraints", "V1_CSs1").consequences.startswith("Holding the close")
    assert texts.get("constraints", "CSc1").severity is None


def test_check_lists_the_instances_and_what_they_declare(tmp_path, capsys):
    from hmi.cli import main
    folder = write_project(tmp_path / "p", TWO_VALVES)
    assert main(["check", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "Components (2 instances)" in out
    assert "  V2  valve (" in out and "bind fsc=fsc2, fso=fso2, C=C2, O=O2" in out
    assert "partition flags def_V2_fsc, def_V2_fso, def_V2_V" in out
    assert "components/valve.yaml" in out.splitlines()[1]  # among the files read


def test_the_two_instances_diagnose_independently(two_valves):
    plant = SimPlant(two_valves)
    plant.inject(Injection("F4", 1_500_000, "V2"))  # V2 closed at rest: fso2 made
    engine = Engine(two_valves, plant)
    for now in range(0, 3_000_001, 10_000):
        snap = engine.step(now)
    states = {d.name: (d.state, d.labels) for d in snap.diagnosers}
    assert states["V2"] == ("S4", ("F4",))
    assert states["V1"][1] == ()  # V1 opened normally and is not suspected
    assert snap.reconstructed == ("fso2",)


def test_renaming_keeps_the_text_and_the_tree_in_step():
    renames = {"C": "C1", "fso_filter": "fso1_filter", "TON1": "V1_TON1"}
    for text in ("rise(C) and not fso_filter", "prev(C, 3) or not (C and TON1)",
                 "Ca and C_x and not C"):
        expr = parse_expr(text, ROOT_POS)
        source = renamed_source(text, renames)
        again = parse_expr(source, ROOT_POS)
        assert to_text(again.root) == to_text(rename_node(expr.root, renames))
    assert renamed_source("Ca and C_x and not C", renames) == "Ca and C_x and not C1"


from hmi.errors import SourcePos  # noqa: E402

ROOT_POS = SourcePos("t.yaml", 1, 1)


# -- errors in the project's components: section --------------------------------------------


@pytest.mark.parametrize("old,new,needle,fragment", [
    ("bind: {fsc: fsc1, fso: fso1, C: C1, O: O1}}\n  V2",
     "bind: {fsc: fsc1, fso: fso1, C: C1, O: O1, S: fsc2}}\n  V2", "S: fsc2",
     "component 'V1': valve has no parameter 'S' (expected one of fsc, fso, C, O)"),
    ("bind: {fsc: fsc1, fso: fso1, C: C1, O: O1}}\n  V2",
     "bind: {fsc: fsc1, fso: fso1, C: C1}}\n  V2", "{fsc: fsc1, fso: fso1, C: C1}",
     "component 'V1' leaves parameter O of valve unbound (expected every parameter bound: "
     "O: <output>)"),
    ("{fsc: fsc2, fso: fso2, C: C2", "{fsc: C2, fso: fso2, C: C2", "C2, fso: fso2",
     "component 'V2': parameter 'fsc' is an input of valve (closed end switch (1 = closed)), "
     "bound to 'C2', which is an output (expected an input of the project)"),
    ("{fsc: fsc2, fso: fso2,", "{fsc: fsc9, fso: fso2,", "fsc9",
     "component 'V2': parameter 'fsc' is bound to 'fsc9', which is not declared"),
    ("C: C2, O: O2}", "C: C2, O: C2}", "C2}}", "parameters 'C' and 'O' are both bound to 'C2'"),
    ("use: USE, device: Valve V2", "use: nowhere/valve.yaml, device: Valve V2",
     "nowhere/valve.yaml", "component file 'nowhere/valve.yaml' not found"),
    ("  V2: {use: USE, device: Valve V2, bind: {fsc: fsc2",
     "  V2: {use: USE, device: Valve V2, wiring: 1, bind: {fsc: fsc2", "wiring",
     "unknown key 'wiring' in component 'V2' (expected one of bind, device, use)"),
])
def test_instance_errors_point_at_the_project(tmp_path, old, new, needle, fragment):
    assert old in TWO_VALVES
    folder = write_project(tmp_path / "p", TWO_VALVES.replace(old, new, 1))
    errors = errors_of(folder)
    hit = [e for e in errors if fragment in e]
    assert hit, errors
    assert hit[0].startswith(where(folder / "project.yaml", needle) + ": error: ")


def test_a_name_clash_with_the_project_is_reported_at_the_instance(tmp_path):
    text = TWO_VALVES.replace("outputs:", "memories:\n  V2_TON1: {description: clash}\n"
                              "outputs:", 1)
    folder = write_project(tmp_path / "p", text)
    errors = errors_of(folder)
    assert errors == [
        f"{where(folder / 'project.yaml', 'V2: {')}: error: component 'V2' would declare the "
        f"timer 'V2_TON1' (TON1 of {os.path.relpath(VALVE)}), already declared as memory at "
        f"{where(folder / 'project.yaml', 'V2_TON1')} (expected names unique across the "
        "project and its components (an instance's names are V2_<name>))"]


def test_two_instances_on_one_sensor_clash_on_its_filtered_name(tmp_path):
    text = TWO_VALVES.replace("{fsc: fsc2, fso: fso2,", "{fsc: fsc1, fso: fso2,")
    errors = errors_of(write_project(tmp_path / "p", text))
    assert len(errors) == 2  # the clash, and the plant's two end switches on one input
    assert "component 'V2' would declare the filtered sensor 'fsc1_filter' (fsc_filter of " \
        in errors[0] and "already declared as filtered sensor of component V1" in errors[0]
    assert "valve sensor 'fsc' is bound to input 'fsc1', which device 'V1' sensor 'fsc'" \
        in errors[1]


# -- errors inside a component --------------------------------------------------------------


def component_variant(tmp_path: Path, old: str, new: str) -> Path:
    text = VALVE.read_text()
    assert old in text, old
    path = tmp_path / "p" / "lib" / "valve.yaml"  # inside the project folder: a use: may
    # not leave the project folder and the component library (hmi/project/confine.py)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


@pytest.mark.parametrize("old,new,needle,fragment", [
    ("expr: C and fsc_filter", "expr: C and fsc_filtre", "fsc_filtre",
     "unknown name 'fsc_filtre' in component valve"),
    ("expr: C and fsc_filter", "expr: C and X3.t >= 1s", "X3.t",
     "X3.t reads a GRAFCET step; a component cannot read the control law"),
    ("input: prev(O)", "input: prev(O) and", "prev(O) and",
     "syntax error in expression"),
    ("  TON1:\n", "  X1:\n", "X1:", "'X1' looks like a GRAFCET step variable"),
    ("C: {kind: output, description: close order}",
     "C: {kind: memory, description: close order}", "memory",
     "parameter kind 'memory' is not known (expected input or output)"),
    ("(estimate of {fso})", "(estimate of {fsx})", "{fsx}", "unknown placeholder {fsx}"),
    ("      severity: medium", "      severity: medium\n    CSs9: {what: x}", "CSs9",
     "explanations for constraint 'CSs9', which component valve does not declare"),
    ("sensor: fso, estimate: fso_hat", "sensor: C, estimate: fso_hat", "sensor: C",
     "the sensor of partition 'fso' is 'C', not an input parameter of the component"),
    ("initial: N0", "device: Valve\n  initial: N0", "device: Valve",
     "a component's diagnoser takes its device from each instance"),
])
def test_component_errors_are_reported_once_at_the_component(tmp_path, old, new, needle,
                                                              fragment):
    component = component_variant(tmp_path, old, new)
    errors = errors_of(write_project(tmp_path / "p", TWO_VALVES, component))
    hit = [e for e in errors if fragment in e]
    assert len(hit) == 1, errors  # once, although two instances use it
    position = where(component, needle.split(":")[0] if needle.endswith(":") else needle)
    if needle == "sensor: C":
        position = where(component, "C, estimate")
    assert hit[0].startswith(position + ": error: ")
    assert "(in component" not in hit[0]


def test_an_error_that_depends_on_the_instance_names_the_component_and_the_instance(tmp_path):
    # A constraint with no output cannot be enforced; the component is fine on its own terms
    # (every name known) so the loader finds it in each instance, at the component's line.
    component = component_variant(tmp_path, "expr: C and O", "expr: fsc and fso")
    folder = write_project(tmp_path / "p", TWO_VALVES, component)
    errors = errors_of(folder)
    here = where(component, "expr: fsc and fso", shift=6)
    project = where(folder / "project.yaml", "V1: {")
    assert errors[0] == (
        f"{here}: error: constraint 'V1_CSc1' has no output at the current scan, so the filter "
        "cannot enforce it (expected at least one output without prev(), e.g. 'C and fsc') "
        f"(in component V1 of {project})")
    assert errors[1].endswith(f"(in component V2 of {where(folder / 'project.yaml', 'V2: {')})")


def test_bad_components_exit_2_without_a_traceback(tmp_path, capsys):
    """In-process (`python -m hmi.cli` exits with main()'s status: a real process is
    checked in tests/test_cli_and_schema.py)."""
    component = component_variant(tmp_path, "expr: C and fsc_filter", "expr: C and fsc_filtre")
    folder = write_project(tmp_path / "p", TWO_VALVES, component)
    assert main(["check", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "unknown name 'fsc_filtre' in component valve" in err
    assert "Traceback" not in err


# -- the valve component is the model of projects/cispi_valve -------------------------------


@pytest.fixture(scope="module")
def valve_pair(tmp_path_factory):
    """projects/cispi_valve (its paper-faithful diagnoser variant, the one the component
    carries), and a copy whose timers, observers, constraints, diagnoser and constraint
    explanations come from the component instead (instance V1, bound by identity).
    """
    folder = tmp_path_factory.mktemp("vc") / "cispi_valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    text = (folder / "project.yaml").read_text()
    text = text[:text.index("timers:")] + (
        f"components:\n  V1: {{use: {os.path.relpath(VALVE, folder)}, device: Valve V1, "
        "bind: {fsc: fsc, fso: fso, C: C, O: O}}\n\n") + text[text.index("include:"):]
    text = text.replace("  - constraints.yaml\n", "").replace("  - diagnoser.yaml\n", "")
    text = text.replace("  - explanations.yaml\n", "")
    # The recovery names the project's own constraints (CSs3...): not part of the model.
    text = text.replace("  - recovery.yaml\n", "")
    (folder / "project.yaml").write_text(text)
    return load_project(PROJECTS / "cispi_valve", "paper"), load_project(folder)


def test_the_component_diagnoser_is_the_valve_diagnoser(valve_pair):
    original, component = (p.diagnosers[0] for p in valve_pair)
    assert [(s.name, s.labels) for s in original.states] == \
        [(s.name, s.labels) for s in component.states]
    assert [t.text() for t in original.transitions] == [t.text() for t in component.transitions]
    a, b = analyse(original), analyse(component)
    assert (len(b.certain_labels), len(b.labels), round(b.dc * 100, 1)) == (10, 13, 76.9)
    assert (a.certain_labels, a.ambiguous_decisions, a.dc) == \
        (b.certain_labels, b.ambiguous_decisions, b.dc)


RENAMED = {"TON1": "V1_TON1", "TON2": "V1_TON2", "fso_hat": "V1_fso_hat",
           "fsc_hat": "V1_fsc_hat", "def_fsc": "def_V1_fsc", "def_fso": "def_V1_fso",
           "def_V": "def_V1_V"}


@pytest.mark.parametrize("control,inject", [
    ("normal", ()), ("normal", ("F4@10s",)), ("normal", ("F13@10.4s",)),
    ("normal", ("F1@12s",)), ("faulty", ()), ("faulty", ("F6@12s",)),
])
def test_the_component_behaves_scan_for_scan_like_the_valve_project(valve_pair, control, inject):
    """Same outputs written, same diagnoser states, same flags, same plant events."""
    runs = []
    for project in valve_pair:
        plant = SimPlant(project)
        for text in inject:
            from hmi.project.injection import parse_injection
            plant.inject(parse_injection(text))
        engine = Engine(project, plant, control=control)
        image = engine.image
        flags = sorted((RENAMED.get(n, n), k) for k, n in enumerate(engine.layout.names)
                       if n.startswith("def_") and k < len(image))  # looked up once
        trace = []
        for now in range(0, 25_000_001, 10_000):
            snap = engine.step(now)
            assert engine.image is image
            trace.append((snap.outputs, tuple((d.state, d.labels) for d in snap.diagnosers),
                          tuple((name, image[k]) for name, k in flags)))
        runs.append((trace, [(e.time_us, e.kind) for e in plant.events()]))
    assert runs[0] == runs[1]


def test_library_components_validate_against_the_component_schema():
    import json

    import jsonschema
    import yaml
    from referencing import Registry, Resource
    schemas = [json.loads((ROOT / "hmi" / "project" / name).read_text())
               for name in ("schema.json", "component.schema.json")]
    registry = Registry().with_resources(
        (s["$id"], Resource.from_contents(s)) for s in schemas)
    validator = jsonschema.Draft202012Validator(schemas[1], registry=registry)
    files = sorted((ROOT / "components").glob("*.yaml"))
    assert files
    for path in files:
        validator.validate(yaml.safe_load(path.read_text()))
    bad = yaml.safe_load(VALVE.read_text())
    bad["parameters"]["C"]["kind"] = "memory"
    with pytest.raises(jsonschema.ValidationError):
        validator.validate(bad)

"""Malformed projects: each gives file:line:column, a clear message, exit status 2, no traceback.

Each case marks the token the error must point at (`at`); the test finds that token in the
file it wrote, so expected positions come from the file, not from the loader under test.
"""

from __future__ import annotations

import re
import shutil
import textwrap
from dataclasses import dataclass, field

import pytest

from hmi.cli import main
from hmi.errors import ProjectError
from hmi.project.loader import load_project
from tests.conftest import PROJECTS

BASE = {
    "head": """
        name: t
        scan_period: 10ms
    """,
    "inputs": """
        inputs:
          a: {description: sensor a}
          b: sensor b
    """,
    "outputs": """
        outputs:
          Y: {description: order Y, safe: 0}
          Z: order Z
    """,
    "memories": "",
    "timers": """
        timers:
          T1: {type: TON, input: a, preset: 1s}
    """,
    "observers": "",
    "control": """
        control:
          equations:
            Y: a and not b
            Z: T1
    """,
    "constraints": """
        constraints:
          K1: Y and b
          K2: Y and Z
    """,
    "plant": """
        plant:
          kind: sim
          model: valve
          ports: {fsc: a, fso: b, C: Y, O: Z}
    """,
}


def project_text(**sections: str) -> str:
    merged = {**BASE, **sections}
    return "".join(textwrap.dedent(text).lstrip("\n") for text in merged.values())


@dataclass
class Case:
    id: str
    fragment: str  # part of the message
    at: str | None  # the token the error points at (first occurrence in `file`)
    sections: dict = field(default_factory=dict)
    files: dict | None = None  # explicit files instead of sections
    file: str = "project.yaml"
    nth: int = 1  # which occurrence of `at`


GRAFCET_OK = """
    control:
      grafcet:
        steps:
          0: {initial: true}
          1: {actions: [Y]}
        transitions:
          - {from: 0, to: 1, when: a}
          - {from: 1, to: 0, when: b}
"""

CASES = [
    Case("yaml-syntax", "YAML syntax error", "}", {"inputs": "inputs: {a: [}\n"}),
    Case("top-level-list", "must be a mapping", None, files={"project.yaml": "- a\n- b\n"}),
    Case("empty-file", "the file is empty", None, files={"project.yaml": "\n"}),
    Case("unknown-section", "unknown section 'inptus'", "inptus",
         {"inputs": "inptus:\n  a: A\n"}),
    Case("missing-name", "the project has no name", None, {"head": "scan_period: 10ms\n"}),
    Case("period-no-unit", "scan_period 10 has no unit", "10",
         {"head": "name: t\nscan_period: 10\n"}),
    Case("period-not-duration", "'fast' is not a duration", "fast",
         {"head": "name: t\nscan_period: fast\n"}),
    Case("duplicate-yaml-key", "duplicate key 'a'", "a:", {"inputs": "inputs:\n  a: A\n  a: B\n"},
         nth=2),
    Case("bad-name", "'1a' is not a valid name", "1a", {"inputs": "inputs:\n  1a: A\n  b: B\n"}),
    Case("reserved-name", "'and' is a reserved word", "and:",
         {"inputs": "inputs:\n  a: A\n  b: B\n  and: C\n"}),
    Case("step-like-name", "looks like a GRAFCET step variable", "X1",
         {"inputs": "inputs:\n  a: A\n  b: B\n  X1: x\n"}),
    Case("duplicate-across-sections", "'a' is already declared as input", "a:",
         {"outputs": "outputs:\n  Y: y\n  Z: z\n  a: again\n"}, nth=2),
    Case("unknown-key", "unknown key 'saf'", "saf",
         {"outputs": "outputs:\n  Y: {description: y, saf: 0}\n  Z: z\n"}),
    Case("safe-wrong-type", "safe value must be a Boolean", "maybe",
         {"outputs": "outputs:\n  Y: {description: y, safe: maybe}\n  Z: z\n"}),
    Case("timer-no-preset", "timer 'T1' has no preset", "{type",
         {"timers": "timers:\n  T1: {type: TON, input: a}\n"}),
    Case("timer-bad-type", "timer type 'TP' is not known", "TP",
         {"timers": "timers:\n  T1: {type: TP, input: a, preset: 1s}\n"}),
    Case("timer-preset-no-unit", "preset 5 has no unit", "5}",
         {"timers": "timers:\n  T1: {type: TON, input: a, preset: 5}\n"}),
    Case("timer-unknown-name", "unknown name 'aa'", "aa",
         {"timers": "timers:\n  T1: {type: TON, input: aa and b, preset: 1s}\n"}),
    Case("timer-reads-output-now", "'Y' is an output", "Y, preset",
         {"timers": "timers:\n  T1: {type: TON, input: Y, preset: 1s}\n"}),
    Case("observer-expr-and-set", "needs either 'expr' or a 'set'/'reset' pair", "{expr",
         {"observers": "observers:\n  o1: {expr: a, set: b}\n"}),
    Case("observer-set-no-reset", "has a set but no reset", "{set",
         {"observers": "observers:\n  o1: {set: a}\n"}),
    Case("expr-syntax", "syntax error in expression", "and b",
         {"control": "control:\n  equations:\n    Y: a and and b\n    Z: T1\n"}),
    Case("expr-function", "function 'max' is not allowed", "max",
         {"control": "control:\n  equations:\n    Y: max(a)\n    Z: T1\n"}),
    Case("expr-arithmetic", "arithmetic operator '+'", "a + b",
         {"control": "control:\n  equations:\n    Y: a + b\n    Z: T1\n"}),
    Case("prev-depth-name", "depth of prev() must be a whole number", "b)",
         {"control": "control:\n  equations:\n    Y: prev(a, b)\n    Z: T1\n"}),
    Case("prev-depth-zero", "prev() depth 0 is out of range", "0)",
         {"control": "control:\n  equations:\n    Y: prev(a, 0)\n    Z: T1\n"}),
    Case("rise-of-expression", "rise() applies to a variable name", "a and b)",
         {"control": "control:\n  equations:\n    Y: rise(a and b)\n    Z: T1\n"}),
    Case("equation-unknown-target", "equation target 'W' is not declared", "W:",
         {"control": "control:\n  equations:\n    W: a\n    Y: a\n    Z: T1\n"}),
    Case("equation-target-input", "equation target 'a' is a input", "a: b",
         {"control": "control:\n  equations:\n    a: b\n    Y: a\n    Z: T1\n"}),
    Case("constraint-not-monomial", "not a monomial: 'or' makes a sum", "a or b",
         {"constraints": "constraints:\n  K1: \"Y and (a or b)\"\n"}),
    Case("constraint-no-output", "has no output at the current scan", "a and b",
         {"constraints": "constraints:\n  K1: a and b\n"}),
    Case("constraint-prev-output-only", "has no output at the current scan", "prev(Y)",
         {"constraints": "constraints:\n  K1: prev(Y) and a\n"}),
    Case("constraint-never-true", "can never be true", "Y and a and not a",
         {"constraints": "constraints:\n  K1: Y and a and not a\n"}),
    Case("constraint-uses-memory", "'M' is a memory and cannot be used in a safety constraint",
         "M\n", {"memories": "memories:\n  M: m\n",
                 "constraints": "constraints:\n  K1: Y and M\n"}),
    Case("constraint-negated-group", "not a monomial", "not (",
         {"constraints": "constraints:\n  K1: Y and not (a and b)\n"}),
    Case("grafcet-no-initial", "the grafcet has no initial step", "0: {}",
         {"control": GRAFCET_OK.replace("0: {initial: true}", "0: {}")}),
    Case("grafcet-unknown-step", "refers to step 7, which is not declared", "7",
         {"control": GRAFCET_OK.replace("to: 0, when: b", "to: 7, when: b")}),
    Case("grafcet-step-not-number", "step 'start' is not a step number", "start",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}", "start: {actions: [Y]}")}),
    Case("action-on-input", "a continuous action targets 'a', which is a input", "a]",
         {"control": GRAFCET_OK.replace("[Y]", "[a]")}),
    Case("stored-action-on-output", "a stored action (set) targets 'Y'", "Y}]",
         {"control": GRAFCET_OK.replace("[Y]", "[{set: Y}]")}),
    Case("step-time-of-non-step", "T1.t: 'T1' is not a GRAFCET step", "T1.t",
         {"control": GRAFCET_OK.replace("when: b", "when: T1.t >= 1s")}),
    Case("compare-booleans", "only times can be compared", "a >= b",
         {"control": GRAFCET_OK.replace("when: b", "when: a >= b")}),
    Case("no-control", "neither equations nor a grafcet", "{description: nothing",
         {"control": "control:\n  main: {description: nothing}\n"}),
    Case("plant-unknown-model", "unknown plant model 'blender'", "blender",
         {"plant": "plant:\n  kind: sim\n  model: blender\n"}),
    Case("plant-unknown-param", "unknown key 'speed'", "speed",
         {"plant": "plant:\n  kind: sim\n  model: valve\n  params: {speed: 2s}\n"}),
    Case("plant-bad-param", "parameter 'travel' 'slow' is not a duration", "slow",
         {"plant": "plant:\n  kind: sim\n  model: valve\n  params: {travel: slow}\n"}),
    Case("plant-port-unknown-var", "port 'C' is bound to 'Q'", "Q}",
         {"plant": "plant:\n  kind: sim\n  model: valve\n  ports: {C: Q}\n"}),
    Case("plant-kind", "plant kind 'opcua' is not known", "opcua",
         {"plant": "plant:\n  kind: opcua\n"}),
    Case("policy-unknown", "policy 'stop' is not known", "stop",
         {"head": "name: t\nscan_period: 10ms\npolicy: stop\n"}),
    Case("address-malformed", "address 'coil' is not a plant address", "coil",
         {"outputs": "outputs:\n  Y: {description: y, address: coil}\n  Z: z\n"}),
    Case("output-on-read-only-table", "mapped to a read-only table", "Y:",
         {"outputs": "outputs:\n  Y: {description: y, address: 'di:3'}\n  Z: z\n"}),
    Case("address-overlap", "already used by 'Y'", "Z:",
         {"outputs": "outputs:\n  Y: {description: y, address: 'coil:1'}\n"
                     "  Z: {description: z, address: 'coil:1'}\n"}),
    Case("key-read-as-boolean", "read by YAML as a Boolean", "on:",
         {"inputs": "inputs:\n  a: A\n  b: B\n  on: C\n"}),
    Case("include-missing", "included file 'more.yaml' not found", "more.yaml",
         {"head": "name: t\nscan_period: 10ms\ninclude: [more.yaml]\n"}),
    Case("unknown-name-suggestion", "did you mean 'T1'", "T2",
         {"control": "control:\n  equations:\n    Y: T2\n    Z: T1\n"}),
    # A step's supervision time (docs/project-format.md, "Control law").
    Case("supervision-negative", "supervision of step 1 '-5s' is not a duration", "-5s",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: -5s}")}),
    Case("supervision-zero", "supervision of step 1 must be longer than zero", "0s}",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: 0s}")}),
    Case("supervision-no-unit", "supervision of step 1 15 has no unit", "15}",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: 15}")}),
    Case("supervision-not-duration", "supervision of step 0 'long' is not a duration", "long",
         {"control": GRAFCET_OK.replace("0: {initial: true}",
                                        "0: {initial: true, supervision: long}")}),
    Case("supervision-list", "supervision of step 1 must be a single value", "[10s]",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: [10s]}")}),
    Case("supervision-below-period", "is shorter than the scan period (10ms)", "5ms",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: 5ms}")}),
    Case("supervision-too-long", "longer than the longest duration allowed", "2000h",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervision: 2000h}")}),
    Case("supervision-misspelt", "unknown key 'supervison'", "supervison",
         {"control": GRAFCET_OK.replace("1: {actions: [Y]}",
                                        "1: {actions: [Y], supervison: 10s}")}),
    Case("supervision-without-grafcet", "unknown key 'supervision'", "supervision",
         {"control": "control:\n  main:\n    supervision: 10s\n    equations:\n"
                     "      Y: a\n      Z: T1\n"}),
    # An expression written over several lines points at the line and column of the token
    # (the long fuzz found a folded block's error at the value's offset on its first line,
    # a column past the end of that line).
    Case("folded-block-expr", "unknown name 'bb'", "bb",
         {"control": "control:\n  equations:\n    Y: >-\n      a and\n      not a or\n"
                     "      b and  bb\n    Z: T1\n"}),
    Case("literal-block-expr", "unknown name 'bb'", "bb",
         {"control": "control:\n  equations:\n    Y: |\n      a and\n      (b or bb)\n"
                     "    Z: T1\n"}),
    Case("plain-multiline-expr", "unknown name 'bb'", "bb",
         {"control": "control:\n  equations:\n    Y: a and\n      b or\n      bb\n"
                     "    Z: T1\n"}),
    Case("quoted-multiline-expr", "unknown name 'bb'", "bb",
         {"control": "control:\n  equations:\n    Y: \"a and\n      bb or b\"\n"
                     "    Z: T1\n"}),
    Case("next-line-char", "U+0085", "\x85", {"inputs": "inputs:\n  a: A\x85\n  b: B\n"}),
    Case("line-separator", "U+2028 (LINE SEPARATOR)", "\u2028",
         {"inputs": "inputs:\n  a: A\u2028  b: B\n"}),
    Case("folded-block-syntax", "syntax error in expression", ")\n",
         {"control": "control:\n  equations:\n    Y: >\n      a and\n      (b and )\n"
                     "    Z: T1\n"}),
]


def _position(text: str, token: str, nth: int) -> tuple[int, int]:
    index = -1
    for _ in range(nth):
        index = text.index(token, index + 1)
    line = text.count("\n", 0, index) + 1
    col = index - (text.rfind("\n", 0, index) + 1) + 1
    return line, col


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_malformed_project(case: Case, tmp_path, capsys):
    folder = tmp_path / "p"
    folder.mkdir()
    files = case.files or {"project.yaml": project_text(**case.sections)}
    for name, text in files.items():
        (folder / name).write_text(text, encoding="utf-8")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    messages = [str(d) for d in info.value.errors]
    matching = [d for d in info.value.errors if case.fragment in d.message + str(d.expected)]
    assert matching, f"no error mentions {case.fragment!r}: {messages}"
    diagnostic = matching[0]
    assert diagnostic.pos.file.endswith(case.file)
    if case.at is not None:
        text = (folder / case.file).read_text()
        assert (diagnostic.pos.line, diagnostic.pos.col) == _position(text, case.at, case.nth)
    else:
        assert diagnostic.pos.line >= 1 or case.id in ("empty-file",)
    # The command line says the same thing, exits 2 and prints no traceback.
    assert main(["check", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and case.fragment in err
    assert re.search(r"project\.yaml:\d+:\d+: error: ", err)


def test_at_least_thirty_distinct_malformed_projects():
    assert len({c.id for c in CASES}) >= 30


def test_section_defined_in_project_and_include(tmp_path):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text(
        head="name: t\nscan_period: 10ms\ninclude: [more.yaml]\n"))
    (folder / "more.yaml").write_text("timers:\n  T9: {type: TON, input: a, preset: 1s}\n")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    error = info.value.errors[0]
    assert "section 'timers' is defined twice" in error.message
    assert error.pos.file.endswith("more.yaml") and (error.pos.line, error.pos.col) == (1, 1)


def test_errors_inside_an_included_file_name_that_file(tmp_path):
    folder = tmp_path / "p"
    folder.mkdir()
    sections = {k: v for k, v in BASE.items() if k != "constraints"}
    (folder / "project.yaml").write_text(
        "".join(textwrap.dedent(t).lstrip("\n") for t in sections.values())
        + "include: [c.yaml]\n")
    (folder / "c.yaml").write_text("constraints:\n  K1: Y and bb\n")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    error = info.value.errors[0]
    assert error.pos.file.endswith("c.yaml") and (error.pos.line, error.pos.col) == (2, 13)


def test_missing_folder_and_folder_without_project(tmp_path, capsys):
    assert main(["check", str(tmp_path / "nope")]) == 2
    assert "no such project folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["check", str(tmp_path / "empty")]) == 2
    assert "this folder has no project.yaml" in capsys.readouterr().err


def test_several_errors_are_reported_together(tmp_path):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text(
        control="control:\n  equations:\n    Y: aa\n    Z: bb\n",
        constraints="constraints:\n  K1: a and b\n"))
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    assert len(info.value.errors) == 3


def test_unreachable_step_is_a_warning_not_an_error(tmp_path, capsys):
    folder = tmp_path / "p"
    folder.mkdir()
    control = GRAFCET_OK + "        2: {}\n"
    control = textwrap.dedent(GRAFCET_OK).replace(
        "      1: {actions: [Y]}\n", "      1: {actions: [Y]}\n      2: {}\n")
    (folder / "project.yaml").write_text(project_text(control=control))
    project = load_project(folder)
    warnings = [str(w) for w in project.warnings]
    assert any("step 2 can never become active" in w for w in warnings)
    assert main(["check", str(folder)]) == 0
    assert "step 2 can never become active" in capsys.readouterr().out


@pytest.mark.parametrize("wrong, fragment", [
    ("safe: maybe", "safe value must be a Boolean"),
    ("address: coil:70000", "address index 70000 is out of range"),
    ("address: hr:3.16", "bit 16 is out of range"),
    ("address: di:5", "read-only"),
    ("description: [a, b]", "description"),
])
def test_one_wrong_field_of_an_output_is_one_error(tmp_path, wrong, fragment):
    """The output still exists for the rest of the check: no knock-on errors elsewhere (the
    control law targeting it, the plant's ports) that would bury the real one."""
    folder = tmp_path / "cispi_valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    text = (folder / "project.yaml").read_text(encoding="utf-8")
    field_name = wrong.split(":")[0]
    lines = text.splitlines(keepends=True)
    start = lines.index("  C:\n")
    for k in range(start + 1, len(lines)):
        if lines[k].strip().startswith(f"{field_name}:"):
            lines[k] = f"    {wrong}\n"
            break
    else:
        raise AssertionError(f"no {field_name} under C")
    (folder / "project.yaml").write_text("".join(lines), encoding="utf-8")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    errors = info.value.errors
    assert len(errors) == 1, [str(d) for d in errors]
    assert fragment in errors[0].message + str(errors[0].expected)
    assert errors[0].pos.file.endswith("project.yaml")


def test_supervision_not_a_multiple_of_the_period_is_a_warning(tmp_path, capsys):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text(control=GRAFCET_OK.replace(
        "1: {actions: [Y]}", "1: {actions: [Y], supervision: 1.005s}")), encoding="utf-8")
    project = load_project(folder)
    assert project.controls["main"].grafcet.steps[1].supervision_us == 1_005_000
    assert any("not a multiple of the scan period" in w.message for w in project.warnings)
    assert main(["check", str(folder)]) == 0
    out = capsys.readouterr()
    assert "supervision X1 1.005s" in out.out


def test_a_carriage_return_alone_is_refused_where_it_is(tmp_path, capsys):
    """YAML reads a carriage return without a line feed as a line break, editors do not all:
    refused, at its place as an editor counts it (CR LF line ends are fine)."""
    folder = tmp_path / "p"
    folder.mkdir()
    text = project_text(inputs="inputs:\n  a: A\r  b: B\n")
    (folder / "project.yaml").write_bytes(text.encode())
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    [diagnostic] = info.value.errors
    head = text[:text.index("\r")]
    assert "a carriage return without a line feed" in diagnostic.message
    assert (diagnostic.pos.line, diagnostic.pos.col) == (
        head.count("\n") + 1, len(head) - head.rfind("\n"))
    (folder / "project.yaml").write_bytes(text.replace("\r", "\n").replace(
        "\n", "\r\n").encode())
    assert main(["check", str(folder)]) == 0
    capsys.readouterr()

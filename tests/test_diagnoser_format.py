"""The `diagnosers:` section: every validation error with its file:line:column, the names
it declares (flags, filtered sensors) and where they may be read, and the one-scan-back
reading of outputs in a diagnoser's conditions.
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass

import pytest

from hmi.cli import main
from hmi.engine.commands import SetInput
from hmi.engine.scan import Engine
from hmi.errors import ProjectError
from hmi.plant.sim.plant import SimPlant
from hmi.project.loader import load_project
from hmi.session.session import Session

PROJECT = """
name: t
scan_period: 10ms
inputs: {fsc: closed switch, fso: open switch, go: start button}
outputs: {C: close, O: open}
timers:
  T1: {type: TON, input: prev(O), preset: 2s}
  T2: {type: TON, input: prev(C), preset: 2s}
observers:
  fso_hat: {set: T1, reset: prev(C)}
  fsc_hat: {set: T2, reset: prev(O), initial: true}
control:
  equations:
    O: go and not fso
    C: False
constraints:
  K1: C and fsc_filter
  K2: C and O
plant: {kind: sim, model: valve}
include: [diag.yaml]
"""

DIAG = """
diagnosers:
  D:
    labels: {F1: fsc stuck at 0, F2: fsc stuck at 1, F5: valve stuck}
    partitions:
      fsc: {labels: [F1, F2], sensor: fsc, estimate: fsc_hat}
      V: {labels: [F5], actuators: [C, O]}
    initial: N0
    states:
      N0: {description: sync}
      N1: {description: closed}
      N2: {description: opening}
      B1: {labels: [F1, F5]}
      S1: {labels: [F1]}
      S2: {labels: [F2]}
    transitions:
      - {from: N0, to: N1, when: fsc and not O}
      - {from: N1, to: N2, when: rise(O)}
      - {from: N1, to: B1, when: not fsc and not O}
      - {from: N2, to: S2, after: 300ms}
      - {from: B1, to: S1, when: fso, within: [1s, 2s]}
    resync:
      - {when: fsc and not fso, to: N1}
"""


def write(folder, project=PROJECT, diag=DIAG):
    folder.mkdir(exist_ok=True)
    (folder / "project.yaml").write_text(textwrap.dedent(project).lstrip(), encoding="utf-8")
    (folder / "diag.yaml").write_text(textwrap.dedent(diag).lstrip(), encoding="utf-8")
    return folder


@dataclass
class Case:
    id: str
    fragment: str  # part of the message
    old: str  # replaced in DIAG (or PROJECT when file is project.yaml)
    new: str
    at: str | None  # the token the error points at (occurrence `nth` in the written file)
    nth: int = 1
    file: str = "diag.yaml"


CASES = [
    Case("non-deterministic", "is not deterministic: from 'N1', transition 2",
         "      - {from: N1, to: B1,", "      - {from: N1, to: S2, when: fso}\n"
         "      - {from: N1, to: B1,", "{from: N1, to: S2", 1),
    Case("faulty-to-normal", "goes from the faulty state 'B1' to the normal state 'N1'",
         "    resync:", "      - {from: B1, to: N1, when: fsc}\n    resync:", "N1, when: fsc}"),
    Case("unknown-label", "unknown label 'F9' in state 'S1'", "S1: {labels: [F1]}",
         "S1: {labels: [F9]}", "F9"),
    Case("label-outside-partitions", "label 'F3' is outside every partition",
         "F5: valve stuck}", "F5: valve stuck, F3: fso stuck}", "F3"),
    Case("label-in-two-partitions", "label 'F2' is in partition 'fsc'",
         "V: {labels: [F5]", "V: {labels: [F5, F2]", "F2]", 2),
    Case("sensor-not-input", "'C' is an output, not usable as the sensor",
         "sensor: fsc,", "sensor: C,", "C, estimate"),
    Case("actuator-not-output", "'fso' is an input, not usable as the actuator",
         "actuators: [C, O]", "actuators: [C, fso]", "fso]"),
    Case("estimate-unknown", "unknown name 'fsc_hatt' as the estimate",
         "estimate: fsc_hat", "estimate: fsc_hatt", "fsc_hatt"),
    Case("sensor-without-estimate", "has a sensor but no estimate",
         ", estimate: fsc_hat}", "}", "{labels: [F1, F2]"),
    Case("sensor-and-actuators", "needs either a 'sensor'",
         "actuators: [C, O]}", "actuators: [C, O], sensor: fso}", "{labels: [F5]"),
    Case("initial-unknown", "the initial state 'N9' is not declared",
         "initial: N0", "initial: N9", "N9"),
    Case("initial-faulty", "the initial state 'B1' is faulty",
         "initial: N0", "initial: B1", "B1\n"),
    Case("no-initial", "has no 'initial'", "    initial: N0\n", "", None),
    Case("timeout-without-duration", "has neither an event nor a timeout duration",
         "{from: N2, to: S2, after: 300ms}", "{from: N2, to: S2}", "{from: N2"),
    Case("timeout-no-unit", "'after' of transition 4 of diagnoser 'D' 300 has no unit",
         "after: 300ms", "after: 300", "300}"),
    Case("when-and-after", "has both 'when' and 'after'",
         "after: 300ms}", "after: 300ms, when: fsc}", "300ms"),
    Case("two-timeouts", "state 'N2' has a second timeout",
         "    resync:", "      - {from: N2, to: S1, after: 1s}\n    resync:", "{from: N2, to: S1"),
    Case("unknown-state", "unknown state 'N7'", "{from: N2, to: S2,", "{from: N2, to: N7,",
         "N7"),
    Case("self-loop", "goes from 'N2' to itself", "{from: N2, to: S2,", "{from: N2, to: N2,",
         "{from: N2, to: N2"),
    Case("empty-window", "is empty", "within: [1s, 2s]", "within: [2s, 1s]", "[2s, 1s]"),
    Case("window-one-value", "has 1 values", "within: [1s, 2s]", "within: [1s]", "[1s]"),
    Case("window-on-timeout", "is a timeout; a window only applies to an event",
         "after: 300ms}", "after: 300ms, within: [0s, 1s]}", "[0s, 1s]"),
    Case("resync-to-faulty", "re-synchronises to the faulty state 'S1'",
         "to: N1}\n", "to: S1}\n", "S1}\n", 1),
    Case("condition-reads-a-flag", "'def_V' is a flag and cannot be used in a diagnoser",
         "when: fso, within", "when: fso and def_V, within", "def_V"),
    Case("condition-unknown-name", "unknown name 'fsoo'", "when: fso, within",
         "when: fsoo, within", "fsoo"),
    Case("condition-syntax", "syntax error", "when: fso, within", "when: 'fso and', within",
         None),
    Case("bad-state-name", "'1N' is not a valid state name", "N2: {description: opening}",
         "1N: {description: opening}", "1N"),
    Case("label-list-not-list", "must be a list", "S2: {labels: [F2]}", "S2: {labels: F2}",
         "F2}"),
    Case("timer-reads-flag-now", "'def_V' is a partition flag: its value at this scan",
         "input: prev(C)", "input: def_V", "def_V", 1, "project.yaml"),
    Case("filtered-name-clash", "the filtered sensor 'fsc_filter' clashes with the input",
         "go: start button}", "go: start button, fsc_filter: x}", "fsc, estimate", 1),
]


def _position(text: str, token: str, nth: int) -> tuple[int, int]:
    index = -1
    for _ in range(nth):
        index = text.index(token, index + 1)
    line = text.count("\n", 0, index) + 1
    return line, index - (text.rfind("\n", 0, index) + 1) + 1


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_invalid_diagnoser(case: Case, tmp_path, capsys):
    project, diag = PROJECT, DIAG
    source = PROJECT if case.file == "project.yaml" or case.old not in DIAG else DIAG
    assert source.count(case.old) == 1, f"{case.old!r} must occur once"
    if source is PROJECT:
        project = PROJECT.replace(case.old, case.new)
    else:
        diag = DIAG.replace(case.old, case.new)
    folder = write(tmp_path / "p", project, diag)
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    matching = [d for d in info.value.errors if case.fragment in d.message + str(d.expected)]
    assert matching, f"no error mentions {case.fragment!r}: " + "; ".join(
        str(d) for d in info.value.errors)
    diagnostic = matching[0]
    if case.at is not None:
        where = "diag.yaml" if case.id == "filtered-name-clash" else case.file
        assert diagnostic.pos.file.endswith(where)
        text = (folder / where).read_text()
        assert (diagnostic.pos.line, diagnostic.pos.col) == _position(text, case.at, case.nth)
    assert main(["check", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and case.fragment in err
    assert re.search(r"\.yaml:\d+:\d+: error: ", err)


def test_the_base_project_is_valid_and_declares_flags_and_filtered_sensors(tmp_path):
    project = load_project(write(tmp_path / "p"))
    spec = project.diagnosers[0]
    assert [p.flag for p in spec.partitions] == ["def_fsc", "def_V"]
    assert [p.filtered for p in spec.partitions] == ["fsc_filter", None]
    # A constraint reads the filtered sensor at t, as a context literal (not an output).
    k1 = project.constraints[0]
    assert [str(lit) for lit in k1.context_literals] == ["fsc_filter"] and k1.kind == "simple"


def test_disjoint_windows_or_exclusive_conditions_are_deterministic(tmp_path):
    diag = DIAG.replace("      - {from: N1, to: B1,",
                        "      - {from: N1, to: S2, when: fso and fsc and not O}\n"
                        "      - {from: N1, to: B1,")
    load_project(write(tmp_path / "a", diag=diag))
    diag = DIAG.replace("      - {from: B1, to: S1, when: fso, within: [1s, 2s]}",
                        "      - {from: B1, to: S1, when: fso, within: [1s, 2s]}\n"
                        "      - {from: B1, to: S2, when: fso, within: [2s, inf]}")
    load_project(write(tmp_path / "b", diag=diag))


def test_unreachable_states_and_unused_labels_are_warnings(tmp_path, capsys):
    diag = DIAG.replace("      S2: {labels: [F2]}", "      S2: {labels: [F2]}\n"
                        "      S9: {labels: [F2]}").replace(
        "F5: valve stuck}", "F5: valve stuck, F6: other}").replace(
        "V: {labels: [F5]", "V: {labels: [F5, F6]")
    project = load_project(write(tmp_path / "p", diag=diag))
    warnings = [str(w) for w in project.warnings]
    assert any("state 'S9' of diagnoser 'D' is unreachable" in w for w in warnings)
    assert any("label 'F6' of diagnoser 'D' is in no state's decision" in w for w in warnings)
    assert main(["check", str(tmp_path / "p")]) == 0
    assert "is unreachable" in capsys.readouterr().out


def test_rise_of_an_output_in_a_diagnoser_is_the_order_written_at_the_previous_scan(tmp_path):
    """Compiled as written, rise(O) would compare O(t-1) with itself at the diagnoser stage
    and never be true; read one scan back it is true the scan after O was written."""
    project = load_project(write(tmp_path / "p"))
    engine = Engine(project, SimPlant(project))
    session = Session(engine)
    for _ in range(5):
        s = session.scan_once()
    assert s.snapshot.diagnosers[0].state == "N1"
    session.command(SetInput("go", True))
    written = session.scan_once().snapshot
    assert written.outputs == (False, True) and written.diagnosers[0].state == "N1"
    seen = session.scan_once().snapshot
    assert seen.diagnosers[0].state == "N2" and seen.diagnosers[0].via == \
        "N1 -> N2 on rise(O)"


@pytest.mark.parametrize("line, wrong, fragment", [
    (68, ("[F4]", "[F99]"), "unknown label 'F99' in state 'S4'"),
    (60, ("[F4, F6]", "[F4, F66]"), "unknown label 'F66' in state 'B4'"),
])
def test_one_mistake_in_the_valve_diagnoser_is_one_error(tmp_path, line, wrong, fragment):
    """No knock-on errors: the state keeps its faulty decision (its transitions are not also
    'faulty to normal'), and the explanations of the diagnoser's labels and partitions are
    not reported as unknown because the diagnoser was rejected."""
    import shutil

    from tests.conftest import PROJECTS
    folder = tmp_path / "cispi_valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    path = folder / "diagnoser.yaml"
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    assert wrong[0] in lines[line - 1]
    lines[line - 1] = lines[line - 1].replace(*wrong)
    path.write_text("".join(lines), encoding="utf-8")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    errors = info.value.errors
    assert len(errors) == 1 and fragment in errors[0].message, [str(e) for e in errors]
    assert (errors[0].pos.file.endswith("diagnoser.yaml"), errors[0].pos.line) == (True, line)

"""A device's own fault signal is the root cause: conveyor_robot's drive fault relay Hc
(`fault: true`) raises its own high alarm naming Conveyor C1 with "Check Conveyor C1"
recommended, and no explanation recommends continuing while the drive is halted — the
stopwatch monitor's fault on the halted task reads "stopped in the middle of its task"
(docs/explanations.md), not "expect the cycle to run late". Virtual time."""

from __future__ import annotations

from hmi.project.loader import load_project
from tests.conftest import PROJECTS, make_session

S = 1_000_000


def _run(inject, seconds):
    session = make_session(PROJECTS / "conveyor_robot", inject=inject)
    return session.run_for(seconds * S)


def test_the_drive_fault_input_is_declared_a_fault():
    project = load_project(PROJECTS / "conveyor_robot")
    assert [v.name for v in project.inputs if v.fault] == ["Hc"]


def test_a_halted_drive_raises_its_own_p1_and_nothing_recommends_continue():
    cell = _run(["C1.stop@5s"], 20)
    assert cell.snapshot.value("Hc")
    alarms = {a.key: a for a in cell.alarms}
    drive = alarms["fault:Hc"]
    assert drive.severity == "high" and drive.active
    assert drive.text.startswith("Conveyor C1: halted by a malfunction")
    assert drive.explanation.recommended.label == "Check Conveyor C1"
    monitor = alarms["monitor:conveyor"].explanation
    assert monitor.what.startswith("Conveyor C1: stopped in the middle of its task")
    assert monitor.severity == "high"
    assert monitor.recommended.label == "Check Conveyor C1"
    assert "run late" not in monitor.consequences
    for e in cell.explanations:
        assert e.recommended is None or e.recommended.id != "continue", (e.key, e.what)


def test_the_drive_alarm_clears_when_the_drive_runs_again():
    cell = _run(["C1.stop@1s+2s"], 6)  # the paper's 2 s stop: it runs again at 3 s
    assert not cell.snapshot.value("Hc")
    drive = next(a for a in cell.alarms if a.key == "fault:Hc")
    assert not drive.active  # cleared, waiting for its acknowledgement
    assert not any(e.key == "fault:Hc" for e in cell.explanations)


def test_a_normal_run_raises_no_drive_alarm():
    cell = _run([], 30)
    assert not any(a.key.startswith("fault:") for a in cell.alarms)

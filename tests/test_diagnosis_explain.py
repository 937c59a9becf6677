"""Diagnoser decisions as explanations and alarms, and the reset preview in their records.

The valve's diagnoser V1 (projects/cispi_valve/diagnoser.yaml): F1 (fsc stuck at 0) at 10 s
ends in A1 {F1, F13}, ambiguous, at 15.75 s; F9 (unexpected fso rise) at 10 s is isolated
with certainty in S9 the same scan.
"""

from __future__ import annotations

from hmi.engine.commands import ChoosePolicy, FaultReset, InjectFault
from hmi.engine.runner import Controller
from hmi.engine.scan import Engine
from hmi.plant.base import PlantError
from hmi.plant.sim import Injection, SimPlant
from hmi.project.loader import load_project
from hmi.ui.scenarios import VALVE

S = 1_000_000


def run(code: str, until_s: float, policy: str | None = None) -> Controller:
    project = load_project(VALVE)
    controller = Controller(Engine(project, SimPlant(project), policy=policy))
    controller.command(InjectFault(Injection(code, 10 * S)))
    controller.run_for(int(until_s * S))
    return controller


def diagnosis(controller):
    return next(e for e in controller.engine.last.explanations if e.key == "diagnosis:V1")


def test_ambiguous_decision_is_explained_as_such():
    c = run("F1", 17)
    snap = c.engine.last
    record = snap.diagnosers[0]
    assert record.labels == ("F1", "F13") and record.final
    e = diagnosis(c)
    assert e.kind == "diagnosis" and e.ambiguous and e.latched and e.severity == "high"
    assert e.what == ("Valve V1: sensor fsc stuck at 0 (F1) or valve blocked between its "
                      "positions (F13) — ambiguous: check the valve and motor first")
    assert "reached state A1" in e.why and "N7 -> A1 after 1.93s" in e.why
    assert "cannot tell apart" in e.why and "fsc=0, fso=0, C=0, O=0" in e.why
    assert "def_fsc is set" in e.consequences and "fsc_hat" in e.consequences
    assert "C, O are masked" in e.consequences
    assert "Check the valve and motor first: a fault there can damage" in e.consequences
    assert [p.id for p in e.policies] == ["check", "continue", "stop_device", "manual",
                                          "reset"]
    assert e.recommended.id == "check" and e.recommended.command is None
    alarm = next(a for a in snap.alarms if a.key == "diagnosis:V1")
    assert alarm.priority == 1 and alarm.latched and alarm.raised_us == 15_750_000


def test_certain_sensor_decision_recommends_running_degraded():
    c = run("F9", 11)
    e = diagnosis(c)
    assert not e.ambiguous and e.severity == "medium"
    assert e.what == "Valve V1: unexpected fso rise (0 to 1) (F9) — diagnosed with certainty"
    assert "isolates one label" in e.why
    assert "read fso from its estimate fso_hat" in e.consequences
    assert "masked" not in e.consequences
    assert e.recommended.id == "continue"
    assert "fso read from fso_hat" in e.recommended.effect
    result = c.command(ChoosePolicy("diagnosis:V1", "continue"))
    assert result.accepted and "chosen" in result.message


def test_monitor_policy_says_the_orders_are_not_masked():
    c = run("F1", 17, policy="monitor")
    e = diagnosis(c)
    assert "NOT masked (monitor policy)" in e.consequences
    assert "C, O masked" not in e.recommended.effect  # continue does not claim a mask


def test_record_previews_what_a_reset_would_do():
    c = run("F1", 17)
    record = c.engine.last.diagnosers[0]
    assert record.resync == "" and record.resync_values == "fsc=0, fso=0, C=0, O=0"
    message = c.command(FaultReset()).message
    assert "stays in A1" in message
    assert c.engine.diagnosis.runtimes[0].state.name == "A1"

    c = run("F9", 11)
    # wait for the valve at rest, open, no order: the rule that re-synchronises to N5
    while not c.engine.last.diagnosers[0].resync:
        c.run_for(10_000)
    record = c.engine.last.diagnosers[0]
    assert record.resync == "N5" and record.resync_values == "fsc=0, fso=1, C=0, O=0"
    message = c.command(FaultReset()).message
    assert "re-synchronised to N5" in message
    assert c.engine.diagnosis.runtimes[0].state.name == "N5"


def test_normal_records_carry_no_preview():
    c = run("F9", 5)  # before the fault
    record = c.engine.last.diagnosers[0]
    assert not record.faulty and record.resync == "" and record.resync_values == ""
    assert not any(e.key.startswith("diagnosis:") for e in c.engine.last.explanations)


def test_explanations_survive_a_first_scan_without_inputs():
    """The diagnosis stage has not run yet (inputs unknown from the first scan): the other
    explanations are still built (the plant's loss)."""
    project = load_project(VALVE)
    plant = SimPlant(project)

    def unreachable(now_us):
        raise PlantError("connection refused")

    plant.read = unreachable
    engine = Engine(project, plant)
    snap = engine.step(0)
    assert snap.error is None
    assert any(e.key.startswith("safe_state:") for e in snap.explanations)

"""Explanations of diagnoser decisions: certain, ambiguous, degraded sensors, policies."""

from __future__ import annotations

from hmi.cli import main
from hmi.engine.commands import ChoosePolicy, FaultReset
from tests.conftest import PROJECTS
from tests.examples import make_session

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000


def run_to(session, seconds):
    snap = None
    end = session.engine.now + seconds * S
    while session.engine.now < end:
        snap = session.scan_once()
    return snap


def find(snap, key):
    return next(e for e in snap.explanations if e.key == key)


def test_ambiguous_diagnosis_reads_as_such_and_recommends_checking_the_valve_first(capsys):
    # The paper variant: its A1 {F1, F13} is final (the improved one may still refine it to
    # S8 when the switch makes again: an unexpected fall at the arrival).
    assert main(["run", str(VALVE), "--for", "60s", "--inject", "F1@10s", "--explain",
                 "--diagnoser", "paper"]) == 0
    out = capsys.readouterr().out
    assert ("[high] Valve V1: sensor fsc stuck at 0, or valve blocked between its positions "
            "— closed end switch ignored, no longer driven") in out
    section = out.split("Explanation of diagnosis:V1")[1]
    for level in ("Why:", "Consequences:", "Policies:"):
        assert level in section
    assert "cannot tell them apart" in section
    assert "If it is valve blocked between its positions (an actuator fault)" in section
    assert "Recommended: Check Valve V1 first" in section


def test_certain_sensor_fault_recommends_continuing_degraded_with_project_texts():
    session = make_session(VALVE, inject=["F4@10s"])
    snap = run_to(session, 12)
    e = find(snap, "diagnosis:V1")
    assert e.what == "Valve V1: sensor fso stuck at 1 — open end switch ignored"
    assert not e.ambiguous and e.latched and e.severity == "medium"
    assert 'The open end switch says "open" all the time' in e.consequences  # project text
    assert "Already done: open end switch ignored;" in e.consequences  # {action} filled
    assert e.recommended.id == "continue"
    assert e.recommended.effect.startswith("keep filling on the estimate")
    degraded = find(snap, "reconstruction:fso")
    assert degraded.what == ("Valve V1: open end switch fso ignored, position estimated from "
                             "the orders - running degraded")
    assert not degraded.alarm
    alarms = [a.key for a in snap.alarms]
    assert "diagnosis:V1" in alarms and "reconstruction:fso" not in alarms


def test_certain_actuator_fault_recommends_reset_after_repair():
    session = make_session(VALVE, inject=["F11@8.2s"])
    snap = run_to(session, 12)
    e = find(snap, "diagnosis:V1")
    assert "unexpected movement from closed to open — no longer driven" in e.what
    assert "{F11}" in e.detail
    assert "no longer driven" in e.what and e.severity == "high"
    assert e.recommended.id == "reset"


def test_a_diagnosis_alarm_stays_until_reset_and_reset_keeps_a_visible_fault():
    session = make_session(VALVE, inject=["F4@10s"])
    snap = run_to(session, 12)
    assert any(a.key == "diagnosis:V1" and a.latched for a in snap.alarms)
    result = session.command(ChoosePolicy("diagnosis:V1", "continue"))
    assert result.accepted and "Continue degraded" in result.message
    result = session.command(FaultReset())
    snap = session.scan_once()
    # fso is still stuck at 1: the diagnoser cannot re-synchronise and says why.
    assert "V1" in result.message
    assert any(a.key == "diagnosis:V1" for a in snap.alarms)


def test_diagnosis_alarm_is_journalled(tmp_path):
    from hmi.explain.journal import read
    path = tmp_path / "j.jsonl"
    assert main(["run", str(VALVE), "--for", "20s", "--inject", "F1@10s", "--journal",
                 str(path)]) == 0
    raised = [e for e in read(path).entries if e.get("key") == "diagnosis:V1"]
    assert raised and raised[0]["event"] == "raised" and raised[0]["severity"] == "high"
    assert raised[0]["t"] == "16.270"


def test_masked_actuator_has_its_own_explanation_until_the_reset():
    session = make_session(VALVE, inject=["F5@5s"])
    snap = run_to(session, 12)
    assert set(snap.snapshot.masked) == {"C", "O"}
    e = find(snap, "masked:V")
    assert e.kind == "masked" and not e.alarm and e.latched
    assert e.what == ("Valve V1: close order and open order held off — the device is not "
                      "driven")
    assert "def_V" in e.detail
    assert "000 eq. 9-10" in e.detail and "(F2, F5)" in e.detail
    assert "sensor fsc stuck at 1 or valve stuck at the closed position" in e.why
    assert e.since_us == find(snap, "diagnosis:V1").since_us
    assert [p.id for p in e.policies] == ["continue", "stop_device", "reset"]
    assert not [a for a in snap.alarms if a.key == "masked:V"]
    session.command(FaultReset())  # F5 is still there: the diagnoser stays faulty, mask and all
    snap = run_to(session, 1)
    assert snap.snapshot.masked and find(snap, "masked:V")
    healthy = run_to(make_session(VALVE), 12)
    assert not [e for e in healthy.explanations if e.kind == "masked"]

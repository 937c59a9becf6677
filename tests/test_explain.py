"""Graduated explanations, ISA-18.2 alarms, policy choices and the durable journal."""

from __future__ import annotations

import pytest

from hmi.cli import main
from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    FaultReset,
    ManualOutput,
    SetMode,
    SetPolicy,
    StopDevice,
)
from hmi.errors import ProjectError
from hmi.explain.alarms import (
    ACTIVE_ACK,
    ACTIVE_UNACK,
    CLEARED_UNACK,
    AlarmManager,
)
from hmi.explain.journal import Journal, read
from hmi.explain.model import Explanation
from hmi.project.loader import load_project
from hmi.session.journal_recorder import JournalRecorder
from tests.conftest import PROJECTS, write_project
from tests.examples import make_session

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000


def run_until(session, predicate, seconds=30):
    end = session.engine.now + seconds * S
    while session.engine.now < end:
        snap = session.scan_once()
        if predicate(snap):
            return snap
    raise AssertionError("condition not reached")


def explanation(snap, key):
    return next(e for e in snap.explanations if e.key == key)


# -- explanations of each kind ---------------------------------------------------------------

def test_corrected_constraint_explanation_has_four_levels_from_descriptions():
    session = make_session(VALVE, control="faulty", policy="correct")
    snap = run_until(session, lambda s: "CSs5" in s.snapshot.filter_report.violated_names)
    e = explanation(snap, "constraint:CSs5")
    assert e.what == ("Valve V1: close order blocked — start closing only from the open "
                      "position")
    # Plain words first: the rule and the values in words, the model one level
    # deeper, in the engineering detail.
    assert "close order on, close order off just before, open end switch off" in e.why
    assert "CSs5" not in e.what + e.why + e.consequences
    assert "`rise(C) and not fso_filter`" in e.detail and "C=1 (close order); prev(C)=0" in \
        e.detail
    assert "fso_filter=0 (Valve V1 open end switch, as the filter reads it)" in e.detail
    assert f"scan {snap.snapshot.scan}" in e.detail and "CSs5" in e.detail
    assert "The filter sent close order off instead" in e.consequences
    assert e.severity == "low" and e.recommended.id == "continue"
    assert [p.id for p in e.policies] == ["continue", "manual", "stop_device"]


def test_a_violation_that_returns_is_explained_from_its_new_onset():
    """Explanations are reused while a violation lasts, never across two episodes."""
    session = make_session(VALVE, control="faulty", policy="correct")
    first = run_until(session, lambda s: "CSs5" in s.snapshot.filter_report.violated_names)
    held = session.scan_once()  # the program keeps asking: the episode goes on
    assert "CSs5" in held.snapshot.filter_report.violated_names
    assert explanation(held, "constraint:CSs5") is explanation(first, "constraint:CSs5")
    run_until(session, lambda s: "CSs5" not in s.snapshot.filter_report.violated_names)
    again = run_until(session, lambda s: "CSs5" in s.snapshot.filter_report.violated_names)
    e = explanation(again, "constraint:CSs5")
    assert f"Violated since scan {again.snapshot.scan}" in e.detail
    assert f"Violated since scan {first.snapshot.scan}" not in e.detail


def test_explanation_follows_a_policy_change_during_a_violation():
    session = make_session(VALVE, control="faulty", policy="correct")
    before = run_until(session, lambda s: "CSs5" in s.snapshot.filter_report.violated_names)
    assert "NOT corrected" not in explanation(before, "constraint:CSs5").what
    assert session.command(SetPolicy("monitor")).accepted
    snap = session.scan_once()
    # the same episode, under another policy
    assert "CSs5" in snap.snapshot.filter_report.violated_names
    e = explanation(snap, "constraint:CSs5")
    assert "NOT corrected" in e.what and e.severity == "high"


def test_project_texts_fill_their_placeholders():
    session = make_session(VALVE, control="faulty", policy="correct")
    snap = run_until(session, lambda s: "CSc1" in s.snapshot.filter_report.violated_names)
    e = explanation(snap, "constraint:CSc1")
    assert e.what == "Valve V1: open and close ordered together - open order blocked"
    assert "kept the orders apart (open order blocked)" in e.consequences
    assert e.severity == "medium"  # the project's choice


def test_blocked_and_monitor_explanations_differ():
    snap = run_until(make_session(VALVE, control="faulty", policy="block"),
                     lambda s: s.snapshot.latched)
    keys = {e.key for e in snap.explanations}
    assert {"constraint:CSs2", "safe_state:filter"} <= keys
    latch = explanation(snap, "safe_state:filter")
    assert latch.latched and latch.recommended.id == "reset"
    assert "Check the control program before resetting" in latch.consequences
    snap = run_until(make_session(VALVE, control="faulty", policy="monitor"),
                     lambda s: s.snapshot.filter_report.violations)
    e = snap.explanations[0]
    assert "NOT corrected" in e.what and e.severity == "high"
    assert e.recommended.id == "correct"


def test_whole_cell_explanations_say_cell_not_the_project_identifier():
    """The cell's own situations (a latch, manual forces, an internal error) are the cell's,
    said as such: the project's `name:` is an identifier (a folder's name), not a device an
    operator knows."""
    snap = run_until(make_session(VALVE, control="faulty", policy="block"),
                     lambda s: s.snapshot.latched)
    latch = explanation(snap, "safe_state:filter")
    assert latch.what.startswith("Cell: stopped safe")
    session = make_session(VALVE)
    session.scan_once()
    session.command(SetMode(True))
    session.command(ManualOutput("O", True))
    manual = explanation(session.scan_once(), "manual")
    for e in (latch, manual):
        assert "cispi_valve" not in e.what


def test_manual_forces_are_explained_without_an_alarm():
    session = make_session(VALVE)
    session.scan_once()
    session.command(SetMode(True))
    session.command(ManualOutput("O", True))
    snap = session.scan_once()
    e = explanation(snap, "manual")
    assert "MANUAL" in e.what and "open order on" in e.what and not e.alarm
    assert "O=1" in e.detail
    assert not [a for a in snap.alarms if a.key == "manual"]


def test_fallback_and_internal_error_are_explained(tmp_path):
    session = make_session(VALVE)
    session.scan_once()
    session.engine.filter_stage.apply = lambda *args: 1 / 0
    # the filter's first question, asked by the scan
    session.engine.safety_filter.violations = lambda *args: 1 / 0
    snap = session.scan_once()
    e = explanation(snap, "safe_state:internal")
    assert "internal error" in e.what and "ZeroDivisionError" in e.detail
    assert "ZeroDivisionError" not in e.why and e.severity == "high"


PLACEHOLDER_PROJECT = """\
name: x
scan_period: 10ms
inputs: {fsc: a, fso: b}
outputs: {C: c, O: o}
control: {equations: {C: fsc}}
constraints:
  K1: C and fsc
explanations:
  constraints:
EXPLANATIONS
plant: {kind: sim, model: valve}
"""


def placeholder_errors(tmp_path, explanations: str) -> list:
    """The load errors of a small valve project whose constraint explanations are
    `explanations` (YAML, indented under `constraints:`)."""
    text = PLACEHOLDER_PROJECT.replace("EXPLANATIONS\n", explanations)
    with pytest.raises(ProjectError) as info:
        load_project(write_project(tmp_path / "x", {"project.yaml": text}))
    return info.value.errors


def test_unknown_placeholder_is_a_load_error_with_position(tmp_path):
    messages = [str(d) for d in placeholder_errors(
        tmp_path, '    K1: {what: "{device}: {devise} blocked"}\n    K9: {what: hello}\n')]
    assert any("unknown placeholder {devise}" in m and ":10:" in m for m in messages)
    assert any("explanations for unknown constraint 'K9'" in m for m in messages)


def test_unknown_placeholder_in_a_text_over_several_lines_points_at_its_line(tmp_path):
    """A folded block (as the example projects write their longer texts): the error names
    the placeholder's own line and column, not an offset on the block's first line."""
    errors = placeholder_errors(tmp_path, "    K1:\n      what: >-\n"
                                "        {device}: the close order is held\n"
                                "        off while {devise} is closed\n")
    [diagnostic] = [d for d in errors if "unknown placeholder {devise}" in d.message]
    assert (diagnostic.pos.line, diagnostic.pos.col) == (13, 19), str(diagnostic)


# -- alarms ----------------------------------------------------------------------------------

def make_exp(key="k", latched=False, severity="low", text="thing") -> Explanation:
    return Explanation(key, "constraint", severity, "dev", text, "why", "cons", (), 0, 0,
                       latched=latched)


def test_isa_18_2_states():
    m = AlarmManager()
    e = make_exp()
    events = m.update((e,), 1, 0)
    assert [(x.event, x.state) for x in events] == [("raised", ACTIVE_UNACK)]
    assert [(x.event, x.state) for x in m.acknowledge("k", 2, 10)] == [
        ("acknowledged", ACTIVE_ACK)]
    events = m.update((), 3, 20)  # acknowledged then cleared: back to normal
    assert [(x.event, x.state) for x in events] == [("cleared", "normal")] and not m.alarms
    m.update((e,), 4, 30)
    events = m.update((), 5, 40)  # cleared before acknowledgement: stays listed
    assert [(x.event, x.state) for x in events] == [("cleared", CLEARED_UNACK)]
    assert m.listed()[0].state == CLEARED_UNACK
    events = m.update((e,), 6, 50)  # returns
    assert [(x.event, x.state) for x in events] == [("returned", ACTIVE_UNACK)]
    m.update((), 7, 60)
    assert [(x.event, x.state) for x in m.acknowledge(None, 8, 70)] == [
        ("acknowledged", "normal")]
    assert not m.alarms


def test_acknowledge_all_and_ordering_by_priority():
    m = AlarmManager()
    m.update((make_exp("a", severity="low"), make_exp("b", severity="high")), 1, 0)
    assert [a.key for a in m.listed()] == ["b", "a"]
    m.update((make_exp("a", severity="low"), make_exp("c", severity="low")), 2, 1)
    # active unacknowledged, then cleared unacknowledged (b), whatever their priority
    assert [(a.key, a.state) for a in m.listed()] == [
        ("c", ACTIVE_UNACK), ("a", ACTIVE_UNACK), ("b", CLEARED_UNACK)]
    assert len(m.acknowledge(None, 3, 2)) == 3  # b, cleared, leaves the list
    assert sorted(a.key for a in m.listed()) == ["a", "c"]
    assert all(a.state == ACTIVE_ACK for a in m.listed())


def chatter(m: AlarmManager, times: int = 10) -> tuple[list, int]:
    """One alarm returning every 2 s (10 times a minute): its events, and the time after."""
    e = make_exp()
    events: list = []
    t = 0
    for _ in range(times):
        events += m.update((e,), 0, t)
        events += m.update((), 0, t + S)
        t += 2 * S
    return events, t


def test_chattering_is_collapsed_into_one_alarm_with_a_count():
    m = AlarmManager()
    events, t = chatter(m)
    kinds = [x.event for x in events]
    assert kinds.count("chattering") == 1
    assert kinds.count("returned") == 4  # the 4th return makes it chattering; then collapsed
    alarm = m.listed()[0]
    assert alarm.chattering and alarm.active and alarm.returns == 9
    later = m.update((), 0, t + 61 * S)  # stays clear for a minute: finally clears
    assert [x.event for x in later] == ["cleared"]


def test_alarms_are_settled_only_when_the_same_update_would_change_nothing():
    """AlarmManager.settled decides a quiet scan (hmi.session.Session.run_for): no update
    then, so it must be true only when an update with the last scan's explanations would
    change nothing."""
    m = AlarmManager()
    e, f = make_exp("k"), make_exp("j")
    assert m.settled(())
    assert not m.settled((e,))  # it would raise it
    m.update((e,), 1, 0)
    assert m.settled((e,)) and m.update((e,), 2, 1) == []
    assert not m.settled(()) and not m.settled((make_exp("k"),))  # clears; new text
    m.update((e, f), 3, 2)
    assert m.settled((e, f)) and not m.settled((e,))  # without f: f clears
    m.update((e,), 4, 3)
    assert m.settled((e,))  # f cleared, waits for its acknowledgement
    m.update((), 5, 4)
    assert m.settled(()) and m.update((), 6, 5) == []
    assert not m.settled((e,))  # it would return
    m.acknowledge(None, 7, 6)
    _, t = chatter(m)
    assert not m.settled(())  # chattering: held active while clear, for a minute
    assert m.update((), 0, t + 61 * S) and m.settled(())
    m.shelve("k", 10 * S, 0, t + 62 * S)
    assert not m.settled(())  # the shelf runs out with time


def test_latched_alarm_stays_until_fault_reset():
    session = make_session(VALVE, control="faulty", policy="block")
    snap = run_until(session, lambda s: s.snapshot.latched)
    for _ in range(200):
        snap = session.scan_once()
    alarm = next(a for a in snap.alarms if a.key == "safe_state:filter")
    assert alarm.active and alarm.latched
    session.command(Acknowledge("safe_state:filter"))
    session.command(FaultReset())
    snap = session.scan_once()
    assert not [a for a in snap.alarms if a.key == "safe_state:filter"]
    assert any(e.event == "cleared" and e.key == "safe_state:filter" for e in snap.alarm_events)


# -- policy choices --------------------------------------------------------------------------

def test_choosing_stop_device_masks_its_outputs_and_release_restores():
    session = make_session(VALVE, control="faulty", policy="correct")
    run_until(session, lambda s: "CSs2" in s.snapshot.filter_report.violated_names)
    result = session.command(ChoosePolicy("constraint:CSs2", "stop_device"))
    assert result.accepted and "Valve V1 stopped" in result.message
    snaps = [session.scan_once() for _ in range(500)]
    assert all(s.snapshot.outputs == (False, False) for s in snaps)
    assert snaps[-1].snapshot.stopped_devices == ("Valve V1",)
    from hmi.engine.commands import ReleaseDevice
    assert session.command(ReleaseDevice("Valve V1")).accepted
    assert not session.command(ChoosePolicy("constraint:CSs2", "teleport")).accepted


def test_choosing_manual_and_reset_policies_send_their_commands():
    session = make_session(VALVE, control="faulty", policy="block")
    run_until(session, lambda s: s.snapshot.latched)
    assert session.command(ChoosePolicy("safe_state:filter", "reset")).accepted
    assert not session.engine.latched
    snap = run_until(session, lambda s: s.snapshot.latched)
    assert session.command(ChoosePolicy("safe_state:filter", "manual")).accepted
    assert session.engine.mode == "manual"
    assert snap.snapshot.scan


# -- journal ---------------------------------------------------------------------------------

def test_journal_records_actions_alarm_transitions_and_manual_outcomes(tmp_path):
    session = make_session(VALVE)
    recorder = JournalRecorder(session, Journal(tmp_path / "j.jsonl"), "test")
    session.scan_once()
    session.command(SetMode(True))
    session.command(ManualOutput("C", True))  # closing a closed valve: refused by CSs1 and CSs5
    session.scan_once()
    session.command(Acknowledge(None))
    session.scan_once()
    recorder.close()
    entries = read(tmp_path / "j.jsonl").entries
    events = [(e["type"], e["event"]) for e in entries]
    assert events[0] == ("session", "start") and events[-1] == ("session", "stop")
    assert ("action", "enter manual mode") in events
    outcome = next(e for e in entries if e["event"] == "manual C on: filter result")
    assert outcome["message"] == "refused: written 0 because of CSs1, CSs5"
    raised = [e for e in entries if e["type"] == "alarm" and e["event"] == "raised"]
    assert {e["key"] for e in raised} == {"constraint:CSs1", "constraint:CSs5"}
    assert all(e["scan"] == 2 and e["t"] == "0.010" and e["wall"] for e in raised)
    assert [e["event"] for e in entries if e["type"] == "alarm"].count("acknowledged") == 2


def test_journal_judges_a_manual_request_against_what_it_asked(tmp_path):
    """Soak seed 200 (sorting, faulty): 'manual CONV_R on' then a recovery started before
    the next scan; the journal said 'written 0 as requested'. The outcome is judged against
    the request: a scan outside manual mode did not apply it, a stopped device refused it."""
    session = make_session(VALVE)
    recorder = JournalRecorder(session, Journal(tmp_path / "j.jsonl"), "test")
    session.scan_once()
    assert session.command(SetMode(True)).accepted
    session.scan_once()
    session.command(ManualOutput("O", True))
    assert session.command(SetMode(False)).accepted  # left before a scan ran the request
    assert session.scan_once().snapshot.output_map["O"] is False
    assert session.command(SetMode(True)).accepted
    session.scan_once()
    assert session.command(StopDevice("Valve V1")).accepted
    session.command(ManualOutput("O", True))
    assert session.scan_once().snapshot.output_map["O"] is False
    session.command(ManualOutput("O", False))  # what it asked: the stop changes nothing
    session.scan_once()
    recorder.close()
    outcomes = [e["message"] for e in read(tmp_path / "j.jsonl").entries
                if e["event"].endswith(": filter result")]
    assert outcomes == ["not applied: the scan ran in auto mode (written 0)",
                        "refused: written 0: Valve V1 is stopped by the operator",
                        "written 0 as requested"]


def test_truncated_last_line_is_tolerated(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    journal = Journal(path)
    journal.append({"type": "action", "event": "one", "scan": 1, "t": "0.000"})
    journal.append({"type": "action", "event": "two", "scan": 2, "t": "0.010"})
    journal.close()
    with path.open("ab") as f:
        f.write(b'{"wall":"2026-11-22T10:00:00.000+00:00","type":"ac')
    result = read(path)
    assert [e["event"] for e in result.entries] == ["one", "two"] and result.truncated
    assert main(["journal", str(VALVE), "--path", str(path)]) == 0
    captured = capsys.readouterr()
    assert "one" in captured.out and "two" in captured.out
    assert "cut short" in captured.err


def test_journal_csv_export(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    assert main(["run", str(VALVE), "--for", "10s", "--control", "faulty",
                 "--journal", str(path)]) == 0
    capsys.readouterr()
    assert main(["journal", str(VALVE), "--path", str(path), "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == ("wall,scan,t,type,event,key,state,severity,text,message,by,"
                        "accepted,session")
    assert any(",alarm,raised,constraint:CSs2," in line for line in lines)


def test_journal_csv_says_each_start_what_was_accepted_and_the_session(tmp_path, capsys):
    """The CSV's session start rows were blank (the control program, the filter policy and
    the plant are fields of their own in the JSON entry); an action's outcome had no column;
    nothing told two sessions apart. Two runs into one journal, a refused and an accepted
    command in the second."""
    import csv
    path = tmp_path / "j.jsonl"
    assert main(["run", str(VALVE), "--for", "1s", "--journal", str(path)]) == 0
    assert main(["run", str(VALVE), "--for", "3s", "--control", "faulty", "--policy",
                 "block", "--journal", str(path)]) == 0
    journal = Journal(path)
    journal.session = "later-1"
    journal.append({"type": "action", "event": "fault reset", "accepted": False,
                    "message": "nothing to reset", "scan": 1, "t": "0.010"})
    journal.append({"type": "action", "event": "acknowledge all", "accepted": True,
                    "message": "acknowledged 1 alarm", "scan": 2, "t": "0.020"})
    journal.close()
    capsys.readouterr()
    assert main(["journal", str(VALVE), "--path", str(path), "--csv"]) == 0
    rows = list(csv.DictReader(capsys.readouterr().out.splitlines()))
    starts = [r for r in rows if r["type"] == "session" and r["event"] == "start"]
    assert len(starts) == 2
    assert "control normal" in starts[0]["message"] and "filter policy correct" in \
        starts[0]["message"] and "plant simulated" in starts[0]["message"]
    assert "control faulty" in starts[1]["message"] and "filter policy block" in \
        starts[1]["message"]
    sessions = [r["session"] for r in rows]
    assert all(sessions) and sessions[0] != starts[1]["session"]
    first = {r["session"] for r in rows[:rows.index(starts[1])]}
    assert first == {starts[0]["session"]}  # every row of a session carries its id
    actions = {r["event"]: r for r in rows if r["type"] == "action"}
    assert actions["fault reset"]["accepted"] == "false"
    assert actions["acknowledge all"]["accepted"] == "true"
    assert {r["session"] for r in actions.values()} == {"later-1"}
    assert all(r["accepted"] == "" for r in rows if r["type"] != "action")


def test_run_prints_alarms_and_full_explanations(capsys):
    assert main(["run", str(VALVE), "--for", "10s", "--control", "faulty", "--explain"]) == 0
    out = capsys.readouterr().out
    assert "Alarms:" in out and "[low] Valve V1: open order blocked" in out
    assert "Explanation of constraint:CSs2" in out and "Consequences:" in out
    assert "Recommended: Continue" in out

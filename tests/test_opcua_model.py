"""The OPC UA address space and alarm mapping as plain data (no server, no asyncua).

The model must name every input and output of a project with its description, read values
of the declared types from real snapshots, and the condition tracker must send exactly the
transitions a SCADA needs: each state change once, acknowledgements seen only in the alarm
list included, nothing for what did not change.
"""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from hmi.engine.commands import Acknowledge, FaultReset, Shelve, Unshelve
from hmi.engine.scan import Engine
from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK, CLEARED_UNACK
from hmi.explain.journal import Journal
from hmi.opcua.conditions import HMI_USER, NORMAL, SEVERITY, ConditionTracker
from hmi.opcua.model import BOOL, DOUBLE, STRING, STRINGS, UINT, build_model
from hmi.plant.select import open_plant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session

ROOT = Path(__file__).resolve().parent.parent
PROJECTS = sorted(p.name for p in (ROOT / "projects").iterdir() if (p / "project.yaml").exists())
TYPES = {BOOL: bool, STRING: str, STRINGS: list, DOUBLE: float, UINT: int}


def _session(name: str, faults: tuple[str, ...] = ()) -> Session:
    project = load_project(ROOT / "projects" / name)
    injections = [parse_injection(f) for f in faults]
    return Session(Engine(project, open_plant(project, None, False, injections, None)))


@pytest.mark.parametrize("name", PROJECTS)
def test_every_io_of_every_project_is_in_the_model_with_its_description(name):
    session = _session(name)
    project = session.project
    model = build_model(project, session.engine.layout)
    paths = {p.path for p in model.points}
    folders = {f.path: f for f in model.folders}
    for var in project.inputs:
        base = (var.device, "Inputs", var.name) if var.device else ("Inputs", var.name)
        assert (*base, "Value") in paths
        assert folders[base].description == (var.description or var.name)
    for var in project.outputs:
        base = (var.device, "Outputs", var.name) if var.device else ("Outputs", var.name)
        for leaf in ("ProgramValue", "WrittenValue", "FilterChanged", "FilterConstraint"):
            assert (*base, leaf) in paths
    for c in project.constraints:
        assert ("Constraints", c.name) in paths
    assert len(paths) == len(model.points), "two variables at one place"
    assert all(p.description for p in model.points)
    units = {p.path[-1]: p.unit for p in model.points}
    assert units["ScanTime"] == "ms" and units["RunTime"] == "s"


@pytest.mark.parametrize("name", PROJECTS)
def test_every_point_reads_a_value_of_its_type_from_real_snapshots(name):
    session = _session(name)
    model = build_model(session.project, session.engine.layout)
    for _ in range(50):
        snapshot = session.scan_once()
        for point in model.points:
            value = point.read(snapshot)
            assert isinstance(value, TYPES[point.kind]), (point.path, value)
            if point.kind == STRINGS:
                assert all(isinstance(v, str) for v in value)


def test_the_model_follows_the_filter_and_the_diagnoser_of_a_faulty_valve():
    session = _session("cispi_valve", ("F5@8.2s",))
    model = build_model(session.project, session.engine.layout)
    points = {p.path: p for p in model.points}
    masked_seen = state_seen = False
    for _ in range(1100):
        snap = session.scan_once()
        state = points[("Valve V1", "Diagnosers", "V1", "State")].read(snap)
        assert state == snap.snapshot.diagnosers[0].state
        flag = points[("Valve V1", "Diagnosers", "V1", "Flags", "def_V")].read(snap)
        assert flag == dict(snap.snapshot.diagnosers[0].flags)["def_V"]
        state_seen |= state == "B2"
        for out in ("C", "O"):
            base = ("Valve V1", "Outputs", out)
            assert points[(*base, "WrittenValue")].read(snap) == snap.snapshot.output_map[out]
            assert points[(*base, "ProgramValue")].read(snap) == snap.snapshot.fov_map[out]
            masked = points[(*base, "Masked")].read(snap)
            masked_seen |= masked
            if points[(*base, "FilterChanged")].read(snap):
                assert points[(*base, "FilterConstraint")].read(snap)
    assert state_seen and masked_seen


# -- the condition tracker -------------------------------------------------------------------


def _run_with_acks(seed: int, journal: Path, scans: int = 2500):
    """A faulty valve run where an operator acknowledges and resets at random; journalled,
    as every real session is (the journal takes the acknowledgements at once)."""
    rng = random.Random(seed)
    session = _session("cispi_valve", ("F5@8.2s", "F8@20s"))
    JournalRecorder(session, Journal(journal))
    tracker = ConditionTracker()
    sent = []
    batches = []
    for _ in range(scans):
        snap = session.scan_once()
        if snap.alarm_events:
            batches.append((snap.alarm_events, snap.alarms))
        if rng.random() < 0.01:
            keys = [a.key for a in snap.alarms]
            session.command(Acknowledge(rng.choice(keys) if keys and rng.random() < 0.7
                                        else None))
        if rng.random() < 0.002:
            session.command(FaultReset())
        # Shelving, both ways, mostly of what may be shelved (a latched alarm may not).
        keys = [a.key for a in snap.alarms if not (a.latched and a.active)
                or rng.random() < 0.1] + [a.key for a, _ in snap.shelved]
        if keys and rng.random() < 0.05:
            key = rng.choice(keys)
            duration = rng.choice([None, 500_000, 5_000_000])
            session.command(Unshelve(key) if rng.random() < 0.3 else Shelve(key, duration))
        if rng.random() < 0.3:  # the publisher wakes now and then, never every scan
            views = tracker.update(batches, snap.alarms, snap.snapshot.time_us, snap.shelved)
            batches = []
            sent.extend(views)
            yield snap, views, tracker, sent


@pytest.mark.parametrize("seed", range(6))
def test_the_tracker_sends_each_state_change_once_and_ends_in_the_lists_state(seed, tmp_path):
    last = None
    for snap, views, tracker, sent in _run_with_acks(seed, tmp_path / "journal.jsonl"):
        listed = {a.key: (a.state, "Unshelved") for a in snap.alarms}
        listed |= {a.key: (a.state, "OneShotShelved" if shelf.until_us is None
                           else "TimedShelved") for a, shelf in snap.shelved}
        # After each update the conditions SCADA was told of are the alarm list and the
        # alarms shelved out of it, exactly, each with its shelving state.
        assert {k: (sent[0], sent[2]) for k, sent in tracker.sent.items()} == listed
        assert set(tracker.retained()) == set(listed)
        for view in views:
            assert view.retain == (view.state != NORMAL)
            assert view.active == (view.state in (ACTIVE_UNACK, ACTIVE_ACK))
            assert view.acked == (view.state in (ACTIVE_ACK, NORMAL))
            assert view.severity == SEVERITY[view.priority]
            assert view.message
        last = sent
    assert last is not None
    by_key: dict[str, list[tuple[str, str]]] = {}
    for view in last:
        states = by_key.setdefault(view.key, [])
        assert not states or states[-1] != (view.state, view.shelving) or view.transition in (
            "returned", "condition-returned"), "the same state sent twice in a row"
        states.append((view.state, view.shelving))
        assert view.shelved == (view.shelving != "Unshelved")
        assert (view.unshelve_ms > 0) <= (view.shelving == "TimedShelved")
    assert any(v.transition == "acknowledged" for v in last), "no acknowledgement exercised"
    assert any(v.shelved for v in last), "no shelving exercised"


def test_an_acknowledgement_seen_only_in_the_list_is_sent_with_who_did_it():
    session = _session("cispi_valve", ("F5@8.2s",))
    tracker = ConditionTracker()
    batches = []
    for _ in range(1000):
        cell = session.scan_once()
        if cell.alarm_events:
            batches.append((cell.alarm_events, cell.alarms))
    raised = tracker.update(batches, cell.alarms, cell.snapshot.time_us)
    high = next(v for v in raised if v.key == "diagnosis:V1")
    assert high.state == ACTIVE_UNACK and high.severity == 900 and high.retain
    alarm = next(a for a in cell.alarms if a.key == "diagnosis:V1")
    assert high.message == alarm.text and high.why == alarm.explanation.why
    assert high.consequences == alarm.explanation.consequences
    assert high.policies == alarm.explanation.policies_text()

    tracker.acknowledged_by("diagnosis:V1", "alice", "on my way")
    session.command(Acknowledge("diagnosis:V1"))
    session.command(Acknowledge("constraint:CSs4"))  # from the HMI
    cell = session.scan_once()  # no alarm event: the journal took the acknowledgements
    views = {v.key: v for v in tracker.update([], cell.alarms, cell.snapshot.time_us)}
    assert views["diagnosis:V1"].state == ACTIVE_ACK
    assert (views["diagnosis:V1"].user, views["diagnosis:V1"].comment) == ("alice",
                                                                          "on my way")
    cleared = views["constraint:CSs4"]
    assert cleared.state == NORMAL and not cleared.retain and cleared.user == HMI_USER
    # nothing changed: nothing sent
    assert tracker.update([], cell.alarms, cell.snapshot.time_us) == []
    assert CLEARED_UNACK not in {sent[0] for sent in tracker.sent.values()}


def test_shelving_states_read_as_part9_names_with_the_time_left():
    from hmi.explain.alarms import Alarm, Shelf
    alarm = Alarm("monitor:T1", ACTIVE_UNACK, "medium", "Conveyor C1: too slow", "Conveyor C1",
                  "monitor", 10, 1_000_000, 1_000_000)
    tracker = ConditionTracker()
    [raised] = tracker.update([], (alarm,), 1_000_000)
    assert (raised.shelving, raised.shelved, raised.transition) == ("Unshelved", False,
                                                                      "raised")
    [once] = tracker.update([], (), 2_000_000, ((alarm, Shelf(2_000_000, None)),))
    assert (once.shelving, once.shelved, once.transition, once.time_us) == (
        "OneShotShelved", True, "shelved", 2_000_000)
    assert once.retain and once.unshelve_ms == 0
    [back] = tracker.update([], (alarm,), 3_000_000)
    assert (back.shelving, back.transition, back.time_us) == ("Unshelved", "unshelved",
                                                              3_000_000)
    [timed] = tracker.update([], (), 4_000_000, ((alarm, Shelf(4_000_000, 64_000_000)),))
    assert timed.shelving == "TimedShelved" and timed.unshelve_ms == 60_000
    assert tracker.update([], (), 5_000_000, ((alarm, Shelf(4_000_000, 64_000_000)),)) == []
    [gone] = tracker.update([], (), 6_000_000)  # cleared while shelved: back to normal
    assert (gone.state, gone.retain, gone.shelved) == ("normal", False, False)

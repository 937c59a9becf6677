"""The stopwatch monitors of the sorting and palletizer cells (projects/*/monitors.yaml):
`plchmi check` lists them, normal runs of both programs raise no monitor fault, and each fault
scenario of docs/sorting.md and docs/palletizer.md raises the labels those pages report, at
the instants they report (within a scan), before or after the damage as they say; and an
operator who stops the device the alarm recommends, at the detection scan, avoids the damage
where the pages say so."""

from __future__ import annotations

import pytest

from hmi.cli import main
from hmi.engine.commands import StopDevice
from hmi.project.loader import load_project
from hmi.project.monitors import monitors_of
from hmi.project.scenarios import scenarios_of
from tests.cellruns import SHARED, run, scenario_run
from tests.conftest import PROJECTS, make_session

MS = 1_000
S = 1_000_000
PERIOD = {"sorting": 5 * MS, "palletizer": 10 * MS}
TASKS = {
    "sorting": ("approach", "load", "leave_0", "turn_90", "leave_90", "turn_0", "unload",
                "deliver_left", "deliver_right"),
    "palletizer": ("leave_home", "push", "retract", "clamp_close", "clamp_open", "plate_open",
                   "plate_close", "raise_empty", "raise_to_layer", "lower_layer"),
}


@pytest.mark.parametrize("name", sorted(TASKS))
def test_check_lists_the_cells_monitors(name, capsys):
    assert tuple(m.name for m in monitors_of(load_project(PROJECTS / name))) == TASKS[name]
    assert main(["check", str(PROJECTS / name)]) == 0
    out = capsys.readouterr().out
    assert f"Monitors ({len(TASKS[name])}: stopwatch" in out
    for task in TASKS[name]:
        assert f"\n  {task}  normal [" in out
    assert "Warnings" not in out  # every bound on the scan grid


@pytest.mark.parametrize("name,control", [("sorting", "normal"), ("sorting", "faulty"),
                                          ("palletizer", "normal"), ("palletizer", "faulty")])
def test_no_monitor_fault_in_a_normal_run(name, control):
    # docs/sorting.md and docs/palletizer.md report the same over 10 virtual minutes.
    normal = run(name, control)
    last, damage = normal.last, normal.damage
    assert not damage
    monitors = {m.name: m for m in last.monitors}
    assert tuple(monitors) == TASKS[name]
    for m in monitors.values():
        assert m.faults == 0 and m.detection is None, m.name
        assert m.completed >= 1, f"{m.name} never ran: the run does not test its window"


# The labels each fault scenario of scenarios.yaml raises: label -> (rule, instant), as the
# doc pages' tables report them, and the damage of that run -> instant. Every declared
# scenario must be listed here, and only those.
EXPECTED = {
    ("sorting", "tt_back_stuck1"): ({"unload_fault": ("overrun", 20_920)}, {}),
    ("sorting", "entry_end_stuck0"): ({"approach_fault": ("overrun", 22_145)}, {}),
    ("sorting", "high_stuck0"): ({}, {}),
    ("sorting", "left_blocked"): ({"deliver_left_fault": ("overrun", 28_775),
                                   "unload_fault": ("overrun", 47_275)}, {}),
    ("sorting", "tt_back_stuck0"): ({"unload_fault": ("too_fast", 20_000),
                                     "deliver_left_fault": ("overrun", 23_000),
                                     "load_fault": ("overrun", 23_625)},
                                    {"box_sheared": 20_005}),
    ("sorting", "tt_front_stuck0"): ({"unload_fault": ("too_fast", 14_000),
                                      "deliver_right_fault": ("overrun", 17_000)},
                                     {"box_dropped": 17_005}),
    ("sorting", "table_jam"): ({"leave_90_fault": ("overrun", 20_205),
                                "turn_0_fault": ("overrun", 21_405)}, {"turn_stall": 21_110}),
    ("palletizer", "plate_closed_stuck1"): ({"plate_close_fault": ("overrun", 23_460)}, {}),
    ("palletizer", "clamp_closed_stuck1"): ({}, {}),
    ("palletizer", "layer_eye_stuck0"): ({"raise_to_layer_fault": ("overrun", 21_660)},
                                         {"load_crushed": 20_265}),
    ("palletizer", "pusher_home_stuck1"): ({"leave_home_fault": ("overrun", 23_680),
                                            "retract_fault": ("cannot_finish", 25_650)},
                                           {"box_against_pusher": 24_555}),
    ("palletizer", "clamp_open_stuck1"): ({"lower_layer_fault": ("too_fast", 20_090),
                                           "clamp_open_fault": ("overrun", 20_670),
                                           "plate_close_fault": ("cannot_finish", 21_000)},
                                          {"plate_into_layer": 20_095}),
    ("palletizer", "elevator_jam"): ({"lower_layer_fault": ("overrun", 22_850)},
                                     {"elevator_stall": 21_555}),
}
# The scenarios where the pages say the first monitor fault comes before the damage.
BEFORE_DAMAGE = {("sorting", "tt_back_stuck0"), ("sorting", "tt_front_stuck0"),
                 ("sorting", "table_jam"), ("palletizer", "pusher_home_stuck1"),
                 ("palletizer", "clamp_open_stuck1")}


def test_every_declared_scenario_has_its_expected_detections():
    declared = {(name, s.name) for name in TASKS
                for s in scenarios_of(load_project(PROJECTS / name))}
    assert declared == set(EXPECTED)


@SHARED
@pytest.mark.parametrize("name,scenario", sorted(EXPECTED),
                         ids=[f"{n}-{s}" for n, s in sorted(EXPECTED)])
def test_fault_scenarios_raise_the_expected_monitor_labels(name, scenario):
    labels, damage_at = EXPECTED[(name, scenario)]
    run = scenario_run(name, scenario)
    last, damage = run.last, run.damage
    found = {m.label: m.detection for m in last.monitors if m.detection is not None}
    assert set(found) == set(labels)
    for label, (rule, ms) in labels.items():
        d = found[label]
        assert d.rule == rule, label
        assert abs(d.time_us - ms * MS) <= PERIOD[name], (label, d.time_us)
    assert {kind: t for t, kind in damage} == {k: ms * MS for k, ms in damage_at.items()}
    if damage:
        first = min(d.time_us for d in found.values())
        assert (first < damage[0][0]) == ((name, scenario) in BEFORE_DAMAGE)


def test_the_operator_reads_the_cells_own_explanation_of_a_monitor_fault(capsys):
    assert main(["run", str(PROJECTS / "sorting"), "--scenario", "table_jam",
                 "--explain"]) == 0
    out = capsys.readouterr().out
    assert "20.205 s  [high] Turntable: still on its end switch 0.100 s after the turn " \
           "order" in out
    assert "motor stalls and overheats after about a second (turn_stall)" in out
    assert "Recommended: Stop Turntable" in out


def act_on_alarm(name: str, inject: str, label: str, device: str, seconds: int = 30):
    """Run with `inject`; at the scan `label` is raised, stop `device` as the operator would.
    Returns that instant and the damage events (plant time, kind)."""
    session = make_session(PROJECTS / name, inject=[inject])
    stopped, damage = [], []

    def on_scan(cell):
        snap = cell.snapshot
        damage.extend((e.time_us, e.kind) for e in snap.plant_events if e.damage)
        if not stopped and any(m.label == label and m.detection for m in snap.monitors):
            stopped.append(snap.time_us)
            assert session.command(StopDevice(device)).accepted
    session.run_for(seconds * S, on_scan)
    return stopped[0], damage


@pytest.mark.parametrize("name,inject,label,device,at_ms", [
    ("sorting", "table_jam@20s", "leave_90_fault", "Turntable", 20_205),  # turn_stall 21.110
    ("sorting", "tt_front_stuck0@14s", "unload_fault", "Turntable", 14_000),  # drop 17.005
    ("palletizer", "pusher_home_stuck1@20s", "leave_home_fault", "Feed conveyor", 23_680),
])
def test_stopping_the_device_the_alarm_names_prevents_the_damage(name, inject, label, device,
                                                                  at_ms):
    stopped, damage = act_on_alarm(name, inject, label, device)
    assert stopped == at_ms * MS
    assert damage == []


def test_stopping_the_pusher_instead_of_the_feed_brings_the_damage_earlier():
    # docs/palletizer.md: halted out of home, the pusher is what the feed drives a box into.
    stopped, damage = act_on_alarm("palletizer", "pusher_home_stuck1@20s", "leave_home_fault",
                                   "Pusher")
    assert stopped == 23_680 * MS
    assert damage == [(23_695 * MS, "box_against_pusher")]  # instead of 24.555 s

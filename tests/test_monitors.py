"""Stopwatch monitors in the engine, on the conveyor/robot cell of 002 §4 (1 t.u. = 1 s)."""

from __future__ import annotations

import pytest

from hmi.cli import main
from hmi.engine.commands import FaultReset
from hmi.project.loader import load_project
from hmi.session.trace import TraceWriter
from hmi.studies.monitor_sweep import run_sweep
from tests.conftest import PROJECTS
from tests.examples import make_session

CELL = PROJECTS / "conveyor_robot"
MS = 1_000
S = 1_000_000


def run(inject=(), seconds=12):
    session = make_session(CELL, inject=inject)
    snaps = []
    session.run_for(seconds * S, snaps.append)
    return session, snaps


def monitor(snap, name):
    return next(m for m in snap.snapshot.monitors if m.name == name)


def at(snaps, t_us):
    return next(s for s in snaps if s.snapshot.time_us == t_us)


def test_the_cell_cycles_and_every_task_is_in_time_without_faults():
    session, snaps = run(seconds=30)
    last = snaps[-1]
    conveyor, robot = monitor(last, "conveyor"), monitor(last, "robot")
    assert conveyor.faults == robot.faults == 0
    assert conveyor.completed >= 8 and robot.completed >= 8
    assert not any(e.damage for s in snaps for e in s.snapshot.plant_events)
    # Each conveyor attempt measured by the monitor equals the device's own record.
    device = session.engine.plant.devices[0]
    assert all(r.work_us == 3_500 * MS for r in device.task_records() if r.end_us)


def test_the_papers_scenario_fault_at_x2_3_y2_1_and_watchdog_at_5():
    _, snaps = run(["C1.stop@1s+2s"])
    # Conveyor and robot start together at the first scan (location L7 of 002 Fig. 9).
    first = snaps[0]
    assert [m.location for m in first.snapshot.monitors] == ["executing", "executing"]
    assert monitor(at(snaps, 2_990 * MS), "conveyor").location == "interrupted"
    m = monitor(at(snaps, 3 * S), "conveyor")
    assert m.location == "faulty" and m.labels == ("conveyor_fault",)
    d = m.detection
    assert (d.rule, d.time_us, d.x_us, d.y_us, d.scan) == ("cannot_finish", 3 * S, 3 * S,
                                                           1 * S, 301)
    trip = monitor(snaps[-1], "conveyor").watchdog
    assert trip.attempt == 1 and (trip.time_us, trip.x_us) == (5 * S, 5 * S)
    assert monitor(snaps[-1], "robot").faults == 0  # the robot is not disturbed


def test_tasks_run_concurrently_and_independently():
    both = run(["C1.stop@1s+2s", "R1.stop@500ms+2.5s"])[1][-1]
    alone_c = run(["C1.stop@1s+2s"])[1][-1]
    alone_r = run(["R1.stop@500ms+2.5s"])[1][-1]
    # Robot: interrupted at y4 = 0.5; alpha4 - y4 = 1.5 no longer fits before gamma4 = 4
    # once x4 = 2.5. Conveyor as in the paper. The same instants alone and together.
    r, c = monitor(both, "robot").detection, monitor(both, "conveyor").detection
    assert (r.time_us, r.x_us, r.y_us) == (2_500 * MS, 2_500 * MS, 500 * MS)
    assert (c.time_us, c.x_us, c.y_us) == (3 * S, 3 * S, 1 * S)
    assert monitor(alone_r, "robot").detection == r
    assert monitor(alone_c, "conveyor").detection == c


@pytest.mark.parametrize("inject,task,rule,t_us,x_us,y_us", [
    (["C1.slip@1s"], "conveyor", "overrun", 4 * S, 4 * S, 4 * S),
    (["R1.skip@1s"], "robot", "too_fast", 1 * S, 1 * S, 1 * S),
    (["C1.stop@1s+1.5s"], "conveyor", "late_end", 5 * S, 5 * S, 3_500 * MS),
    (["C1.stop@3200ms+1700ms"], "conveyor", "deadline", 5 * S, 5 * S, 3_300 * MS),
    (["R1.stop@1s+2.5s"], "robot", "cannot_finish", 3 * S, 3 * S, 1 * S),
])
def test_each_rule_through_the_simulated_plant(inject, task, rule, t_us, x_us, y_us):
    _, snaps = run(inject)
    d = monitor(snaps[-1], task).detection
    assert (d.rule, d.time_us, d.x_us, d.y_us) == (rule, t_us, x_us, y_us)


@pytest.mark.parametrize("inject", [["C1.stop@1s+1s"], ["R1.stop@1s+1s"], []])
def test_interruptions_that_still_fit_raise_nothing(inject):
    _, snaps = run(inject)
    assert all(m.faults == 0 for m in snaps[-1].snapshot.monitors)


def test_fault_reset_keeps_a_hopeless_task_faulty_then_releases_it():
    session = make_session(CELL, inject=["C1.stop@1s+2s"])
    session.run_for(4 * S)  # fault at 3 s; the late pallet is still on its way (arrives 5.5 s)
    result = session.command(FaultReset())
    assert "conveyor_fault stays" in result.message and "still executing" in result.message
    assert monitor(session.scan_once(), "conveyor").location == "faulty"
    session.run_for(2 * S)  # the pallet arrived at 5.5 s, the next one started at 5.51 s
    result = session.command(FaultReset())
    assert "conveyor_fault released" in result.message
    m = monitor(session.scan_once(), "conveyor")
    assert m.location == "executing" and m.detection is None and m.attempt == 2
    session.run_for(4 * S)
    m = monitor(session.last, "conveyor")
    assert m.completed == 1 and m.faults == 1 and m.detection is None


def test_a_reset_with_nothing_latched_says_so():
    session = make_session(CELL)
    session.run_for(1 * S)
    assert session.command(FaultReset()).message == "fault reset: nothing was latched"


def test_monitor_faults_do_not_force_outputs_safe():
    _, snaps = run(["C1.stop@1s+2s"])
    assert not any(s.snapshot.latched for s in snaps)
    assert monitor(snaps[-1], "robot").completed == 3  # the cell kept working


def test_traces_carry_the_monitors_and_are_deterministic(tmp_path):
    for name in ("a.csv", "b.csv"):
        session = make_session(CELL, inject=["C1.stop@1s+2s"])
        with TraceWriter(tmp_path / name) as writer:
            session.run_for(8 * S, lambda cell: writer.write(cell.snapshot))
    a = (tmp_path / "a.csv").read_text()
    assert a == (tmp_path / "b.csv").read_text()
    header, *rows = a.splitlines()
    columns = header.split(",")
    loc = columns.index("monitor.conveyor")
    assert rows[300].split(",")[loc] == "faulty" and rows[299].split(",")[loc] == "interrupted"


def test_a_project_without_monitors_has_no_stage(valve_project):
    session = make_session(PROJECTS / "cispi_valve")
    assert session.engine.monitors is None and session.scan_once().snapshot.monitors == ()


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------


def test_run_scenario_paper_prints_the_monitor_beside_the_watchdog(capsys):
    assert main(["run", str(CELL), "--scenario", "paper"]) == 0
    out = capsys.readouterr().out
    assert "Scenario paper:" in out and "Faults injected: C1.stop@1s+2s" in out
    assert "conveyor_fault at 3.000 s: x = 3.000 s, y = 1.000 s" in out
    assert "plain watchdog (x reaches gamma 5s): 5.000 s, x = 5.000 s" in out
    assert "the monitor was 2.000 s earlier" in out
    assert "1201 scans" in out  # the scenario's 12 s


def test_run_without_length_or_with_unknown_scenario_exits_2(capsys):
    assert main(["run", str(CELL)]) == 2
    assert "--for TIME is required" in capsys.readouterr().err
    assert main(["run", str(CELL), "--scenario", "nope"]) == 2
    assert "--scenario 'nope': the project declares paper" in capsys.readouterr().err


def test_check_lists_monitors_and_scenarios(capsys):
    assert main(["check", str(CELL)]) == 0
    out = capsys.readouterr().out
    assert "Monitors (2:" in out
    assert "conveyor  normal [3s, 4s], acceptable [3s, 5s]  label conveyor_fault" in out
    assert "robot  normal [2s, 3s], acceptable [2s, 4s]  label robot_fault" in out
    assert "interrupt rise(Hc), resume fall(Hc)" in out and "interrupted while Hr" in out
    assert "paper  [C1.stop@1s+2s, 12s]" in out


# --------------------------------------------------------------------------------------------
# The earliness sweep
# --------------------------------------------------------------------------------------------

STARTS = (500 * MS, 1 * S, 2 * S, 3 * S)
LENGTHS = (1 * S, 1_490 * MS, 1_500 * MS, 2 * S, 3 * S)


@pytest.fixture(scope="module")
def sweep():
    return run_sweep(load_project(CELL), "conveyor", None, STARTS, LENGTHS)


def test_sweep_truth_comes_from_the_plant_and_matches_the_physics(sweep):
    assert sweep.fault == "C1.stop" and sweep.task_start_us == 0
    for row in sweep.rows:
        # The belt stops while the pallet travels (w < 3.5 s): it arrives L late.
        assert row.end_x_us == 3_500 * MS + row.length_us and row.work_us == 3_500 * MS
        assert row.in_time == (3_500 * MS + row.length_us < 5 * S)


def test_sweep_no_false_alarm_no_miss_never_later_than_the_watchdog(sweep):
    assert sweep.ok
    fine = [r for r in sweep.rows if r.in_time]
    late = [r for r in sweep.rows if not r.in_time]
    assert len(fine) == 8 and len(late) == 12
    assert all(r.monitor is None and r.watchdog is None for r in fine)
    assert all(r.monitor is not None and r.watchdog is not None for r in late)
    assert all(r.monitor.time_us <= r.watchdog.time_us for r in late)


def test_sweep_detection_instants(sweep):
    rows = {(r.start_us, r.length_us): r for r in sweep.rows}
    paper = rows[(1 * S, 2 * S)]
    assert (paper.monitor.x_us, paper.monitor.y_us, paper.watchdog.x_us) == (3 * S, 1 * S, 5 * S)
    for w in (500 * MS, 1 * S, 2 * S):  # the earliest rule: x = gamma - alpha + w
        for length in (2 * S, 3 * S):
            d = rows[(w, length)].monitor
            assert (d.rule, d.x_us, d.y_us) == ("cannot_finish", 2 * S + w, w)
            assert rows[(w, length)].earlier_us == 3 * S - w
    # Work already >= alpha: nothing to anticipate, the monitor fires with the watchdog.
    assert rows[(3 * S, 2 * S)].monitor.rule == "deadline"
    assert rows[(3 * S, 2 * S)].earlier_us == 0
    # Ends exactly at gamma: late (Property 1), seen at the end, same scan as the watchdog.
    assert rows[(1 * S, 1_500 * MS)].monitor.rule == "late_end"


def test_sweep_command_prints_the_table_and_exits_0(capsys):
    assert main(["sweep", str(CELL), "--starts", "1s", "--lengths", "1s,2s"]) == 0
    out = capsys.readouterr().out
    assert "interruption C1.stop" in out
    assert "2 runs: 1 in time, 1 late or out of window." in out
    assert "monitor false alarms 0" in out and "monitor later than the watchdog 0" in out
    assert "OK: no false alarm, no miss, never later than the watchdog" in out


def test_sweep_bad_arguments_exit_2(capsys):
    assert main(["sweep", str(CELL), "--task", "nope"]) == 2
    assert "--task 'nope'" in capsys.readouterr().err
    assert main(["sweep", str(CELL), "--fault", "C1.jam"]) == 2
    assert "unknown fault" in capsys.readouterr().err
    assert main(["sweep", str(CELL), "--control", "nope"]) == 2
    assert "--control 'nope'" in capsys.readouterr().err
    assert main(["sweep", str(PROJECTS / "cispi_valve")]) == 2
    assert "declares no monitors" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------
# Explanations and alarms
# --------------------------------------------------------------------------------------------


def test_a_monitor_fault_is_explained_and_raises_a_latched_alarm():
    session = make_session(CELL, inject=["C1.stop@1s+2s"])
    snaps = []
    session.run_for(4 * S, snaps.append)
    assert not any(e.key == "monitor:conveyor" for e in at(snaps, 2_990 * MS).explanations)
    snap = at(snaps, 3 * S)
    e = next(e for e in snap.explanations if e.key == "monitor:conveyor")
    assert e.kind == "monitor" and e.latched and e.alarm and e.device == "Conveyor C1"
    assert (e.since_scan, e.since_us) == (301, 3 * S)
    assert "cannot end within its acceptable time" in e.what
    assert "conveyor_fault" in e.detail and "conveyor_fault" not in e.what
    assert "x = 3.000 s" in e.detail and "y = 1.000 s" in e.detail and "[3s, 5s]" in e.detail
    assert "had done 1s of the 3s of work it needs and been stopped for 2s" in e.why
    assert "still in progress" in e.consequences
    assert [p.id for p in e.policies] == ["continue", "stop_device", "reset"]
    raised = [a for a in snap.alarm_events if a.key == "monitor:conveyor"]
    assert [a.event for a in raised] == ["raised"]
    session.run_for(2 * S)  # the late task ended; the next one runs normally
    session.command(FaultReset())
    snap = session.scan_once()
    assert not any(e.key == "monitor:conveyor" for e in snap.explanations)
    assert not any(a.key == "monitor:conveyor" and a.active for a in snap.alarms)


def test_project_texts_replace_a_monitor_explanation(tmp_path):
    import shutil
    folder = tmp_path / "cell"
    shutil.copytree(CELL, folder)
    with (folder / "monitors.yaml").open("a") as f:
        f.write('explanations:\n  monitors:\n    conveyor:\n'
                '      what: "{task} late: x={x}, y={y}, gamma={gamma} ({label})"\n'
                '      severity: high\n')
    session = make_session(folder, inject=["C1.stop@1s+2s"])
    session.run_for(3 * S)
    e = next(e for e in session.last.explanations if e.key == "monitor:conveyor")
    assert e.what == ("Conveyor C1 carrying a pallet from the pusher to B late: x=3.000, "
                      "y=1.000, gamma=5s (conveyor_fault)")
    assert e.severity == "high"


def test_explanations_for_an_unknown_monitor_are_a_load_error(tmp_path, capsys):
    import shutil
    folder = tmp_path / "cell"
    shutil.copytree(CELL, folder)
    with (folder / "monitors.yaml").open("a") as f:
        f.write("explanations:\n  monitors:\n    belt: {what: x}\n")
    assert main(["check", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "monitors.yaml:" in err and "explanations for unknown monitor 'belt'" in err

"""In manual mode the control program waits, and resumes where it waited (GEMMA's F4,
S7-GRAPH's MAN mode; docs/grafcet.md, "Manual mode").

While in manual mode no transition fires, the step times X.t stop where they were, the
stored memories and the equations' memories hold (the equations are not evaluated); the
project's timers and observers, the diagnosers, the filter and the monitors run as ever.
Leaving manual mode, the program resumes from the steps where it waited, their times going
on from where they stopped. Compiled and interpreted scans agree on all of it, and
Engine.capture / restore carry the waiting program.

Before this, the law ran blind in manual mode (its orders not applied): on conveyor_robot,
manual mode entered once the robot was back home let the GRAFCET fire the join, the push
and the transport by itself, and the cell waited for ever in X3 + X10 after it
(test_conveyor_cycles_after_manual_mode).
"""

from __future__ import annotations

import pytest

from hmi.engine import commands as cmd
from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.loader import load_project
from hmi.session.session import Session
from hmi.studies.loopstate import LoopAccess
from tests.conftest import write_project
from tests.examples import example
from tests.test_compiled_scan import comparable
from tests.twins import Twins

MS = 1000
S = 1_000_000

# A push of 300 ms (C while X1.t < 300ms), a stored memory (M, set on X1), an equation's
# memory (N, set by b in X1, reset in X0), a timer on a and an observer of b.
WAITS_PROJECT = {
    "project.yaml": """
        name: waits
        scan_period: 10ms
        inputs: {a: A, b: B, fsc: sensor, fso: sensor}
        outputs: {C: order, O: order, P: order}
        memories: {M: {description: memory}, N: {description: memory}}
        timers: {T: {type: TON, input: a, preset: 50ms, description: a held}}
        observers: {saw_b: {set: b, reset: "False", description: b seen}}
        control:
          equations:
            N: {set: X1 and b, reset: X0}
            P: N
          grafcet:
            steps:
              0: {initial: true}
              1: {actions: [{do: C, if: X1.t < 300ms}, {set: M}]}
              2: {actions: [O]}
            transitions:
              - {from: 0, to: 1, when: a}
              - {from: 1, to: 2, when: X1.t >= 300ms}
              - {from: 2, to: 0, when: "not a"}
        plant: {kind: sim, model: valve, ports: {C: C, O: O}}
    """,
}


@pytest.fixture
def waits(tmp_path):
    return load_project(write_project(tmp_path / "waits", WAITS_PROJECT))


def test_in_manual_mode_the_program_waits_and_resumes_where_it_waited(waits):
    t = Twins(waits)
    t.scan()
    t.set_input("a", True)
    s = t.scan()
    assert s.active_steps == ("X1",) and s.fired == (1,) and s.value("M") is True
    s = t.run(0.15)[-1]  # X1.t = 150 ms: half the push done
    assert s.value("X1.t") == 150 * MS and s.fov[0] is True
    assert t.apply(cmd.SetMode(True)).message == (
        "manual mode: the control program waits at X1; outputs follow operator requests, "
        "still through the safety filter")
    t.set_input("b", True)  # in automatic mode: N set (X1 and b)
    first = t.scan()
    s = t.run(2)[-1]  # far past the end of the push
    for snap in (first, s):
        assert snap.mode == "manual" and snap.active_steps == ("X1",) and snap.fired == ()
        assert snap.value("X1.t") == 150 * MS  # frozen
        assert snap.value("M") is True and snap.value("N") is False  # held, not evaluated
    assert s.fov == (False, False, False)  # the requests (none): the law asks nothing
    # the rest of stage 2 runs: the timer on a, the observer of b
    assert s.value("T") is True and s.value("saw_b") is True
    assert t.apply(cmd.SetMode(False)).message == (
        "automatic mode: the control program resumes from X1 and drives the outputs")
    t.set_input("b", False)
    s = t.scan()  # resumes: 150 ms + one period, and the push goes on
    assert s.mode == "auto" and s.active_steps == ("X1",)
    assert s.value("X1.t") == 160 * MS and s.fov[0] is True
    pushed = [t.scan() for _ in range(20)]
    assert pushed[12].value("X1.t") == 290 * MS and pushed[12].fov[0] is True
    assert pushed[13].active_steps == ("X2",) and pushed[13].fired == (2,)
    # the push lasted 300 ms of automatic mode in all, 30 scans: as if never interrupted
    assert sum(p.fov[0] for p in t.snaps if p.mode == "auto") == 30


def test_two_waits_in_a_row_each_stop_the_step_time(waits):
    """The step time stops at each wait and goes on after it."""
    t = Twins(waits)
    t.scan()
    t.set_input("a", True)
    t.run(0.1)
    times = []
    for _ in range(2):
        t.apply(cmd.SetMode(True))
        t.run(1.0)
        times.append(t.snaps[-1].value("X1.t"))
        t.apply(cmd.SetMode(False))
        t.run(0.05)
    assert times == [90 * MS, 140 * MS]
    assert t.snaps[-1].value("X1.t") == 190 * MS


def test_manual_mode_entered_while_paused_before_the_first_scan(waits):
    """Manual mode before the first scan: the program waits at its initial steps from the
    first scan (its reset) on."""
    t = Twins(waits)
    t.apply(cmd.SetMode(True))
    t.set_input("a", True)
    s = t.run(0.5)[-1]
    assert all(p.active_steps == ("X0",) and p.value("X0.t") == 0 for p in t.snaps)
    t.apply(cmd.SetMode(False))
    s = t.scan()  # a, judged at the start of the scan: 0 -> 1 at once
    assert s.active_steps == ("X1",) and s.fired == (1,)


def test_the_diagnosers_run_in_manual_mode():
    """cispi_valve: O forced on in manual mode opens the valve; the diagnoser follows the
    valve through its states while the program waits in X0."""
    t = Twins(example("cispi_valve"))
    s = t.run(0.3)[-1]
    assert s.active_steps == ("X0",)
    before, waited = s.diagnosers[0].state, s.value("X0.t")
    t.apply(cmd.SetMode(True))
    t.apply(cmd.ManualOutput("O", True))
    seen = set()
    for _ in range(300):
        s = t.scan()
        seen.add(s.diagnosers[0].state)
        assert s.active_steps == ("X0",) and s.value("X0.t") == waited
    assert s.value("fso") is True
    assert seen - {before}, "the diagnoser never moved in manual mode"


def test_capture_and_restore_carry_the_waiting_program(waits):
    """Engine.capture in manual mode, then restore after leaving it: the program waits again
    and, left again, resumes exactly as the first time."""
    engine = Engine(waits, SimPlant(waits))
    access = LoopAccess(engine, engine.plant)
    period = waits.scan_period_us
    engine.step(0)
    engine.plant.set_input("a", True)
    k = 1
    for _ in range(10):
        engine.step(k * period)
        k += 1
    engine.apply(cmd.SetMode(True))
    for _ in range(50):
        engine.step(k * period)
        k += 1
    state, at = access.capture(), k

    def leave_and_run():
        engine.apply(cmd.SetMode(True)) if engine.mode != "manual" else None
        for i in range(20):
            engine.step((at + i) * period)
        engine.apply(cmd.SetMode(False))
        return [comparable(engine.step((at + 20 + i) * period)) for i in range(40)]

    first = leave_and_run()
    access.restore(state)
    assert engine.mode == "manual"
    assert leave_and_run() == first
    assert first[0].value("X1.t") == 100 * MS


@pytest.mark.parametrize("manual_at", (1.0, 2.8))
def test_compiled_and_interpreted_scans_agree_through_manual_mode(manual_at):
    """conveyor_robot, the soak's sequence (manual mode mid-transfer and once the robot is
    home): every snapshot of both engines the same."""
    t = Twins(example("conveyor_robot"))
    entered = t.run(manual_at)[-1]
    t.apply(cmd.SetMode(True))
    t.run(5)
    assert {p.active_steps for p in t.snaps if p.mode == "manual"} == {entered.active_steps}
    t.apply(cmd.SetMode(False))
    t.run(20)
    t.apply(cmd.FaultReset())
    t.run(10)


def transfers(snap) -> int:
    return dict(snap.snapshot.plant_counters)["R1.transfers"]


def test_conveyor_cycles_after_manual_mode():
    """The random operator's dead end: start, manual mode for 5 s, automatic for 60 s, a
    fault reset, 60 s, with manual mode entered in X2 + X12 (the robot back home, a pallet on
    its way to B). Before, the law ran on in manual mode: it fired the join, the push and the
    transport with none of their orders written, and back in automatic mode the robot took
    the only pallet and the program waited in X3 + X10 for a pallet at B for ever, with
    nothing on screen saying so. Now the program waits in X2 + X12 and the cell cycles:
    pallets transferred keep increasing, the steps change.

    (The soak's step list enters manual mode at 1 s, in X2 + X11: there manual mode drops G
    and aborts the robot's transfer, and X11 resumed orders G again, which hands over the
    next pallet as well; that dead end is the plant moved by hand, not the program running
    blind: docs/grafcet.md, "Manual mode".)"""
    project = example("conveyor_robot")
    session = Session(Engine(project, SimPlant(project)))
    session.run_for(2.8 * S)
    assert session.last.snapshot.active_steps == ("X2", "X12")
    assert session.command(cmd.SetMode(True)).accepted
    session.run_for(5 * S)
    assert session.last.snapshot.active_steps == ("X2", "X12")  # waited (B and e both came)
    assert session.command(cmd.SetMode(False)).accepted
    session.run_for(60 * S)
    assert session.command(cmd.FaultReset()).accepted
    session.run_for(1 * S)
    after_reset = transfers(session.last)
    steps = set()

    def seen(snap):
        steps.add(snap.snapshot.active_steps)
    session.run_for(59 * S, on_scan=seen)
    assert transfers(session.last) >= after_reset + 10
    assert {("X3", "X10"), ("X1", "X11"), ("X2", "X12")} <= steps


def test_the_conveyor_dead_end_is_said_and_the_way_back_works():
    """The soak's step list (tests of /tmp/soak3/conv_deadlock.steps: manual mode at 1 s,
    mid-transfer, for 5 s): back in automatic mode X11 orders G again, which hands over the
    pallet X3 counts on, and the program waits in X3 + X10 for a pallet at B that will never
    come. The step's supervision (10 s) says so: an alarm, with what it waits for (B 0).
    The way back the alarm recommends: manual mode, d on until a pallet waits at B (3.5 s of
    transport), released, automatic mode: the program resumes from X3 + X10, the join fires
    and the cell cycles again; the alarm clears."""
    project = example("conveyor_robot")
    session = Session(Engine(project, SimPlant(project)))
    session.run_for(1 * S)
    assert session.command(cmd.SetMode(True)).accepted
    session.run_for(5 * S)
    assert session.command(cmd.SetMode(False)).accepted
    session.run_for(9 * S, on_quiet=lambda n: None)
    last = session.last.snapshot
    assert last.active_steps == ("X3", "X10") and last.overdue_steps == ()
    session.run_for(4 * S, on_quiet=lambda n: None)  # X3 since 6.02 s, X10 since 9.02 s
    snap = session.last
    assert snap.snapshot.overdue_steps == ("X3", "X10")
    alarms = {a.key: a for a in snap.alarms}
    stuck = alarms["step:X3"]
    assert stuck.state == "active-unacknowledged" and stuck.raised_us == 16_030_000
    assert stuck.text == "Program stuck at “A pallet waits at B” — waiting more than 10s"
    assert "(B) 0" in stuck.explanation.why and "(e) 1" in stuck.explanation.why
    assert [w.text for w in snap.snapshot.waits] == ["X3 waits for B and e — B 0, e 1",
                                            "X10 waits for B and e — B 0, e 1"]
    before = transfers(snap)
    # the way back: the recommended policy (manual mode), d until B, release, leave manual
    result = session.command(cmd.ChoosePolicy("step:X3", "manual"))
    # the steps by their descriptions (the journal keeps this answer), their names after
    assert result.accepted and ("waits at “A pallet waits at B” (X3), “Robot free at home” "
                                "(X10);") in result.message
    assert session.command(cmd.ManualOutput("d", True)).accepted
    pushed_at = session.last.snapshot.time_us
    session.run_for(0.5 * S)
    assert session.last.snapshot.overdue_steps == ()  # the program waits on purpose
    assert session.last.snapshot.waits[0].values == (("B", False), ("e", True))
    while not session.last.snapshot.value("B"):
        session.scan_once()
    assert 3.5 * S <= session.last.snapshot.time_us - pushed_at <= 3.6 * S  # the belt's transport
    assert [w.holds for w in session.last.snapshot.waits] == [True, True]
    assert session.command(cmd.ManualOutput("d", None)).accepted
    result = session.command(cmd.SetMode(False))
    assert result.message.startswith("automatic mode: the control program resumes from "
                                     "“A pallet waits at B” (X3), “Robot free at home” (X10)")
    steps = set()

    def seen(s):
        steps.add(s.snapshot.active_steps)
    session.run_for(30 * S, on_scan=seen)
    assert {("X1", "X11"), ("X2", "X12"), ("X3", "X10")} <= steps
    assert transfers(session.last) >= before + 7
    assert session.last.snapshot.overdue_steps == ()
    assert not [a for a in session.last.alarms
                if a.key.startswith("step:") and a.state.startswith("active")]

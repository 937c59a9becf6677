"""What each active GRAFCET step waits for (S7-GRAPH's criteria analysis, Snapshot.waits),
and the steps' supervision times (an alarm when a step waits too long: hmi.explain.sequence).

The supervision alarm comes at exactly the scan the step's time is exceeded — on the compiled
scan and the stage objects alike, and on a headless run's quiet path, where a scan with no
other news builds no snapshot (the engine keeps the next deadline and treats it as news);
it clears when the step is left, is not raised while the program waits in manual mode (its
step times hold there) and is carried by Engine.capture / restore.
"""

from __future__ import annotations

import pytest

from hmi.engine import commands as cmd
from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.loader import load_project
from hmi.session.session import Session
from tests.conftest import write_project
from tests.test_compiled_scan import comparable_cell
from tests.twins import Twins

MS = 1000
S = 1_000_000

# X0 leaves by two transitions (a; b and not c), X1 by its own step time, X2 and X5 join.
SEQ_PROJECT = {
    "project.yaml": """
        name: seq
        scan_period: 10ms
        inputs:
          a: {description: Start button}
          b: {description: Part present}
          c: {description: Clamp closed}
        outputs: {P: {description: Push order}}
        control:
          grafcet:
            steps:
              0: {initial: true, description: Waiting for a part, supervision: 500ms}
              1: {description: Pushing, actions: [P], supervision: 1s}
              2: {description: Ready}
              5: {initial: true, description: Clamp station}
            transitions:
              - {from: 0, to: 1, when: a, description: Start pressed}
              - {from: 0, to: 2, when: b and not c}
              - {from: 1, to: 2, when: X1.t >= 300ms}
              - {from: [2, 5], to: [0, 5], when: c, description: Clamped}
        plant: {kind: sim, model: valve, ports: {O: P}}
    """,
}


@pytest.fixture
def seq(tmp_path):
    return load_project(write_project(tmp_path / "seq", SEQ_PROJECT))


# -- criteria ------------------------------------------------------------------------------------

def waits_of(snap):
    return [w.text for w in snap.waits]


def test_a_step_with_two_transitions_waits_for_either_and_a_join_names_its_missing_step(seq):
    t = Twins(seq)
    snap = t.scan()
    assert snap.active_steps == ("X0", "X5")
    assert waits_of(snap) == ["X0 waits for a — a 0",
                              "X0 waits for b and not c — b 0, c 0",
                              "X5 waits for c, and X2 active — c 0"]
    first, second, join = snap.waits
    assert (first.transition, first.description, first.targets) == (1, "Start pressed", ("X1",))
    assert first.holds is False and first.missing == (("a", True),)
    assert second.missing == (("b", True),)
    assert join.joins == ("X2",) and join.description == "Clamped"


def test_a_step_time_receptivity_shows_the_step_time(seq):
    t = Twins(seq)
    t.scan()
    t.set_input("a", True)
    t.scan()  # X0 -> X1
    snap = t.run(0.12)[-1]
    assert snap.active_steps == ("X1", "X5")
    wait = snap.waits[0]
    assert wait.text == "X1 waits for X1.t ≥ 300ms — 0.12 s"
    assert wait.values == (("X1.t", 120 * MS),) and wait.holds is False
    assert wait.missing == ()  # not a product of literals: nothing to do by hand


def test_a_join_whose_steps_are_all_active_and_a_receptivity_that_holds(seq):
    t = Twins(seq)
    t.scan()
    t.set_input("b", True)
    snap = t.scan()  # X0 -> X2 (b and not c)
    assert snap.active_steps == ("X2", "X5")
    assert waits_of(snap) == ["X2 waits for c — c 0", "X5 waits for c — c 0"]
    assert all(w.joins == () for w in snap.waits)
    t.apply(cmd.SetMode(True))  # the program waits: the condition comes, nothing fires
    t.set_input("c", True)
    snap = t.run(0.1)[-1]
    assert snap.active_steps == ("X2", "X5")
    assert [w.holds for w in snap.waits] == [True, True]
    assert snap.waits[0].text == "X2 waits for c — c 1"


def test_no_grafcet_waits_for_nothing():
    from tests.examples import example
    project = example("cispi_subsystem")
    engine = Engine(project, SimPlant(project))
    snap = engine.step(0)
    if engine.layout.grafcet is None:
        assert snap.waits == ()


# -- supervision ---------------------------------------------------------------------------------

def test_the_alarm_comes_at_the_scan_the_supervision_time_is_exceeded(seq):
    t = Twins(seq)
    snaps = t.run(0.6)
    overdue = [s for s in snaps if s.overdue_steps]
    # X0 active from 0 ms: X0.t = 500 ms at 500 ms is not more than 500 ms; 510 ms is
    assert overdue[0].time_us == 510 * MS and overdue[0].overdue_steps == ("X0",)
    assert overdue[0].value("X0.t") == 510 * MS
    assert all(not s.overdue_steps for s in snaps if s.time_us <= 500 * MS)
    # left: cleared at the scan the step is left
    t.set_input("a", True)
    snap = t.scan()
    assert snap.active_steps == ("X1", "X5") and snap.overdue_steps == ()
    # X1 (1 s) in its turn: it leaves at 300 ms, never overdue
    assert all(not s.overdue_steps for s in t.run(2))


def session_run(project, seconds, quiet: bool):
    """The scans with news (all of them when not `quiet`), the session's quiet path or not."""
    session = Session(Engine(project, SimPlant(project)))
    built = []
    session.run_for(seconds * S, on_scan=built.append,
                    on_quiet=(lambda n: None) if quiet else None)
    return session, built


def test_on_the_quiet_path_the_deadline_is_news(seq):
    """A headless run builds no snapshot for a quiet scan: the scan past the deadline must
    be built, explained and alarmed all the same, as when every snapshot is built."""
    _, every = session_run(seq, 2, quiet=False)
    session, news = session_run(seq, 2, quiet=True)
    assert len(news) < len(every) // 10  # (most scans were quiet)
    raised = [s for s in every if s.snapshot.overdue_steps]
    assert raised[0].snapshot.time_us == 510 * MS
    first = next(s for s in news if s.snapshot.overdue_steps)
    assert first.snapshot.time_us == 510 * MS
    assert [a.key for a in first.alarms] == ["step:X0"]
    assert comparable_cell(first) == comparable_cell(raised[0])
    assert session.last.snapshot.overdue_steps == ("X0",)
    # left on the quiet path: the scan that leaves it is news, the alarm clears there
    session.engine.plant.set_input("a", True)
    built = []
    session.run_for(1 * S, on_scan=built.append, on_quiet=lambda n: None)
    left = built[0]
    assert left.snapshot.active_steps == ("X1", "X5") and left.snapshot.overdue_steps == ()
    assert [(a.key, a.state) for a in left.alarms] == [("step:X0", "cleared-unacknowledged")]


def test_the_explanation_says_what_the_step_waits_for(seq):
    session, _ = session_run(seq, 1, quiet=True)
    (alarm,) = session.last.alarms
    e = alarm.explanation
    assert (alarm.key, alarm.kind, alarm.severity, alarm.latched) == (
        "step:X0", "sequence", "medium", False)
    assert e.what == "Program stuck at “Waiting for a part” — waiting more than 500ms"
    assert "since 0.000 s" in e.why
    assert "“Start pressed” (start button (a) 0)" in e.why
    # a condition without a description is said with what it reads, not as an expression
    assert "or for “part present” (b now 0) and not “clamp closed” (c now 0)" in e.why
    assert "b and not c" not in e.why
    assert "“Pushing”" in e.consequences
    assert [p.id for p in e.policies] == ["manual", "continue"]
    assert e.recommended.id == "manual" and e.recommended.command == cmd.SetMode(True)
    assert "until a (start button) is on" in e.recommended.effect
    assert "Step X0" in e.detail and "`a`" in e.detail


def test_not_while_the_program_waits_in_manual_mode(seq):
    t = Twins(seq)
    t.run(0.21)  # X0.t = 200 ms
    t.apply(cmd.SetMode(True))
    assert all(not s.overdue_steps for s in t.run(3))
    t.apply(cmd.SetMode(False))
    snaps = t.run(0.5)
    # X0.t goes on from 200 ms: more than 500 ms 310 ms after leaving manual mode
    first = next(s for s in snaps if s.overdue_steps)
    left = snaps[0].time_us - 10 * MS
    assert first.time_us - left == 310 * MS and first.value("X0.t") == 510 * MS
    # entering manual mode clears it (the program waits on purpose)
    t.apply(cmd.SetMode(True))
    assert t.scan().overdue_steps == ()


def test_capture_and_restore_carry_the_supervision(seq):
    engine = Engine(seq, SimPlant(seq))
    period = seq.scan_period_us
    for k in range(30):
        engine.step(k * period)
    state = engine.capture()

    def rest():
        return [engine.step(k * period).overdue_steps for k in range(30, 80)]

    first = rest()
    assert first.index(("X0",)) == 21  # 510 ms
    engine.restore(state)
    assert rest() == first
    # restored past the deadline: overdue at once
    engine.restore(state)
    engine.step(60 * period)
    assert engine.snapshot().overdue_steps == ("X0",)


def test_no_supervision_costs_no_deadline(tmp_path):
    files = {"project.yaml": SEQ_PROJECT["project.yaml"].replace(", supervision: 500ms", "")
             .replace(", supervision: 1s", "")}
    project = load_project(write_project(tmp_path / "plain", files))
    engine = Engine(project, SimPlant(project))
    assert engine._supervised is None
    assert all(engine.step(k * 10 * MS).overdue_steps == () for k in range(200))


def test_not_in_recovery_mode_and_restarted_after_it(seq, tmp_path):
    """Recovery mode runs the law blind: no supervision there; leaving it restarts the
    program from its initial steps, whose times (and supervision) start again."""
    files = {"project.yaml": SEQ_PROJECT["project.yaml"] + """
        recovery:
          R1:
            device: Pusher
            description: Pull the pusher back
            steps:
              - {description: Pulling back, do: [P], until: a}
            timeout: 1h
    """}
    project = load_project(write_project(tmp_path / "rec", files))
    engine = Engine(project, SimPlant(project))
    period = project.scan_period_us
    k = 0

    def run(seconds):
        nonlocal k
        snaps = []
        for _ in range(round(seconds * S) // period):
            snaps.append(engine.step(k * period))
            k += 1
        return snaps

    assert run(0.6)[-1].overdue_steps == ("X0",)
    assert engine.apply(cmd.StartRecovery("R1")).accepted
    assert all(s.mode == "recovery" and not s.overdue_steps for s in run(2))
    assert engine.apply(cmd.EndRecovery()).accepted
    snaps = run(0.6)
    first = next(s for s in snaps if s.overdue_steps)
    assert first.time_us - snaps[0].time_us == 510 * MS - period  # X0 again from its start

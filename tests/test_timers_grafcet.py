"""Timers (TON/TOF) and GRAFCET evolution, through small projects run by the engine (each
timer step by step: tests/test_program.py)."""

from __future__ import annotations

from tests.conftest import make_session, write_project

GRAFCET_PROJECT = {
    "project.yaml": """
        name: g
        scan_period: 10ms
        inputs: {a: A, b: B, fsc: sensor, fso: sensor}
        outputs: {C: order, O: order, P: order}
        memories: {M: {description: memory}}
        control:
          equations:
            P: M and X4
          grafcet:
            steps:
              0: {initial: true}
              1: {actions: [C]}
              2: {actions: [{do: O, if: X2.t < 30ms}]}
              3: {actions: [{set: M}]}
              4: {}
              5: {actions: [{reset: M}]}
            transitions:
              - {from: 0, to: [1, 2], when: a}
              - {from: 1, to: 3, when: "True"}
              - {from: 2, to: 4, when: "True"}
              - {from: [3, 4], to: 5, when: b}
              - {from: 5, to: 0, when: X5.t >= 20ms}
        plant: {kind: sim, model: valve, ports: {C: C, O: O}}
    """,
}


def run_scans(session, n, inputs=None):
    snaps = []
    for _ in range(n):
        for name, value in (inputs or {}).items():
            session.engine.plant.set_input(name, value)
        snaps.append(session.scan_once())
    return snaps


def test_grafcet_evolution_fork_join_one_clearing_per_scan(tmp_path):
    session = make_session(write_project(tmp_path / "g", GRAFCET_PROJECT))
    plant = session.engine.plant
    s = session.scan_once()
    assert s.snapshot.active_steps == ("X0",)
    plant.set_input("a", True)
    s = session.scan_once()  # fork: 0 -> 1 and 2 together
    assert s.snapshot.active_steps == ("X1", "X2") and s.snapshot.fired == (1,)
    assert s.snapshot.fov == (True, True, False)  # C from X1, O from X2 (X2.t < 30ms)
    s = session.scan_once()  # 1 -> 3 and 2 -> 4 fire together, once (no chain within a scan)
    assert s.snapshot.active_steps == ("X3", "X4") and s.snapshot.fired == (2, 3)
    assert s.snapshot.value("M") is True  # stored action on activation of X3
    assert s.snapshot.fov == (False, False, True)  # P = M and X4
    s = session.scan_once()
    assert s.snapshot.active_steps == ("X3", "X4")  # join waits for b
    plant.set_input("b", True)
    s = session.scan_once()
    assert s.snapshot.active_steps == ("X5",) and s.snapshot.value("M") is False
    plant.set_input("a", False)
    s = session.scan_once()  # X5.t = 10ms
    assert s.snapshot.active_steps == ("X5",)
    s = session.scan_once()  # X5.t = 20ms -> back to X0
    assert s.snapshot.active_steps == ("X0",)


def test_conditional_action_follows_step_time(tmp_path):
    files = {"project.yaml": """
        name: c
        scan_period: 10ms
        inputs: {fsc: s, fso: s}
        outputs: {C: order, O: order}
        control:
          grafcet:
            steps:
              0: {initial: true, actions: [{do: O, if: X0.t < 30ms}]}
            transitions: []
        plant: {kind: sim, model: valve}
    """}
    session = make_session(write_project(tmp_path / "c", files))
    got = [(s.snapshot.value("X0.t"), s.snapshot.fov[1]) for s in run_scans(session, 5)]
    assert got == [(0, True), (10_000, True), (20_000, True), (30_000, False), (40_000, False)]


def test_equations_set_reset_and_prev_through_engine(tmp_path):
    files = {"project.yaml": """
        name: eq
        scan_period: 10ms
        inputs: {a: A, b: B}
        outputs: {Y: out, Z: out}
        memories: {M: mem}
        control:
          equations:
            M: {set: rise(a), reset: b}
            Y: M
            Z: prev(a, 2) and not a
        plant: {kind: sim, model: valve, ports: {C: Y, O: Z}}
    """}
    session = make_session(write_project(tmp_path / "eq", files))
    p = session.engine.plant
    seq = [(0, 0), (1, 0), (1, 0), (0, 0), (0, 1), (1, 1)]
    got = []
    for a, b in seq:
        p.set_input("a", bool(a))
        p.set_input("b", bool(b))
        s = session.scan_once()
        got.append((s.snapshot.value("M"), s.snapshot.fov[1]))
    # M set on the rise of a (scan 2), kept, reset by b (scan 5), reset wins at scan 6.
    assert [m for m, _ in got] == [False, True, True, True, False, False]
    # Z = a two scans ago and not a now: scans 4 (a at 2) and 5 (a at 3), not 6 (a is 1).
    assert [z for _, z in got] == [False, False, False, True, True, False]

"""The control filter in the engine: detection, the three policies, manual mode, safety."""

from __future__ import annotations

import tempfile
import textwrap
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.cli import main
from hmi.engine.commands import FaultReset, ManualOutput, SetMode, SetPolicy
from hmi.project.loader import load_project
from hmi.studies.filter_analysis import analyse
from tests.conftest import PROJECTS, write_project
from tests.examples import make_session

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000


def run(session, seconds):
    snaps = []
    session.run_for(seconds * S, snaps.append)
    return snaps


def test_detection_names_the_constraint_and_its_literals():
    snaps = run(make_session(VALVE, control="faulty", policy="monitor"), 8)
    both = next(s for s in snaps if "CSc1" in s.snapshot.filter_report.violated_names)
    violation = next(v for v in both.snapshot.filter_report.violations if v.name == "CSc1")
    assert violation.kind == "combined" and violation.literals == (("C", True), ("O", True))
    assert violation.description == "Never order open and close together"
    rise = next(s for s in snaps if "CSs6" in s.snapshot.filter_report.violated_names)
    literals = dict(next(v for v in rise.snapshot.filter_report.violations
                         if v.name == "CSs6").literals)
    assert literals == {"O": True, "not prev(O)": False, "not fsc_filter": False}


def test_monitor_passes_everything_through_and_says_it_is_unsafe():
    snaps = run(make_session(VALVE, control="faulty", policy="monitor"), 8)
    unsafe = [s for s in snaps if s.snapshot.filter_report.unsafe_written]
    assert unsafe and all(s.snapshot.outputs == s.snapshot.fov for s in snaps)


def test_correct_keeps_the_faulty_program_safe_and_the_valve_cycling():
    snaps = run(make_session(VALVE, control="faulty", policy="correct"), 120)
    assert sum(1 for s in snaps if s.snapshot.filter_report.violations) > 100
    assert all(not s.snapshot.filter_report.residual for s in snaps)
    assert all(not (s.snapshot.outputs[0] and s.snapshot.outputs[1])
               for s in snaps)  # never C and O
    assert not [e for s in snaps for e in s.snapshot.plant_events if e.damage]
    assert dict(snaps[-1].snapshot.plant_counters)["cycles"] >= 10


def test_correct_reports_each_change_with_its_reason():
    snaps = run(make_session(VALVE, control="faulty", policy="correct"), 8)
    # Opening held on a fixed time: at fso, CSs2 forces O to 0.
    s = next(s for s in snaps if any(c.by == ("CSs2",) for c in s.snapshot.filter_report.changes))
    change = next(c for c in s.snapshot.filter_report.changes if c.output == "O")
    assert (change.requested, change.written, change.how) == (True, False, "F0")
    assert s.snapshot.filter_report.distance >= 1


def test_block_latches_every_output_safe_until_a_fault_reset():
    session = make_session(VALVE, control="faulty", policy="block")
    snaps = run(session, 10)
    first = next(i for i, s in enumerate(snaps) if s.snapshot.filter_report.violations)
    assert snaps[first].snapshot.latched[0].source == "filter"
    assert "safe blocking on CSs2" in snaps[first].snapshot.latched[0].detail
    assert all(s.snapshot.outputs == (False, False) for s in snaps[first:])
    assert "safe-state latch released" in session.command(FaultReset()).message
    s = session.scan_once().snapshot
    assert not s.latched or s.filter_report.violations  # re-latches only on a new violation


def test_manual_requests_go_through_the_filter():
    session = make_session(VALVE)
    session.scan_once()  # closed, waiting
    session.command(SetMode(True))
    session.command(ManualOutput("C", True))  # close a closed valve: CSs1 refuses it
    s = session.scan_once()
    assert s.snapshot.fov == (True, False) and s.snapshot.outputs == (False, False)
    # Closing a closed valve: CSs1 (closed) and CSs5 (closing may only start when open).
    assert [(c.output, c.by) for c in s.snapshot.filter_report.changes] == [("C", ("CSs1", "CSs5"))]
    session.command(ManualOutput("C", None))
    session.command(ManualOutput("O", True))  # opening from closed is allowed
    s = session.scan_once()
    assert s.snapshot.outputs == (False, True) and not s.snapshot.filter_report.changes


def test_policy_switch_at_run_time():
    session = make_session(VALVE, control="faulty", policy="monitor")
    assert session.command(SetPolicy("correct")).accepted
    assert session.engine.policy == "correct"
    assert not session.command(SetPolicy("stop")).accepted
    # the policy in effect again: the answer (and so the journal) does not read as a switch
    same = session.command(SetPolicy("correct"))
    assert same.accepted and same.message == "filter policy stays correct: already in effect"


# The monitor policy on a real plant: tests/test_plant_contract.py (a real ModbusPlant).


def _unsafe_scans(session, seconds: int) -> list[int]:
    """The scans of a run that wrote an unsafe vector (without keeping every snapshot)."""
    unsafe: list[int] = []

    def on_scan(cell):
        if cell.snapshot.filter_report.unsafe_written:
            unsafe.append(cell.snapshot.scan)

    session.run_for(seconds * S, on_scan)
    return unsafe


def test_the_filter_never_writes_an_unsafe_vector_in_example_runs():
    # 25 s: in these 14 runs the last new situation (the image's Booleans, FOV, violations,
    # latch, the diagnoser's state and labels) appears by 19 s (measured over 40 s runs).
    for control in ("normal", "faulty"):
        for fault in ("F1@5s", "F2@5s", "F3@5s", "F4@5s", "F7@5s", "F10@9s", "F13@5s"):
            session = make_session(VALVE, control=control, policy="correct", inject=[fault])
            unsafe = _unsafe_scans(session, 25)
            assert not unsafe, (control, fault)


def test_no_safe_vector_falls_back_to_the_safe_state(tmp_path):
    files = {"project.yaml": """
        name: f
        scan_period: 10ms
        inputs: {a: A, b: B}
        outputs: {P: p, Q: q}
        control:
          equations: {P: a, Q: a}
        constraints:
          K1: not P and a       # P must be 1 when a
          K2: not Q and a       # Q must be 1 when a
          K3: P and Q and b     # but never both when b
        plant: {kind: sim, model: valve, ports: {fsc: a, fso: b, C: P, O: Q}}
    """}
    folder = write_project(tmp_path / "f", files)
    session = make_session(folder)
    session.engine.plant.devices[0].inject("F2", 0)  # fsc (a) stuck at 1
    session.engine.plant.devices[0].inject("F4", 0)  # fso (b) stuck at 1
    s = session.scan_once().snapshot
    assert s.filter_report.fallback and s.filter_report.safe_state and s.outputs == (False, False)
    assert not s.filter_report.unsafe_written
    report = analyse(load_project(folder))
    assert report.no_solution_count == 1 and "a, b" in report.no_solution[0]


def test_check_prints_analysis_for_the_valve(capsys):
    assert main(["check", str(VALVE)]) == 0
    out = capsys.readouterr().out
    assert "conflicts between simple constraints: none" in out
    assert "situations with no safe output vector: none" in out
    assert "worst-case Hamming distance the corrector may need: 2" in out


def test_check_reports_conflicting_simple_constraints(tmp_path):
    files = {"project.yaml": """
        name: c
        scan_period: 10ms
        inputs: {a: A, b: B}
        outputs: {P: p}
        control: {equations: {P: a}}
        constraints:
          K1: P and a
          K2: not P and b
          K3: not P and not a and not b
        plant: {kind: sim, model: valve, ports: {fsc: a, fso: b, C: P}}
    """}
    report = analyse(load_project(write_project(tmp_path / "c", files)))
    assert report.conflicts == ["K1 forces P to 0 and K2 forces it to 1 when a and b"]


def test_run_faulty_correct_and_block_from_the_command_line(capsys):
    assert main(["run", str(VALVE), "--control", "faulty", "--policy", "correct",
                 "--for", "120s"]) == 0
    out = capsys.readouterr().out
    assert "unsafe outputs written 0" in out and "Damage events: none" in out
    assert "cycles 13" in out
    # Block latches at 2.96 s; 20 s is over two 8-s valve cycles after it (a latched scan is
    # always news: 120 s of them cost 0.8 CPU s).
    assert main(["run", str(VALVE), "--control", "faulty", "--policy", "block",
                 "--for", "20s"]) == 0
    out = capsys.readouterr().out
    assert "Outputs latched safe from scan 297 (2.960 s): safe blocking on CSs2" in out
    assert "cycles 0" in out


# -- property: the filter's correction is safe and minimal -----------------------------------

@st.composite
def constraint_sets(draw):
    outs = [f"o{k}" for k in range(draw(st.integers(1, 5)))]
    ins = ["i0", "i1", "i2"]
    cons = []
    for _ in range(draw(st.integers(1, 8))):
        size = draw(st.integers(1, len(outs)))
        chosen = draw(st.lists(st.sampled_from(outs), min_size=size, max_size=size,
                               unique=True))
        lits = [o if draw(st.booleans()) else f"not {o}" for o in chosen]
        for i in draw(st.lists(st.sampled_from(ins), max_size=2, unique=True)):
            lits.append(i if draw(st.booleans()) else f"not {i}")
        cons.append(" and ".join(lits))
    fov = draw(st.lists(st.booleans(), min_size=len(outs), max_size=len(outs)))
    inputs = draw(st.lists(st.booleans(), min_size=3, max_size=3))
    return outs, cons, fov, inputs


@settings(max_examples=120, deadline=None)
@given(constraint_sets())
def test_filter_output_is_safe_and_at_minimum_distance(case):
    outs, cons, fov, inputs = case
    text = textwrap.dedent(f"""
        name: p
        scan_period: 10ms
        inputs: {{i0: a, i1: b, i2: c}}
        outputs: {{{", ".join(f"{o}: x" for o in outs)}}}
        control:
          equations: {{{", ".join(f"{o}: i0" for o in outs)}}}
        constraints:
    """) + "".join(f"  K{k}: {c}\n" for k, c in enumerate(cons)) + \
        "plant: {kind: sim, model: valve, ports: {fsc: i0}}\n"
    with tempfile.TemporaryDirectory() as tmp:
        Path(tmp, "project.yaml").write_text(text)
        project = load_project(tmp)
    from hmi.engine.scan import Engine
    from hmi.plant.sim.plant import SimPlant
    for strategy in ("exact", "paper"):
        engine = Engine(project, SimPlant(project), solver=strategy)
        for name, value in zip(("i0", "i1", "i2"), inputs, strict=True):
            engine.plant.free_inputs[name] = value
        engine.step(0)
        image = engine.image
        for name, value in zip(("i0", "i1", "i2"), inputs, strict=True):
            assert image[engine.layout.slots[name]] == value
        outputs, report, _ = engine.safety_filter.apply(engine.image, engine.history, tuple(fov),
                                                 engine.policy, False)

        def safe(vec):
            env = dict(zip(outs, vec, strict=True))
            env.update(zip(("i0", "i1", "i2"), inputs, strict=True))
            for c in project.constraints:
                if all(env[lit.name] == lit.positive for lit in c.literals):
                    return False
            return True
        import itertools
        candidates = [v for v in itertools.product((False, True), repeat=len(outs)) if safe(v)]
        if candidates:
            best = min(sum(a != b for a, b in zip(v, fov, strict=True)) for v in candidates)
            assert safe(outputs) and report.distance == best and not report.fallback
        else:
            assert report.fallback and outputs == tuple(False for _ in outs)

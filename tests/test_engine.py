"""The scan engine on the CISPI valve: cycling, determinism, faults, commands, safety."""

from __future__ import annotations

import pytest

from hmi.engine.commands import FaultReset, ManualOutput, SetMode
from hmi.session.trace import TraceWriter
from tests.conftest import PROJECTS
from tests.examples import make_session

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000


def run(session, seconds, *traces):
    """The run's snapshots, each also written to every trace file given (its format by its
    suffix)."""
    writers = [TraceWriter(trace) for trace in traces]
    snaps = []

    def on_scan(s):
        snaps.append(s)
        for writer in writers:
            writer.write(s.snapshot)
    session.run_for(seconds * S, on_scan)
    for writer in writers:
        writer.close()
    return snaps


def test_valve_cycles_and_scans_follow_the_period():
    session = make_session(VALVE)
    snaps = run(session, 60)
    assert len(snaps) == 6001 and snaps[-1].snapshot.time_us == 60 * S
    assert [s.snapshot.time_us for s in snaps[:3]] == [0, 10_000, 20_000]
    counters = dict(snaps[-1].snapshot.plant_counters)
    assert counters["cycles"] == 7  # 8 s per cycle: open 2 s, hold 3 s, close 2 s, wait 1 s
    assert not any(e.damage for s in snaps for e in s.snapshot.plant_events)
    opening = [s for s in snaps if s.snapshot.active_steps == ("X1",)]
    assert opening and all(s.snapshot.outputs == (False, True) for s in opening)


def test_two_runs_give_byte_identical_traces(tmp_path):
    for name in ("a", "b"):  # two runs, each traced in both formats
        run(make_session(VALVE, inject=["F4@10s"]), 30, tmp_path / f"{name}.csv",
            tmp_path / f"{name}.jsonl")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()
    assert (tmp_path / "a.jsonl").read_bytes() == (tmp_path / "b.jsonl").read_bytes()
    assert len((tmp_path / "a.csv").read_text().splitlines()) == 3002


def test_f13_leaves_the_valve_between_positions():
    snaps = run(make_session(VALVE, inject=["F13@20s"]), 60)
    after = [s for s in snaps if s.snapshot.time_us >= 30 * S]
    assert all(dict(s.snapshot.plant_state)["jammed"] for s in after)
    assert all(not s.snapshot.value("fsc") and not s.snapshot.value("fso") for s in after)
    assert {dict(s.snapshot.plant_state)["position"] for s in after} == {50.0}


def test_faulty_control_without_filter_damages_the_valve():
    # The faulty program holds orders against the stops; the monitor policy lets it through.
    snaps = run(make_session(VALVE, control="faulty", policy="monitor"), 30)
    kinds = {e.kind for s in snaps for e in s.snapshot.plant_events if e.damage}
    assert "both_orders" in kinds


def test_manual_mode_replaces_the_functional_vector():
    session = make_session(VALVE)
    session.scan_once()
    assert session.command(ManualOutput("O", True)).accepted is False  # needs manual mode
    assert session.command(SetMode(True)).accepted
    assert session.command(ManualOutput("O", True)).accepted
    s = session.scan_once().snapshot
    assert s.mode == "manual" and s.fov == (False, True) and s.manual == (("O", True),)
    result = session.command(SetMode(False))
    assert "released O" in result.message
    s = session.scan_once().snapshot
    assert s.mode == "auto" and s.manual == ()


def test_an_internal_error_puts_outputs_safe_and_says_so():
    session = make_session(VALVE)
    run(session, 2)  # opening: O is on
    assert session.last.snapshot.outputs == (False, True)

    def broken(*args):
        raise RuntimeError("solver bug")
    working = session.engine.filter_stage.apply
    session.engine.filter_stage.apply = broken
    # the filter's first question, asked by the scan itself (the compiled scan's, handed to
    # the filter stage)
    inner = session.engine.safety_filter
    test = inner.violations
    inner.violations = broken
    s = session.scan_once()
    assert s.snapshot.outputs == (False, False) and s.snapshot.latched[0].source == "internal"
    assert "solver bug" in s.error
    assert session.engine.plant.devices[0].orders == {"C": False, "O": False}
    s = session.scan_once()
    assert s.snapshot.outputs == (False, False)  # stays safe until a fault reset
    session.engine.filter_stage.apply = working
    inner.violations = test
    assert "safe-state latch released" in session.command(FaultReset()).message
    assert session.scan_once().snapshot.latched == ()


def test_repair_is_refused_for_a_model_that_cannot_undo_its_faults(monkeypatch):
    from hmi.engine.commands import RepairFaults
    from hmi.plant.sim.conveyor import Conveyor
    from tests.conftest import PROJECTS, make_session
    # Every example model can be repaired now; a model that could not is refused.
    monkeypatch.setattr(Conveyor, "REPAIRABLE", False)
    session = make_session(PROJECTS / "conveyor_robot", inject=["C1.stop@0s"])
    session.scan_once()
    result = session.command(RepairFaults())
    assert not result.accepted and "repair is not modelled for C1" in result.message
    assert not session.command(RepairFaults("nowhere")).accepted


def test_an_internal_error_that_repeats_latches_once_and_a_new_one_adds_a_reason():
    """A stage broken for good raises at every scan: one latch reason (dated from its first
    scan) and one explanation, not one per scan; another error adds its own; after a fault
    reset, once the cause is gone, the cell runs again."""
    session = make_session(VALVE)
    session.run_for(2 * S)
    engine = session.engine
    real = engine.compiled.core
    failing = {"error": "first"}

    def broken(*args):
        raise RuntimeError(failing["error"])

    engine.compiled.core = broken
    last = session.run_for(1 * S)
    first = engine.latched[0].scan
    assert [(r.source, r.detail) for r in engine.latched] == [
        ("internal", f"internal error at scan {first}: RuntimeError: first")]
    assert [e.key for e in last.explanations].count("safe_state:internal") == 1
    assert last.snapshot.outputs == engine.safe_vector
    failing["error"] = "second"
    last = session.run_for(1 * S)
    assert [(r.source, r.detail) for r in engine.latched] == [
        ("internal", f"internal error at scan {first}: RuntimeError: first"),
        ("internal", f"internal error at scan {first + 101}: RuntimeError: second")]
    assert last.snapshot.outputs == engine.safe_vector
    engine.compiled.core = real
    session.command(FaultReset())
    assert not session.run_for(1 * S).snapshot.latched


def test_the_wall_time_is_measured_where_someone_watches_it_only():
    """A scan's wall time is for the people watching a live run (the HMI's status bar, OPC
    UA, the filter benches: Session.scan_once, Engine.step), never for what is decided: a
    headless run in virtual time (Session.run_for) does not measure it (four clock reads a
    scan) and gives the same snapshots but for those two fields, and the engine measures
    again afterwards, also after a run that raised."""
    live, headless = make_session(VALVE), make_session(VALVE)
    watched = [live.scan_once() for _ in range(300)]
    assert all(s.scan_wall_us > 0 and s.snapshot.filter_wall_us > 0 for s in watched[1:])
    run_ = run(headless, 3)
    assert all(s.scan_wall_us == s.snapshot.filter_wall_us == 0.0 for s in run_)
    assert [s._replace(snapshot=s.snapshot._replace(scan_wall_us=0.0, filter_wall_us=0.0),
                       explain_wall_us=0.0) for s in watched] == run_[:300]
    assert headless.engine.wall_times and headless.scan_once().scan_wall_us > 0

    def stop(snap):
        raise RuntimeError("a reader gave up")
    with pytest.raises(RuntimeError):
        headless.run_for(S, stop)
    assert headless.engine.wall_times

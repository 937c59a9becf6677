"""The CISPI valve diagnoser in the scan: diagnosis of each fault, flags, reconstruction,
masking, fault reset and re-synchronisation (000 §2.1-2.2, §3.1-3.2).

Times come from the valve model (hmi/plant/sim/valve.py: travel 2 s, switches break after 40 ms
of travel, glitches last 300 ms; the diagnoser's windows hold for travels of 1.6 s to 2.4 s)
and the normal cycle of the project (closed rest 1 s, opening 1.92 s, open 3 s, closing
1.92 s after the first cycle). Second cycle: opening order at 8.88 s, open at 10.80 s,
closing order at 13.80 s, closed at 15.72 s.
"""

from __future__ import annotations

import pytest

from hmi.engine.commands import FaultReset
from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.session.session import Session
from tests.conftest import PROJECTS

S = 1_000_000
MS = 1_000
SCAN = 10 * MS
VALVE = PROJECTS / "cispi_valve"
OPEN_ORDER_2 = 8_880 * MS  # second cycle
CLOSE_ORDER_2 = 13_800 * MS


@pytest.fixture(scope="module")
def project():
    return load_project(VALVE)


def make_session(project, inject=(), diagnosis="ftc", policy=None) -> Session:
    plant = SimPlant(project)
    for text in inject:
        plant.inject(parse_injection(text))
    return Session(Engine(project, plant, policy=policy, diagnosis=diagnosis))


def run(session: Session, seconds: float):
    """The engine's snapshots of `seconds` of scans (the diagnoser's state is the engine's)."""
    snaps = []
    session.run_for(int(seconds * S), lambda cell: snaps.append(cell.snapshot))
    return snaps


def first_faulty(snaps):
    return next((s for s in snaps if s.diagnosers[0].faulty), None)


def test_normal_cycle_visits_the_nine_normal_states_and_never_a_faulty_one(project):
    snaps = run(make_session(project), 40)
    states = [s.diagnosers[0].state for s in snaps]
    # N0 (synchronising) is left at the first scan: the valve starts closed with no order;
    # N8 waits for fsc held 500 ms before the valve is closed at rest (N1).
    assert snaps[0].diagnosers[0].via.startswith("N0 -> N8")
    assert snaps[50].diagnosers[0].via.startswith("N8 -> N1")
    assert set(states) == {f"N{k}" for k in range(1, 9)}
    assert not any(s.diagnosers[0].faulty for s in snaps)
    assert not any(s.value("def_fsc") or s.value("def_fso") or s.value("def_V") for s in snaps)
    assert all(s.value("fsc_filter") == s.value("fsc") for s in snaps)
    assert dict(snaps[-1].plant_counters)["cycles"] == 5


def test_outputs_are_read_one_scan_back_so_the_order_is_seen_the_scan_after_it_is_written(
        project):
    snaps = run(make_session(project), 1.1)
    written = next(s for s in snaps if s.outputs[1])  # O written at 1.000 s
    seen = next(s for s in snaps if s.diagnosers[0].state == "N2")
    assert seen.scan == written.scan + 1 and seen.diagnosers[0].via == "N1 -> N2 on O"


# (injection, state reached with the orders as the program gives them (observe), decision,
#  instant the symptom can first be seen, longest delay the model's windows allow)
DIAGNOSES = [
    ("F1@12s", "A1", ("F1", "F13"), CLOSE_ORDER_2, SCAN + 300 * MS + 2_450 * MS + SCAN),
    ("F2@8.2s", "S2", ("F2",), OPEN_ORDER_2, SCAN + 300 * MS + 2_300 * MS),
    ("F3@8.2s", "A3", ("F3", "F13"), OPEN_ORDER_2, SCAN + 300 * MS + 2_450 * MS + SCAN),
    ("F4@12s", "S4", ("F4",), CLOSE_ORDER_2, SCAN + 300 * MS + 2_300 * MS),
    ("F5@8.2s", "S5", ("F5",), OPEN_ORDER_2, SCAN + 300 * MS + 2_300 * MS + SCAN),
    ("F6@12s", "S6", ("F6",), CLOSE_ORDER_2, SCAN + 300 * MS + 2_300 * MS + SCAN),
    ("F7@14.5s", "S7", ("F7",), 14_500 * MS, 500 * MS),  # via R7 {F2, F7}
    ("F8@8.2s", "S8", ("F8",), 8_200 * MS, 500 * MS),
    ("F9@9.5s", "S9", ("F9",), 9_500 * MS, 500 * MS),  # via R9 {F4, F9}
    ("F10@12s", "S10", ("F10",), 12_000 * MS, 500 * MS),
    ("F11@8.2s", "S11", ("F11",), 8_200 * MS, SCAN + 2_450 * MS),
    ("F12@12s", "S12", ("F12",), 12_000 * MS, SCAN + 2_450 * MS),
    ("F13@10.4s", "A3", ("F3", "F13"), OPEN_ORDER_2, SCAN + 300 * MS + 2_450 * MS + SCAN),
    # A switch sticking at 1 mid-travel: made too early, then still made after a glitch.
    ("F2@14.5s", "S2", ("F2",), 14_500 * MS, 500 * MS),
    ("F4@10s", "S4", ("F4",), 10_000 * MS, 500 * MS),
]


@pytest.mark.parametrize("inject,state,labels,symptom_us,max_delay_us", DIAGNOSES,
                         ids=[d[0] for d in DIAGNOSES])
def test_each_fault_is_diagnosed_within_the_windows_of_the_model(
        project, inject, state, labels, symptom_us, max_delay_us):
    snaps = run(make_session(project, [inject], diagnosis="observe"), 20)
    final = snaps[-1].diagnosers[0]
    assert (final.state, final.labels) == (state, labels)
    reached = next(s for s in snaps if s.diagnosers[0].state == state)
    detected = first_faulty(snaps)
    assert symptom_us <= detected.time_us <= reached.time_us <= symptom_us + max_delay_us
    # A faulty decision is latched: once faulty, the diagnoser never shows a normal state.
    after = [s.diagnosers[0] for s in snaps if s.time_us >= detected.time_us]
    assert all(d.faulty for d in after)
    assert final.certain == (len(labels) == 1)


@pytest.mark.parametrize("inject,state", [("F2@8.2s", "B2"), ("F5@8.2s", "B2"),
                                          ("F4@12s", "B4"), ("F6@12s", "B4")])
def test_under_ftc_the_mask_withdraws_the_order_that_would_refine_b2_b4(project, inject, state):
    """{F2, F5} and {F4, F6} masks the valve at once (a stuck valve stalls the motor in 1 s);
    without the order the valve cannot show which it was, so the decision stays ambiguous."""
    snaps = run(make_session(project, [inject]), 25)
    final = snaps[-1].diagnosers[0]
    assert final.state == state and not final.certain and not final.final
    assert snaps[-1].masked == ("C", "O") and snaps[-1].outputs == (False, False)
    assert not [e for s in snaps for e in s.plant_events if e.damage]


def test_a_sensor_flag_reconstructs_the_sensor_and_the_cycle_goes_on(project):
    snaps = run(make_session(project, ["F9@9.5s"]), 30)
    at = next(s for s in snaps if s.time_us == 9_500 * MS)
    d = at.diagnosers[0]
    # A glitch or a stuck switch: both are fso's partition, so fso is reconstructed at once.
    assert (d.state, d.labels, dict(d.flags)) == ("R9", ("F4", "F9"),
                                                  {"def_fsc": False, "def_fso": True,
                                                   "def_V": False})
    glitch_over = next(s for s in snaps if s.diagnosers[0].state == "S9")
    assert glitch_over.time_us == 9_800 * MS  # fso broke again after its 300 ms glitch
    assert at.value("fso") and not at.value("fso_filter")  # the glitch is not believed ...
    assert at.reconstructed == ("fso",) and at.masked == ()
    assert at.active_steps == ("X1",) and at.outputs == (False, True)  # ... so O stays on
    later = [s for s in snaps if s.time_us > 9_500 * MS]
    assert all(s.value("fso_filter") == s.value("fso_hat") for s in later)
    assert all(s.value("fsc_filter") == s.value("fsc") for s in later)
    assert dict(snaps[-1].plant_counters)["cycles"] >= 3
    assert not [e for s in snaps for e in s.plant_events if e.damage]


def test_an_actuator_flag_masks_the_orders_before_the_filter_and_after_it(project):
    snaps = run(make_session(project, ["F2@8.2s"]), 12)
    onset = next(s for s in snaps if s.masked)
    assert onset.time_us == 9_190 * MS and onset.diagnosers[0].state == "B2"
    # The program still asks to open; the filter judged the masked candidate (O = 0): the
    # drop of O before fso is what CSs4 forbids, and the mask has the last word.
    assert onset.fov == (False, True) and onset.outputs == (False, False)
    report = onset.filter_report
    assert "CSs4" in report.violated_names
    masked = [c for c in report.changes if c.how == "masked"]
    assert [(c.output, c.requested, c.written, c.by) for c in masked] == [
        ("O", True, False, ("def_V",))]
    assert "accepted: CSs4" in report.note and not report.residual
    assert all(s.outputs == (False, False) for s in snaps if s.time_us >= onset.time_us)


def test_monitor_policy_never_applies_a_mask_but_says_it_would(project):
    snaps = run(make_session(project, ["F2@8.2s"], policy="monitor"), 10)
    onset = next(s for s in snaps if s.diagnosers[0].state == "B2")
    assert onset.masked == () and onset.outputs == onset.fov == (False, True)
    assert "def_V would mask C, O" in onset.filter_report.note


def test_observe_and_off_modes_leave_the_sensors_alone(project):
    observe = run(make_session(project, ["F9@9.5s"], diagnosis="observe"), 11)
    off = run(make_session(project, ["F9@9.5s"], diagnosis="off"), 11)
    assert observe[-1].diagnosers[0].state == "S9" and observe[-1].value("def_fso")
    assert all(s.value("fso_filter") == s.value("fso") for s in observe + off)
    assert not any(s.reconstructed or s.masked for s in observe + off)
    assert off[-1].diagnosers[0].state == "N0" and not off[-1].value("def_fso")


def test_fault_reset_resynchronises_to_the_normal_state_the_io_shows(project):
    session = make_session(project, ["F8@8.2s"])
    snaps = run(session, 9)
    assert snaps[-1].diagnosers[0].state == "S8"
    # Wait until the valve rests closed with no order, then reset.
    while True:
        s = session.scan_once().snapshot
        if s.time_us > 20 * S and s.active_steps == ("X0",) and s.outputs == (False, False) \
                and s.value("fsc") and s.time_us % S == 500 * MS:
            break
    message = session.command(FaultReset()).message
    assert "diagnoser V1: S8 {F8} reset, re-synchronised to N1 (Closed at rest) on " \
           "fsc=1, fso=0, C=0, O=0; flags cleared" in message
    after = session.scan_once().snapshot
    d = after.diagnosers[0]
    assert (d.state, d.labels) == ("N1", ()) and d.via.startswith("fault reset (resync rule 1")
    assert not any(v for _, v in d.flags) and after.reconstructed == ()
    # ... and it follows the next cycle again.
    more = run(session, 10)
    assert {"N2", "N3", "N4", "N5"} <= {s.diagnosers[0].state for s in more}
    assert not any(s.diagnosers[0].faulty for s in more)


def test_fault_reset_leaves_the_diagnoser_faulty_while_the_fault_is_visible(project):
    session = make_session(project, ["F1@12s"])
    snaps = run(session, 20)
    assert snaps[-1].diagnosers[0].state == "A1"
    message = session.command(FaultReset()).message
    assert ("diagnoser V1 stays in A1 {F1, F13}: fsc=0, fso=0, C=0, O=0 match no normal "
            "state: the fault is still visible") in message
    after = session.scan_once().snapshot
    assert after.diagnosers[0].state == "A1" and after.masked == ("C", "O")


def test_the_trace_has_the_diagnoser_state_and_the_flags(project, tmp_path):
    from hmi.session.trace import TraceWriter
    session = make_session(project, ["F9@9.5s"])
    path = tmp_path / "t.csv"
    with TraceWriter(path) as writer:
        session.run_for(10 * S, lambda cell: writer.write(cell.snapshot))
    header, *rows = path.read_text().splitlines()
    columns = header.split(",")
    for name in ("diag.V1", "def_fsc", "def_fso", "def_V", "fsc_filter", "fso_filter"):
        assert name in columns
    last = dict(zip(columns, rows[-1].split(","), strict=True))
    assert last["diag.V1"] == "S9" and last["def_fso"] == "1"


def test_run_summary_shows_the_diagnosis_the_flags_and_the_reconstruction(capsys):
    from hmi.cli import main
    assert main(["run", str(VALVE), "--for", "60s", "--inject", "F4@10s"]) == 0
    out = capsys.readouterr().out
    assert "Damage events: none" in out and "cycles 7" in out
    assert "10.000 s  V1 -> R9 {F4, F9}  flags def_fso  (N3 -> R9 on fso and not fsc " \
           "within [0s, 1.4s))" in out
    assert "10.500 s  V1 -> S4 {F4}  flags def_fso  (R9 -> S4 after 500ms)" in out
    assert "reconstructed: fso from fso_hat since 10.000 s" in out
    assert "masked: none" in out


def test_run_summary_counts_masked_orders_apart_from_corrections(capsys):
    from hmi.cli import main
    assert main(["run", str(VALVE), "--for", "30s", "--inject", "F2@8.2s"]) == 0
    out = capsys.readouterr().out
    assert "scans corrected 0" in out
    assert "9.190 s  V1 -> B2 {F2, F5}  flags def_fsc, def_V" in out
    assert "masked: C since 9.190 s, O since 9.190 s (2082 scans withdrew an order" in out


def test_an_order_withdrawn_mid_travel_by_a_latch_resynchronises_instead_of_faulting(project):
    session = make_session(project)
    run(session, 2)  # opening since 1.000 s
    assert session.last.snapshot.diagnosers[0].state == "N3"
    session.engine.latch_safe("test", "an operator emergency stop")
    snaps = run(session, 5)  # much longer than the travel window: no arrival, no fault
    assert snaps[1].diagnosers[0].state == "N0"
    assert snaps[1].diagnosers[0].via == "N3 -> N0 on not O and not fsc and not fso"
    assert not any(s.diagnosers[0].faulty for s in snaps)
    # After the reset the filter refuses to restart the opening from mid-travel (CSs6), so
    # the valve stays where the latch left it; the diagnoser waits, synchronising, no fault.
    assert "safe-state latch released" in session.command(FaultReset()).message
    after = run(session, 10)
    assert {s.diagnosers[0].state for s in after} == {"N0"}
    assert not any(s.masked for s in after)


def test_a_gap_in_the_observation_sends_a_normal_diagnoser_back_to_synchronising(project):
    engine = Engine(project, SimPlant(project))
    for k in range(150):  # 1.49 s: opening (N3)
        snap = engine.step(k * SCAN)
    assert snap.diagnosers[0].state == "N3"
    # A live run paused for 3 s: the next scan comes 3 s later.
    snap = engine.step(snap.time_us + 3 * S)
    d = snap.diagnosers[0]
    assert d.state == "N0" and d.via == "plant not observed for 3s: re-synchronising"
    assert not d.faulty


def test_a_plant_outage_keeps_a_faulty_decision_and_resynchronises_a_normal_one(project):
    from hmi.plant.base import PlantError

    class Flaky(SimPlant):
        down: tuple[int, int] = (0, 0)

        def read(self, now_us):
            if self.down[0] <= now_us < self.down[1]:
                raise PlantError("connection lost")
            return super().read(now_us)

    plant = Flaky(project)
    plant.down = (int(1.5 * S), int(2.5 * S))
    session = Session(Engine(project, plant))
    snaps = run(session, 3)
    during = next(s for s in snaps if s.time_us == 2 * S)
    assert during.diagnosers[0].state == "N3"  # shown as it stood, not stepped
    back = next(s for s in snaps if s.time_us == 2_500 * MS)
    assert back.diagnosers[0].state == "N0"
    assert back.diagnosers[0].via.startswith("plant not observed for")
    # A faulty decision outlives an outage.
    plant = Flaky(project)
    plant.inject(parse_injection("F9@1.5s"))
    plant.down = (int(2 * S), int(3 * S))
    session = Session(Engine(project, plant))
    assert run(session, 4)[-1].diagnosers[0].state == "S9"


def test_a_catch_up_scan_does_not_make_the_next_normal_step_a_gap(project):
    """A live run's scans come at uneven times: one 1 ms after the previous (catching up
    after a late one), the next 11 ms later. A gap is counted in the nominal period (the
    project's 10 ms), not in the shortest step seen, so none of these resets the diagnoser;
    a pause of 3 s still does."""
    engine = Engine(project, SimPlant(project))
    for k in range(150):  # 1.49 s: opening (N3)
        snap = engine.step(k * SCAN)
    assert snap.diagnosers[0].state == "N3"
    now = snap.time_us
    for step in (1, 11, 1, 19, 3, 17, 1, 60, 10):  # in ms; 60 ms: six scans late, no gap
        now += step * MS
        snap = engine.step(now)
        d = snap.diagnosers[0]
        assert d.state == "N3" and not d.via.startswith("plant not observed"), (step, d.via)
    snap = engine.step(now + 3 * S)
    assert snap.diagnosers[0].via == "plant not observed for 3s: re-synchronising"


def test_a_session_slower_than_the_project_counts_gaps_in_its_own_period(project):
    """`--period 200ms` on a 10 ms project: a 200 ms step is one scan, not twenty, even after
    a 1 ms catch-up scan; a gap is ten of the session's periods."""
    engine = Engine(project, SimPlant(project))
    Session(engine, 200 * MS)
    now = 0
    snaps = []
    for step in (200, 200, 200, 200, 200, 200, 1, 200, 199, 201):  # 1.4 s: opening (N3)
        now += step * MS
        snaps.append(engine.step(now))
    assert snaps[-1].diagnosers[0].state == "N3"
    assert not any(s.diagnosers[0].via.startswith("plant not observed") for s in snaps)
    assert engine.step(now + 2_001 * MS).diagnosers[0].via.startswith("plant not observed")

"""Recovery: a declared way back from every fault, in virtual time.

The valve's 13 faults each end with the cell in automatic operation after fault, repair,
recovery and reset (one test runs them all); the two dead ends of the issue (F13 repaired,
a plant connection lost mid-travel) are shown to be dead ends without the recovery and
ways back with it; the recovery is still filtered, times out, is journalled and refused
where it must be; its loader errors name file:line:column.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hmi.engine.commands import (
    EndRecovery,
    FaultReset,
    RepairFaults,
    SetMode,
    SetPolicy,
    StartRecovery,
)
from hmi.engine.scan import Engine
from hmi.errors import ProjectError
from hmi.explain.journal import Journal, read
from hmi.explain.reset import reset_preview
from hmi.plant.base import PlantError
from hmi.plant.sim.plant import SimPlant
from hmi.project.campaign import campaign_of
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session
from tests.cellruns import run_quietly
from tests.conftest import PROJECTS

S = 1_000_000
VALVE = PROJECTS / "cispi_valve"


def cycles(snap) -> int:
    return dict(snap.snapshot.plant_counters)["cycles"]


def run_until(session: Session, predicate, limit_us: int):
    """Scans until `predicate(snapshot)`, at most `limit_us` of virtual time."""
    end = session.engine.now + limit_us
    snap = session.scan_once()
    while not predicate(snap):
        assert session.engine.now < end, "did not happen in time"
        snap = session.scan_once()
    return snap


def recover(session: Session, name: str = "V1_close"):
    """Repair done: start the recovery, wait for its end, fault reset, leave recovery."""
    result = session.command(StartRecovery(name))
    assert result.accepted, result.message
    snap = run_until(session, lambda s: s.snapshot.recovery.status != "running", 5 * S)
    assert snap.snapshot.recovery.status == "done", snap.snapshot.recovery.message
    reset = session.command(FaultReset())
    assert reset.accepted
    left = session.command(EndRecovery())
    assert left.accepted and "initial steps" in left.message
    return snap


def test_every_valve_fault_ends_in_automatic_operation_after_repair_recovery_and_reset():
    project = load_project(VALVE)
    scenarios = [s for s in campaign_of(project).scenarios if s.table]
    assert sorted((s.fault for s in scenarios), key=lambda f: int(f[1:])) == \
        [f"F{k}" for k in range(1, 14)]
    needed_for = []
    for scenario in scenarios:
        plant = SimPlant(project)
        plant.inject(parse_injection(f"{scenario.fault}@{scenario.at_us}us"))
        session = Session(Engine(project, plant))
        faulty = []
        snap = run_quietly(session, scenario.at_us + 12 * S,
                           lambda s, seen=faulty: seen.extend(
                               d.labels for d in s.snapshot.diagnosers if d.faulty))
        assert faulty, f"{scenario.fault} was never diagnosed"
        if snap.snapshot.recovery.needed:
            needed_for.append(scenario.fault)
        assert session.command(RepairFaults()).accepted
        repaired_at = len(plant.events())
        recover(session)
        before = cycles(session.last)
        snap = run_quietly(session, 20 * S)
        assert snap.snapshot.mode == "auto", scenario.fault
        assert not snap.snapshot.latched and not snap.error, scenario.fault
        diagnosers = snap.snapshot.diagnosers
        assert not any(d.faulty for d in diagnosers), (scenario.fault, diagnosers)
        assert cycles(snap) - before >= 2, f"{scenario.fault}: the cycle did not resume"
        assert not [e for e in plant.events()[repaired_at:] if e.damage], scenario.fault
        assert not snap.snapshot.recovery.needed
    # The faults that leave the valve between its ends are the ones that called for it.
    assert {"F1", "F3", "F13"} <= set(needed_for)


def test_f13_repaired_is_a_dead_end_without_the_recovery_and_the_reset_says_so():
    project = load_project(VALVE)
    plant = SimPlant(project)
    plant.inject(parse_injection("F13@10.4s"))
    session = Session(Engine(project, plant))
    run_quietly(session, 22 * S)
    session.command(RepairFaults())
    snap = session.scan_once()
    lines = reset_preview(snap.snapshot, snap.alarms)
    advice = [line for line in lines if line.recovery]
    assert advice and all(line.recovery == "V1_close" for line in advice)
    assert any("known position" in line.why for line in advice)
    session.command(FaultReset())
    stuck = run_quietly(session, 20 * S)
    assert any(d.faulty for d in stuck.snapshot.diagnosers)  # the reset alone cannot re-synchronise
    assert 0 < dict(stuck.snapshot.plant_state)["position"] < 100
    assert [n[0] for n in stuck.snapshot.recovery.needed] == ["V1_close"]
    assert any(e.key == "recovery_needed:V1_close" and e.alarm and any(
        p.id == "recovery" and p.recommended for p in e.policies)
        for e in stuck.explanations)
    # Manual mode does not get it out either: the mask holds the orders at 0.
    session.command(SetMode(True))
    assert "C" in session.scan_once().snapshot.masked
    session.command(SetMode(False))
    recover(session)
    snap = run_quietly(session, 20 * S)
    assert cycles(snap) >= 2 and not any(d.faulty for d in snap.snapshot.diagnosers)


class Outage(SimPlant):
    """A simulated plant whose inputs cannot be read during `down`: the engine latches the
    safe vector, which reaches the valve and stops it where it is (a Modbus link that drops
    the reads first, or a device that answers writes only)."""

    down: tuple[int, int] = (0, 0)

    def read(self, now_us):
        if self.down[0] <= now_us < self.down[1]:
            raise PlantError("connection lost")
        return super().read(now_us)


def test_a_connection_lost_mid_travel_is_a_dead_end_without_the_recovery():
    project = load_project(VALVE)
    plant = Outage(project)
    plant.down = (int(2 * S), int(3 * S))  # the valve is opening (1 s to 2.96 s)
    session = Session(Engine(project, plant))
    run_quietly(session, 4 * S)
    assert session.last.snapshot.latched
    assert session.command(FaultReset()).accepted
    snap = run_quietly(session, 10 * S)
    assert not snap.snapshot.latched
    assert cycles(snap) == 0 and 0 < dict(snap.snapshot.plant_state)["position"] < 100
    report = snap.snapshot.filter_report
    assert report is not None and "CSs6" in report.violated_names
    assert [n[0] for n in snap.snapshot.recovery.needed] == ["V1_close"]
    assert any(line.recovery == "V1_close" for line in reset_preview(snap.snapshot, snap.alarms))
    events = len(plant.events())
    recover(session)
    snap = run_quietly(session, 20 * S)
    assert cycles(snap) >= 2 and snap.snapshot.mode == "auto"
    assert not [e for e in plant.events()[events:] if e.damage]


@pytest.fixture
def long_recovery(tmp_path: Path) -> Path:
    """The valve with a recovery that would hold the close order past the closed end: it
    asks to close until the *open* switch is made (a wrong procedure), so only its own
    constraint and its timeout stand between it and the end stop."""
    folder = tmp_path / "valve"
    shutil.copytree(VALVE, folder)
    text = (folder / "recovery.yaml").read_text()
    (folder / "recovery.yaml").write_text(
        text.replace("do: [C], until: fsc}", "do: [C], until: fso}"))
    return folder


@pytest.mark.parametrize("policy", ["correct", "monitor"])
def test_a_recovery_is_still_filtered_by_its_own_constraints_and_times_out(long_recovery,
                                                                           policy):
    project = load_project(long_recovery)
    plant = SimPlant(project)
    session = Session(Engine(project, plant, policy=policy))
    session.run_for(S // 2)  # closed, at rest
    assert session.command(StartRecovery("V1_close")).accepted
    snap = session.scan_once()
    assert snap.snapshot.fov_map["C"] is True and snap.snapshot.value("fsc")
    assert snap.snapshot.policy == policy
    report = snap.snapshot.filter_report
    assert report is not None and "R_V1_closed" in report.violated_names
    assert snap.snapshot.output_map["C"] is False  # the close order withdrawn at the closed end
    snap = run_until(session, lambda s: s.snapshot.recovery.status != "running", 4 * S)
    assert snap.snapshot.recovery.status == "failed" and "not done within 3.000 s" in \
        snap.snapshot.recovery.message
    assert not any(snap.snapshot.outputs)
    assert not [e for e in plant.events() if e.damage]
    assert any(e.key == "recovery_failed:V1_close" and e.alarm and e.severity == "high"
               for e in snap.explanations)


def test_recovery_is_refused_where_it_must_be_and_journalled(tmp_path):
    project = load_project(VALVE)
    plant = Outage(project)
    plant.down = (int(2 * S), int(2.5 * S))  # the valve stops half open
    session = Session(Engine(project, plant))
    journal = Journal(tmp_path / "journal.jsonl")
    recorder = JournalRecorder(session, journal)
    session.run_for(3 * S)
    refused = session.command(StartRecovery("V1_close"))
    assert not refused.accepted and "fault reset first" in refused.message
    assert not session.command(StartRecovery("nope")).accepted
    assert not session.command(EndRecovery()).accepted
    session.command(FaultReset())
    assert session.command(StartRecovery("V1_close")).accepted
    assert session.scan_once().snapshot.mode == "recovery"
    assert not session.command(SetMode(True)).accepted
    assert not session.command(StartRecovery("V1_close")).accepted  # one at a time
    assert session.command(SetPolicy("block")).accepted  # the policy still applies
    run_until(session, lambda s: s.snapshot.recovery.status == "done", 3 * S)
    assert session.command(EndRecovery()).accepted
    recorder.close()
    entries = read(journal.path).entries
    actions = [(e["event"], e["accepted"]) for e in entries if e["type"] == "action"]
    assert ("start recovery V1_close", False) in actions
    assert ("start recovery V1_close", True) in actions
    assert ("leave recovery mode", True) in actions
    done = [e for e in entries if e["type"] == "recovery"]
    assert [e["event"] for e in done] == ["done"] and "Valve V1" in done[0]["message"]


def test_the_project_errors_of_a_recovery_name_file_line_and_column(tmp_path):
    folder = tmp_path / "valve"
    shutil.copytree(VALVE, folder)
    text = (folder / "recovery.yaml").read_text()
    (folder / "recovery.yaml").write_text(
        text.replace("relaxes: [CSs3,", "relaxes: [CSs99,")
            .replace("do: [C]", "do: [C, Z]")
            .replace("R_V1_both:", "CSs1:"))
    with pytest.raises(ProjectError) as caught:
        load_project(folder)
    messages = [(str(e.pos), e.message) for e in caught.value.errors]
    text = str(caught.value)
    assert "recovery.yaml:" in text
    assert "relaxes 'CSs99', which is not a constraint of the project" in text
    assert "drives 'Z', which is not an output" in text
    assert "constraint name 'CSs1' is already used by the project" in text
    assert all(pos.count(":") >= 2 for pos, _ in messages)  # file:line:column


# -- in the HMI ------------------------------------------------------------------------------


async def test_the_operator_finds_the_way_back_from_f13_through_the_reset_dialog():
    from ui_harness import palette, region_text, run_for, run_until, screen_text, wait_for_main
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ConfirmDialog
    from hmi.ui.headless import press, wait_for_screen

    app = make_app(inject=("F13@10.4s",))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.recovery.needed, 20, "recovery needed")
        await palette(pilot, "SIMULATION: repair")
        await press(pilot, "r")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "g: start recovery" in text and "known position" in text
        assert dialog.alternative == "Start recovery"
        await press(pilot, "g")
        await wait_until_dialog(pilot, "recovery-dialog")
        text = screen_text(app)
        assert "Start recovery: Close valve V1" in text and "Only the close order acts" in text
        await press(pilot, "y")
        await wait_for_main(pilot)
        # the message line names the procedure by its title, not by its identifier
        assert "start recovery" in app.message.plain and "V1_close" not in app.message.plain
        assert "Close valve V1" in app.message.plain
        await run_for(pilot, 0.5)
        assert "RECOVERY" in region_text(app, "#status")
        assert "▲ RECOVERY ▲" in region_text(app, "#banners")
        await run_until(pilot, lambda s: s.snapshot.recovery.status == "done", 3, "recovery done")
        assert "RECOVERY DONE" in region_text(app, "#banners")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await press(pilot, "m")
        await wait_until_dialog(pilot, "recovery-dialog")
        assert "Leave recovery mode?" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 20)
        snap = app.link.session.last
        assert snap.snapshot.mode == "auto" and "AUTO" in region_text(app, "#status")
        assert cycles(snap) >= 2 and not any(d.faulty for d in snap.snapshot.diagnosers)
        assert not app.query_one("#banners").display


async def wait_until_dialog(pilot, dialog_id: str) -> None:
    from hmi.ui.headless import wait_until
    await wait_until(pilot, lambda: pilot.app.screen.id == dialog_id, dialog_id)
    await pilot.pause()


@pytest.mark.parametrize("fault", ["V1.F13@26.5s", "V2.F13@22.5s", "V1.F1@30s", "P.welded@30s"])
def test_the_subsystem_is_brought_back_to_its_initial_state_by_its_cell_recovery(fault):
    project = load_project(PROJECTS / "cispi_subsystem")
    plant = SimPlant(project)
    injection = parse_injection(fault)
    plant.inject(injection)
    session = Session(Engine(project, plant))
    snap = run_quietly(session, injection.at_us + 15 * S)
    if "F13" in fault or "F1@" in fault:
        assert [n[0] for n in snap.snapshot.recovery.needed] == ["cell_home"]
    assert session.command(RepairFaults()).accepted
    repaired_at = len(plant.events())
    recover(session, "cell_home")
    fills = dict(session.last.snapshot.plant_counters)["T2.fills"]
    snap = run_quietly(session, 60 * S)
    assert dict(snap.snapshot.plant_counters)["T2.fills"] - fills >= 2
    assert not any(d.faulty for d in snap.snapshot.diagnosers) and not snap.snapshot.latched
    assert not [e for e in plant.events()[repaired_at:] if e.damage]


def test_the_program_waits_while_a_recovery_runs_and_restarts_from_its_initial_steps():
    """The recovery dialog says the control program waits: its steps and step times hold
    through the whole procedure and the fault reset at its end (no step fires while the
    procedure drives the valve), and leaving recovery starts it from its initial steps."""
    project = load_project(VALVE)
    plant = SimPlant(project)
    plant.inject(parse_injection("F13@10.4s"))
    session = Session(Engine(project, plant))
    run_quietly(session, 22 * S)
    session.command(RepairFaults())
    before = session.scan_once()
    assert session.command(StartRecovery("V1_close")).accepted
    seen = set()
    snap = run_until(session, lambda s: seen.add(s.snapshot.active_steps) or
                     s.snapshot.recovery.status != "running", 5 * S)
    assert snap.snapshot.recovery.status == "done"
    assert session.command(FaultReset()).accepted
    snap = run_quietly(session, 10 * S, lambda s: seen.add(s.snapshot.active_steps))
    assert seen == {before.snapshot.active_steps}, seen
    assert not snap.snapshot.output_map["O"]  # what the panel showed is what the valve does
    assert session.command(EndRecovery()).accepted
    snap = session.scan_once()
    assert snap.snapshot.mode == "auto"
    initial = tuple(s.name for s in project.controls[snap.snapshot.control_name].grafcet.steps
                    if s.initial)
    assert snap.snapshot.active_steps == initial != before.snapshot.active_steps


async def test_the_recovery_banner_says_the_next_step_the_state_needs():
    """RECOVERY DONE: "next: r fault reset" while a reset has something to release; after the
    reset only leaving recovery is left, and the control panel has not moved meanwhile."""
    from ui_harness import palette, region_text, run_for, run_until, wait_for_main
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ConfirmDialog
    from hmi.ui.headless import press, wait_for_screen

    app = make_app(inject=("F13@10.4s",))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.recovery.needed, 20, "recovery needed")
        await palette(pilot, "SIMULATION: repair")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "g")
        await wait_until_dialog(pilot, "recovery-dialog")
        await press(pilot, "y")
        await wait_for_main(pilot)
        # (the program waits: its steps read held, not running)
        active = [line for line in region_text(app, "#control").splitlines() if "‖" in line]
        await run_until(pilot, lambda s: s.snapshot.recovery.status == "done", 3, "recovery done")
        assert "next: r fault reset" in region_text(app, "#banners")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 3)
        banners = region_text(app, "#banners")
        assert "RECOVERY DONE" in banners and "next: m leave recovery" in banners
        assert "fault reset" not in banners
        snap = app.link.session.last
        assert not snap.snapshot.output_map["O"] and not snap.snapshot.output_map["C"]
        # the program waits where it was: the same steps, held, none running
        control = region_text(app, "#control").splitlines()
        assert active and active == [line for line in control if "‖" in line]
        assert "(held)" in active[0] and not [line for line in control if "●" in line]


def test_under_a_plant_loss_latch_the_reset_dialog_offers_no_recovery_the_engine_refuses():
    """The valve stopped mid-travel by a lost connection: while the outputs are held safe the
    engine refuses any recovery ("a fault reset first"), so the reset dialog offers none (no
    `g`) and says the order: this reset first, then the recovery."""
    project = load_project(VALVE)
    plant = Outage(project)
    plant.down = (int(2 * S), int(3 * S))
    session = Session(Engine(project, plant))
    snap = run_quietly(session, 12 * S)
    # latched, and the valve between its ends
    assert snap.snapshot.latched and snap.snapshot.recovery.needed
    lines = reset_preview(snap.snapshot, snap.alarms)
    assert not any(line.recovery for line in lines)
    assert any("this reset first" in line.why for line in lines)
    refused = session.command(StartRecovery("V1_close"))
    assert not refused.accepted and "fault reset first" in refused.message
    assert session.command(FaultReset()).accepted
    snap = session.scan_once()
    assert not snap.snapshot.latched
    now = reset_preview(snap.snapshot, snap.alarms)
    assert any(line.recovery == "V1_close" for line in now)  # now it is


def test_a_reset_during_f7_while_the_valve_travels_does_not_call_for_a_recovery():
    """F7 (closed switch made too early) while the valve closes: between its ends only
    because it travels, and driven; waiting for its end is enough, then a reset
    re-synchronises. The dialog says so, and offers no recovery."""
    project = load_project(VALVE)
    plant = SimPlant(project)
    plant.inject(parse_injection("F7@14.5s"))
    session = Session(Engine(project, plant))
    snap = run_quietly(session, int(14.9 * S))
    assert any(d.faulty and not d.resync for d in snap.snapshot.diagnosers)
    assert 0 < dict(snap.snapshot.plant_state)["position"] < 100 and snap.snapshot.output_map["C"]
    lines = reset_preview(snap.snapshot, snap.alarms)
    assert not any(line.recovery for line in lines)
    assert any("still driven" in line.why and "no recovery" in line.why for line in lines)
    # the valve reaches its closed end within the 2 s the issue measured
    snap = run_until(session, lambda s: any(d.resync for d in s.snapshot.diagnosers), 2 * S)
    assert any(line.resets and line.target for line in reset_preview(snap.snapshot, snap.alarms))
    assert session.command(FaultReset()).accepted
    assert not any(d.faulty for d in session.scan_once().snapshot.diagnosers)

"""Named states of the app (the CISPI valve, the conveyor/robot cell), reached by pressing the
operator's keys.

The snapshot tests and the screenshot script (``python tests/screenshots.py``) share these,
so the README's pictures are the states the tests check. Every scenario runs in virtual time
with wall-clock figures hidden, so it renders identically on any machine.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from textual.pilot import Pilot
from ui_harness import palette, run_for, run_until, wait_for_main

from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.kept import load_once
from hmi.session.session import Session
from hmi.ui.alarm_list import AlarmList
from hmi.ui.app import PlcHmiApp
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.headless import drain, press, settle, wait_for_screen, wait_until
from hmi.ui.io_panel import IOPanel

VALVE = Path(__file__).resolve().parents[1] / "projects" / "cispi_valve"
CONVEYOR = VALVE.parent / "conveyor_robot"


def make_app(project: Path = VALVE, control: str | None = None,
             policy: str | None = None, inject: tuple[str, ...] = (),
             diagnoser: str | None = None) -> PlcHmiApp:
    """A virtual-time app on a simulated plant, with no wall-clock figures on screen.

    `inject` are faults as the command line writes them (``C1.stop@1s+2s``), scheduled
    before the first scan as ``plchmi ui --inject`` does; `diagnoser` a diagnoser variant
    (``--diagnoser``)."""
    loaded = load_once(project, diagnoser)
    injections = tuple(parse_injection(text) for text in inject)
    plant = SimPlant(loaded)
    for injection in injections:
        plant.inject(injection)
    engine = Engine(loaded, plant, control=control, policy=policy)
    return PlcHmiApp(Session(engine), live=False, show_measured=False,
                     injected=injections)


async def select_row(pilot: Pilot, name: str) -> None:
    """Move the I/O table's cursor to the row of `name`."""
    table = pilot.app.query_one(IOPanel)
    table.focus()
    table.move_cursor(row=table.get_row_index(name))
    await drain(pilot)


async def normal(pilot: Pilot) -> None:
    """The valve cycling: second cycle, open and filling."""
    await run_for(pilot, 12.3)


async def manual(pilot: Pilot) -> None:
    """Manual mode with the open order forced on, the valve opening under it."""
    await run_for(pilot, 9.5)  # closed, waiting
    await press(pilot, "m")
    await wait_for_screen(pilot, ConfirmDialog)
    await press(pilot, "y")
    await wait_for_main(pilot)
    await run_for(pilot, 0.5)
    await select_row(pilot, "O")
    await press(pilot, "1")
    await settle(pilot)
    await run_for(pilot, 1.2)


async def stepping(pilot: Pilot) -> None:
    """Paused mid-opening, then stepped three scans."""
    await run_for(pilot, 1.5)
    await press(pilot, "space")
    await press(pilot, "s", "s", "s")
    await settle(pilot)


async def fault_f13(pilot: Pilot) -> None:
    """SIMULATION: F13 injected while opening; the valve jams at 40 % (the motor stalls
    before any arrival deadline can expire), the diagnoser concludes {F3, F13} when fso does
    not come: fso reconstructed, both orders masked."""
    await run_until(pilot, lambda s: "X1" in s.snapshot.active_steps, 5, "the opening step")
    await run_for(pilot, 0.8)
    await press(pilot, "f")
    await wait_for_screen(pilot, FaultDialog)
    await press(pilot, "end", "enter", "enter")  # F13 is the last fault; "0": now
    await wait_for_main(pilot)
    await run_for(pilot, 4.0)


async def fault_dialog(pilot: Pilot) -> None:
    """The SIMULATION fault injection dialog, F13 highlighted."""
    await run_for(pilot, 3.0)
    await press(pilot, "f")
    await wait_for_screen(pilot, FaultDialog)
    await press(pilot, "end")
    await drain(pilot)


async def faulty_program(pilot: Pilot) -> None:
    """The deliberately faulty program: it holds orders against the end stops and orders
    open and close together; the filter is at work (correct or block, by the app's policy)."""
    await run_for(pilot, 8.7)


async def inject_by_dialog(pilot: Pilot, index: int, delay: str) -> None:
    """SIMULATION: the fault dialog's `index`-th fault, `delay` seconds from now."""
    await press(pilot, "f")
    await wait_for_screen(pilot, FaultDialog)
    await press(pilot, *(["down"] * index), "enter")  # the fault; then the delay field
    await press(pilot, "backspace", *delay, "enter")
    await wait_for_main(pilot)


def decided(labels: tuple[str, ...]):
    return lambda s: bool(s.snapshot.diagnosers) and s.snapshot.diagnosers[0].labels == labels


async def diagnosis_certain(pilot: Pilot) -> None:
    """SIMULATION: F9 (unexpected fso rise) at 10 s; the diagnoser isolates it with
    certainty (S9), fso is read from its estimate; the explanation opened to its evidence."""
    await inject_by_dialog(pilot, 8, "10")
    await run_until(pilot, decided(("F9",)), 25, "F9 isolated")
    await run_for(pilot, 1.0)
    await press(pilot, "e")
    await settle(pilot)


async def diagnosis_ambiguous(pilot: Pilot) -> None:
    """SIMULATION: F1 (fsc stuck at 0) at 10 s; at the end of the next closing the diagnoser
    concludes {F1, F13}: ambiguous, fsc reconstructed, orders masked. The explanation is
    open to its policies, the recommended one (check the valve first) focused."""
    await inject_by_dialog(pilot, 0, "10")
    await run_until(pilot, decided(("F1", "F13")), 25, "the ambiguity {F1, F13}")
    await run_for(pilot, 1.0)
    await press(pilot, "e", "e", "e")
    await settle(pilot)


async def reset_refused(pilot: Pilot) -> None:
    """The fault reset dialog after F1: the diagnoser cannot re-synchronise (fsc=0, fso=0
    match no normal state), so the dialog says what stays and why."""
    await diagnosis_ambiguous_state(pilot)
    await press(pilot, "r")
    await wait_for_screen(pilot, ConfirmDialog)
    await drain(pilot)


async def diagnosis_ambiguous_state(pilot: Pilot) -> None:
    await inject_by_dialog(pilot, 0, "10")
    await run_until(pilot, decided(("F1", "F13")), 25, "the ambiguity {F1, F13}")
    await run_for(pilot, 1.0)


async def manual_refused(pilot: Pilot) -> None:
    """Manual mode, the valve open: the operator asks for the open order, the filter refuses
    it (CSs2: never hold the open order on an open valve) and the answer says so."""
    await run_until(pilot, lambda s: "X2" in s.snapshot.active_steps, 10, "the valve open")
    await press(pilot, "m")
    await wait_for_screen(pilot, ConfirmDialog)
    await press(pilot, "y")
    await wait_for_main(pilot)
    await select_row(pilot, "O")
    await press(pilot, "1")
    await run_for(pilot, 0.05)


async def monitor_fault(pilot: Pilot) -> None:
    """Conveyor/robot, 002 §4 paper scenario (C1.stop@1s+2s): the conveyor's monitor fires
    at x = 3 s, y = 1 s, two seconds before a watchdog would; its explanation opened."""
    await run_until(pilot, lambda s: any(m.detection for m in s.snapshot.monitors), 5,
                    "the conveyor monitor's fault")
    await run_for(pilot, 0.5)
    await press(pilot, "e")
    await settle(pilot)


async def conveyor_stuck(pilot: Pilot) -> None:
    """Conveyor/robot: manual mode entered mid-transfer for 5 s; back in automatic mode the
    robot takes the pallet X3 counts on and the program waits in X3 + X10 for a pallet that
    will not come. Past X3's supervision time (10 s) the alarm says it is stuck and what it
    waits for; the operator selects it and opens its explanation."""
    await run_for(pilot, 1)
    await press(pilot, "m", "y")
    await wait_for_main(pilot)
    await run_for(pilot, 5)
    await press(pilot, "m", "y")
    await wait_for_main(pilot)
    await run_until(pilot, lambda s: "X3" in s.snapshot.overdue_steps, 12, "X3 overdue")
    await run_for(pilot, 0.5)
    await press(pilot, "tab")
    await wait_until(pilot, lambda: isinstance(pilot.app.focused, AlarmList), "the list")
    await press(pilot, "home", "e")
    await settle(pilot)


async def alarms_80x24(pilot: Pilot) -> None:
    """The faulty program at 80×24: five alarms in three rows; the operator tabs to the list,
    selects the second (active) alarm and acknowledges it: it goes after the unacknowledged
    ones, and the list scrolls to keep it in view."""
    await run_for(pilot, 8.7)
    await press(pilot, "tab")
    await wait_until(pilot, lambda: isinstance(pilot.app.focused, AlarmList), "the list")
    await press(pilot, "down", "a")
    await run_for(pilot, 0.01)


async def recovery(pilot: Pilot) -> None:
    """F13 at 10.4 s jams the valve 78 % open; repaired, the fault reset cannot re-synchronise
    the diagnoser and offers the recovery (g); confirmed, the valve closes in recovery mode."""
    await run_until(pilot, lambda s: s.snapshot.recovery.needed, 20, "recovery needed")
    await palette(pilot, "SIMULATION: repair")
    await press(pilot, "r")
    await wait_for_screen(pilot, ConfirmDialog)
    await press(pilot, "g")
    await wait_until(pilot, lambda: pilot.app.screen.id == "recovery-dialog",
                     "the recovery dialog")
    await press(pilot, "y")
    await wait_for_main(pilot)
    await run_for(pilot, 0.8)


class _Served:
    """A server's state as the HMI reads it (hmi.opcua.status), fixed for the picture: two
    SCADA clients, one of them sending commands over an encrypted channel."""

    def __init__(self) -> None:
        from hmi.opcua.status import SERVING, OpcClient, ServingStatus
        self._status = ServingStatus(
            "opc.tcp://0.0.0.0:4840", SERVING,
            ("None", "Basic256Sha256 Sign", "Basic256Sha256 SignAndEncrypt"), writable=True,
            users=2, clients=(OpcClient("10.0.4.21:50412", "anonymous", "None"),
                              OpcClient("10.0.4.30:61022", "alice",
                                        "Basic256Sha256 SignAndEncrypt")),
            published=1230, events=0)

    def status(self):
        return self._status


def served_app() -> PlcHmiApp:
    """The valve served over OPC UA (``--opcua``), its server's state fixed (`_Served`)."""
    app = make_app()
    app.served = _Served()
    return app


async def serving(pilot: Pilot) -> None:
    """Served over OPC UA: the status bar counts the SCADA's clients, at 80×24 beside the
    mode and the policy (the palette's server page: tests/test_opcua_ui.py)."""
    await run_for(pilot, 12.3)


HISTORY_EPOCH_US = 1_790_000_000_000_000  # 2026-09-21 14:13:20 UTC: the trends' time 0


def history_app() -> PlcHmiApp:
    """The valve with its historian and journal (in a temporary folder kept with the app),
    the run's time 0 fixed and the trends' times in UTC: the same picture on any machine."""
    import tempfile
    from datetime import UTC

    from hmi.history.historian import Historian
    from hmi.history.target import Target
    from hmi.session.runio import open_journal

    folder = tempfile.TemporaryDirectory(prefix="plchmi-trends-")
    loaded = load_once(VALVE, None)
    plant = SimPlant(loaded)
    plant.inject(parse_injection("F13@8m"))
    session = Session(Engine(loaded, plant))
    session.epoch_us = HISTORY_EPOCH_US
    journal = open_journal(session, Path(folder.name) / "journal.jsonl", "hmi")
    historian = Historian(session, Target("sqlite", str(Path(folder.name) / "history.sqlite")),
                          journal=journal, flush_s=0.05).attach()
    app = PlcHmiApp(session, live=False, show_measured=False)
    app.trend_zone = UTC
    app.scenario_history = (folder, journal, historian)  # type: ignore[attr-defined]
    return app


async def trends(pilot: Pilot, signals: tuple[str, ...] | None = None) -> None:
    """Ten minutes of the valve, F13 at 8 min (its alarm acknowledged), then the trends: the
    last 15 min (the cell started 10 min ago: nothing known before, and said)."""
    from hmi.ui.trend_screen import TrendScreen
    await run_for(pilot, 510)
    await press(pilot, "A")  # acknowledge all
    await run_for(pilot, 90)
    _, _, historian = pilot.app.scenario_history  # type: ignore[attr-defined]
    historian.flush()
    await press(pilot, "t")
    screen = await wait_for_screen(pilot, TrendScreen)
    if signals is not None:
        screen.show(signals)
    await wait_until(pilot, lambda: screen.up_to_date, "the picture of the signals")
    await press(pilot, "left", "left", "left", "left", "left", "left")


TREND_SIGNALS_80x24 = ("O", "C", "fso", "fsc", "CSc1", "V1.state", "O.travel", "O.operations")
TREND_SIGNALS = ("O", "C", "fso", "fsc", "O.fov", "C.fov", "CSc1", "V1.state", "O.travel",
                 "O.operations", "C.travel", "cell.alarms", "plant.position")


@dataclass(frozen=True)
class Scenario:
    name: str
    size: tuple[int, int]
    run: Callable[[Pilot], Awaitable[None]]
    description: str
    make: Callable[[], PlcHmiApp] = field(default=make_app)


SCENARIOS: tuple[Scenario, ...] = (
    Scenario("normal_80x24", (80, 24), normal, "The valve cycling, at 80×24"),
    Scenario("normal_160x48", (160, 48), normal, "The valve cycling, at 160×48"),
    Scenario("manual", (100, 30), manual, "Manual mode: MANUAL / FORCES ACTIVE, O forced on"),
    Scenario("stepping", (80, 24), stepping, "Paused, stepped scan by scan"),
    Scenario("fault_f13", (120, 36), fault_f13,
             "SIMULATION: F13 injected, the valve jammed; diagnosed {F3, F13}, orders masked"),
    Scenario("fault_dialog", (100, 30), fault_dialog,
             "SIMULATION: the fault injection dialog"),
    Scenario("filter_corrects", (120, 36), faulty_program,
             "The faulty program, corrected by the filter (policy correct)",
             partial(make_app, control="faulty")),
    Scenario("safe_blocking", (100, 30), faulty_program,
             "The faulty program under safe blocking: outputs latched safe",
             partial(make_app, control="faulty", policy="block")),
    Scenario("manual_refused", (100, 30), manual_refused,
             "Manual mode: the open order requested on an open valve, refused by the filter"),
    Scenario("diagnosis_certain", (120, 36), diagnosis_certain,
             "SIMULATION: F9 isolated with certainty; fso read from its estimate"),
    Scenario("diagnosis_ambiguous", (160, 48), diagnosis_ambiguous,
             "SIMULATION: F1 diagnosed {F1, F13}, ambiguous; the explanation open"),
    Scenario("reset_refused", (120, 36), reset_refused,
             "Fault reset after F1: the diagnoser cannot re-synchronise; the dialog says why"),
    Scenario("monitor_fault", (120, 36), monitor_fault,
             "Conveyor/robot (002 §4): the conveyor's stopwatch monitor fires at x = 3 s",
             partial(make_app, CONVEYOR, inject=("C1.stop@1s+2s",))),
    Scenario("conveyor_stuck", (100, 30), conveyor_stuck,
             "Conveyor/robot stuck: X3 past its supervision time, waiting for B and e",
             partial(make_app, CONVEYOR)),
    Scenario("recovery_80x24", (80, 24), recovery,
             "SIMULATION: F13 repaired; RECOVERY closes the valve, filtered by its own rules",
             partial(make_app, inject=("F13@10.4s",))),
    Scenario("alarms_80x24", (80, 24), alarms_80x24,
             "The alarm list at 80×24: five alarms in three rows, one acknowledged",
             partial(make_app, control="faulty")),
    Scenario("trends_80x24", (80, 24), partial(trends, signals=TREND_SIGNALS_80x24),
             "Trends at 80×24: the valve's last 15 min from its history, F13's alarm on the "
             "time axis", history_app),
    Scenario("trends_160x48", (160, 48), partial(trends, signals=TREND_SIGNALS),
             "Trends at 160×48: I/O, what the program asked, a violation, the diagnoser's "
             "state, the valve's opening time and operations", history_app),
    Scenario("serving_80x24", (80, 24), serving,
             "Served over OPC UA (--opcua): two SCADA clients, at 80×24",
             served_app),
)

"""Named states of the app on the CISPI valve, reached by pressing the operator's keys.

The snapshot tests and the screenshot script (``python -m hmi.ui.screenshots``) share these,
so the README's pictures are the states the tests check. Every scenario runs in virtual time
with wall-clock figures hidden, so it renders identically on any machine.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

from textual.pilot import Pilot

from hmi.engine.runner import Controller
from hmi.engine.scan import Engine
from hmi.plant.sim import SimPlant
from hmi.project.loader import load_project
from hmi.ui.app import PlcHmiApp
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.io_panel import IOPanel
from hmi.ui.testing import run_for, run_until, settle, wait_for_main, wait_for_screen

VALVE = Path(__file__).resolve().parents[2] / "projects" / "cispi_valve"


def make_app(project: Path = VALVE, control: str | None = None,
             policy: str | None = None) -> PlcHmiApp:
    """A virtual-time app on a simulated plant, with no wall-clock figures on screen."""
    loaded = load_project(project)
    engine = Engine(loaded, SimPlant(loaded), control=control, policy=policy)
    return PlcHmiApp(Controller(engine), live=False, show_measured=False)


async def select_row(pilot: Pilot, name: str) -> None:
    """Move the I/O table's cursor to the row of `name`."""
    table = pilot.app.query_one(IOPanel)
    table.focus()
    table.move_cursor(row=table.get_row_index(name))
    await pilot.pause()


async def normal(pilot: Pilot) -> None:
    """The valve cycling: second cycle, open and filling."""
    await run_for(pilot, 12.3)


async def manual(pilot: Pilot) -> None:
    """Manual mode with the open order forced on, the valve opening under it."""
    await run_for(pilot, 9.5)  # closed, waiting
    await pilot.press("m")
    await wait_for_screen(pilot, ConfirmDialog)
    await pilot.press("y")
    await wait_for_main(pilot)
    await run_for(pilot, 0.5)
    await select_row(pilot, "O")
    await pilot.press("1")
    await settle(pilot)
    await run_for(pilot, 1.2)


async def stepping(pilot: Pilot) -> None:
    """Paused mid-opening, then stepped three scans."""
    await run_for(pilot, 1.5)
    await pilot.press("space")
    await pilot.press("s", "s", "s")
    await settle(pilot)


async def fault_f13(pilot: Pilot) -> None:
    """SIMULATION: F13 injected while opening; the valve jams, the sequence waits for fso."""
    await run_until(pilot, lambda s: "X1" in s.active_steps, 5, "the opening step")
    await run_for(pilot, 0.8)
    await pilot.press("f")
    await wait_for_screen(pilot, FaultDialog)
    await pilot.press("end", "enter", "enter")  # F13 is the last fault; "0": now
    await wait_for_main(pilot)
    await run_for(pilot, 4.0)


async def fault_dialog(pilot: Pilot) -> None:
    """The SIMULATION fault injection dialog, F13 highlighted."""
    await run_for(pilot, 3.0)
    await pilot.press("f")
    await wait_for_screen(pilot, FaultDialog)
    await pilot.press("end")
    await pilot.pause()


async def faulty_program(pilot: Pilot) -> None:
    """The deliberately faulty program: it holds orders against the end stops and orders
    open and close together; the filter is at work (correct or block, by the app's policy)."""
    await run_for(pilot, 8.7)


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
             "SIMULATION: F13 injected, the valve blocked between its end switches"),
    Scenario("fault_dialog", (100, 30), fault_dialog,
             "SIMULATION: the fault injection dialog"),
    Scenario("filter_corrects", (120, 36), faulty_program,
             "The faulty program, corrected by the filter (policy correct)",
             partial(make_app, control="faulty")),
    Scenario("safe_blocking", (100, 30), faulty_program,
             "The faulty program under safe blocking: outputs latched safe",
             partial(make_app, control="faulty", policy="block")),
)

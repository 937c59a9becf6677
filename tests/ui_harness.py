"""What the UI tests, the snapshot tests and the screenshot script need besides
hmi/ui/headless.py (which the soak uses too): virtual time run on the app's driver, the
screen as text, the command palette, waits on a live app.
"""

from __future__ import annotations

import asyncio
import io
import time
from collections.abc import Callable
from typing import Any

from rich.console import Console
from textual.command import CommandInput, CommandList, CommandPalette
from textual.pilot import Pilot

from hmi.session.view import CellView
from hmi.ui.app import PlcHmiApp
from hmi.ui.driver import VirtualDriver
from hmi.ui.headless import WaitTimeout, press, settle, wait_for_screen, wait_until
from hmi.ui.textual_adapter import render_screen

LIVE_HANG_GUARD_S = 300.0  # live tests: only against a dead thread; waits end on state


async def wait_live(pilot: Pilot, predicate: Callable[[], Any], what: str) -> Any:
    """A live app (its scan thread, its refresh timer): wait for `predicate()` as long as the
    scan thread runs. No deadline paces it; only a dead thread, or a hang of several minutes,
    fails it."""
    app = pilot.app
    started = time.monotonic()
    while True:
        result = predicate()
        if result:
            return result
        runner = getattr(app.driver, "runner", None)
        if runner is not None and runner.started and not runner.alive:
            raise WaitTimeout(f"{what}: the scan thread is not running ({runner.error!r})")
        if time.monotonic() - started > LIVE_HANG_GUARD_S:
            raise WaitTimeout(f"{what} did not happen in {LIVE_HANG_GUARD_S:g} s (a hang)")
        await asyncio.sleep(0.01)


async def wait_for_main(pilot: Pilot) -> None:
    """Wait until every dialog is closed (the main screen is active again)."""
    app = pilot.app
    await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the main screen")
    await settle(pilot)


def driver(pilot: Pilot) -> VirtualDriver:
    app = pilot.app
    assert isinstance(app, PlcHmiApp)
    assert isinstance(app.driver, VirtualDriver), "virtual time needs PlcHmiApp(live=False)"
    return app.driver


async def run_for(pilot: Pilot, seconds: float) -> int:
    """Run `seconds` of virtual time (no scan while paused), then show the result."""
    count = driver(pilot).advance(round(seconds * 1_000_000))
    await settle(pilot)
    return count


async def run_until(pilot: Pilot, predicate: Callable, limit_s: float, what: str) -> None:
    """Run virtual time until `predicate(cell)` (the session's CellView of a scan); fail if
    `limit_s` virtual seconds pass."""
    if not driver(pilot).advance_until(predicate, int(limit_s * 1_000_000)):
        raise WaitTimeout(f"{what} did not happen within {limit_s:g} s of virtual time")
    await settle(pilot)


def violating(cell: CellView) -> bool:
    """A run_until predicate: the filter checked this scan and found a rule violated."""
    report = cell.snapshot.filter_report
    return report is not None and bool(report.violations)


def not_violating(cell: CellView) -> bool:
    """A run_until predicate: the filter checked this scan and found no rule violated."""
    report = cell.snapshot.filter_report
    return report is not None and not report.violations


async def palette(pilot: Pilot, query: str, expect: str | None = None) -> None:
    """Open the command palette, type `query`, and run the first hit (checked by `expect`)."""
    await press(pilot, "ctrl+p")
    screen = await wait_for_screen(pilot, CommandPalette)
    # Typing character by character costs a search per key; set the text in one go (the
    # palette searches on the input's Changed message exactly as when typing).
    screen.query_one(CommandInput).value = query
    expect = expect or query

    def first_hit():
        commands = screen.query_one(CommandList)
        if commands.option_count == 0 or commands.highlighted is None:
            return None
        prompt = commands.get_option_at_index(commands.highlighted).prompt
        plain = getattr(prompt, "plain", str(prompt))
        return expect.lower() in plain.lower() and plain

    await wait_until(pilot, first_hit, f"a palette hit for {expect!r}")
    await press(pilot, "enter")
    await wait_until(pilot, lambda: not isinstance(pilot.app.screen, CommandPalette),
                     "the palette to close")


def screen_text(app: PlcHmiApp) -> str:
    """What the terminal shows now, as plain text (one line per row), for assertions."""
    width, height = app.size
    console = Console(width=width, height=height, file=io.StringIO(), force_terminal=True,
                      color_system=None, record=True, legacy_windows=False, safe_box=False)
    console.print(render_screen(app))
    return console.export_text()


def region_text(app: PlcHmiApp, selector: str) -> str:
    """The plain text inside one widget's region of the screen."""
    widget = app.query_one(selector)
    region = widget.region
    lines = screen_text(app).splitlines()
    return "\n".join(line[region.x:region.right]
                     for line in lines[region.y:region.bottom])

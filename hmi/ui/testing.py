"""Helpers for driving the app headless: bounded waits and virtual time, never bare sleeps.

Used by the pilot tests, the snapshot tests and the screenshot script, so that all three see
the same app in the same states. With a :class:`~hmi.ui.driver.VirtualDriver` nothing scans
unless the caller says so, hence every screen these helpers produce is exactly repeatable.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from textual.command import CommandInput, CommandList, CommandPalette
from textual.pilot import Pilot

from hmi.ui.app import PlcHmiApp
from hmi.ui.driver import VirtualDriver

DEFAULT_TIMEOUT = 5.0


class WaitTimeout(AssertionError):
    pass


async def settle(pilot: Pilot) -> None:
    """Hand the latest snapshot to the panels and let Textual process what is queued."""
    app = pilot.app
    assert isinstance(app, PlcHmiApp)
    app.poll(force=True)
    await pilot.pause()


async def wait_until(pilot: Pilot, predicate: Callable[[], Any], what: str = "condition",
                     timeout: float = DEFAULT_TIMEOUT) -> Any:
    """Let the app run until `predicate()` is truthy; fail after `timeout` wall seconds."""
    deadline = time.monotonic() + timeout
    while True:
        result = predicate()
        if result:
            return result
        if time.monotonic() > deadline:
            raise WaitTimeout(f"timed out after {timeout:g} s waiting for {what}")
        await pilot.pause(0.01)


async def wait_for_screen(pilot: Pilot, screen_type: type, timeout: float = DEFAULT_TIMEOUT):
    """Wait until the active screen is a `screen_type` and return it (mounted)."""
    screen = await wait_until(
        pilot, lambda: isinstance(pilot.app.screen, screen_type) and pilot.app.screen,
        f"a {screen_type.__name__}", timeout)
    await pilot.pause()
    return screen


async def wait_for_main(pilot: Pilot, timeout: float = DEFAULT_TIMEOUT) -> None:
    """Wait until every dialog is closed (the main screen is active again)."""
    app = pilot.app
    await wait_until(pilot, lambda: len(app.screen_stack) == 1, "the main screen", timeout)
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
    """Run virtual time until `predicate(snapshot)`; fail if `limit_s` virtual seconds pass."""
    if not driver(pilot).advance_until(predicate, int(limit_s * 1_000_000)):
        raise WaitTimeout(f"{what} did not happen within {limit_s:g} s of virtual time")
    await settle(pilot)


async def palette(pilot: Pilot, query: str, expect: str | None = None,
                  timeout: float = DEFAULT_TIMEOUT) -> None:
    """Open the command palette, type `query`, and run the first hit (checked by `expect`)."""
    await pilot.press("ctrl+p")
    screen = await wait_for_screen(pilot, CommandPalette, timeout)
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

    await wait_until(pilot, first_hit, f"a palette hit for {expect!r}", timeout)
    await pilot.press("enter")
    await wait_until(pilot, lambda: not isinstance(pilot.app.screen, CommandPalette),
                     "the palette to close", timeout)
    await pilot.pause()


def screen_text(app: PlcHmiApp) -> str:
    """What the terminal shows now, as plain text (one line per row), for assertions."""
    import io

    from rich.console import Console

    width, height = app.size
    console = Console(width=width, height=height, file=io.StringIO(), force_terminal=True,
                      color_system=None, record=True, legacy_windows=False, safe_box=False)
    console.print(app.screen._compositor.render_update(
        full=True, screen_stack=app._background_screens))
    return console.export_text()


def region_text(app: PlcHmiApp, selector: str) -> str:
    """The plain text inside one widget's region of the screen."""
    widget = app.query_one(selector)
    region = widget.region
    lines = screen_text(app).splitlines()
    return "\n".join(line[region.x:region.right]
                     for line in lines[region.y:region.bottom])

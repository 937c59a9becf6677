"""What an operator's dialogs leave behind: nothing that grows with their number.

A headless HMI at 80x24 in virtual time opens and closes the fault dialog and the command
palette, the screen rendered with each open (as a terminal would paint it), and the
objects still alive after a full collection are counted, not timed: after the first
cycles have filled every bounded cache, more cycles add nothing. The live figures (a real
terminal, a dialog every half second for minutes) are `plchmi bench live`'s."""

from __future__ import annotations

import gc
from collections import Counter

from textual._styles_cache import StylesCache
from textual.command import CommandPalette
from textual.strip import Strip
from textual.widget import Widget
from ui_harness import run_for, screen_text, wait_for_main

from hmi.ui.app import PlcHmiApp
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.headless import press, wait_for_screen
from tests.conftest import PROJECTS, make_session

WARM = 12  # cycles that fill the bounded caches (Textual's, rich's)
MEASURED = 24  # cycles after them: more than the ~20 widgets' StylesCaches one leaves


def alive() -> Counter[str]:
    gc.collect()
    return Counter(type(o).__qualname__ for o in gc.get_objects())


def styles_caches_without_widget() -> int:
    """StylesCaches alive that no live widget owns (each holds its widget's lines)."""
    gc.collect()
    objects = gc.get_objects()
    owned = {id(o._styles_cache) for o in objects if isinstance(o, Widget)}
    return sum(1 for o in objects if isinstance(o, StylesCache) and id(o) not in owned)


async def test_dialogs_opened_and_closed_leave_nothing_that_grows_with_their_number():
    app = PlcHmiApp(make_session(PROJECTS / "cispi_valve"), live=False,
                    show_measured=False)

    async def cycle() -> None:
        await press(app_pilot, "f")
        await wait_for_screen(app_pilot, FaultDialog)
        screen_text(app)  # (drawn as a terminal would: its widgets render their lines)
        await press(app_pilot, "escape")
        await wait_for_main(app_pilot)
        await press(app_pilot, "ctrl+p")
        await wait_for_screen(app_pilot, CommandPalette)
        screen_text(app)
        await press(app_pilot, "escape")
        await wait_for_main(app_pilot)
        await run_for(app_pilot, 0.5)
        screen_text(app)

    async with app.run_test(size=(80, 24)) as app_pilot:
        for _ in range(WARM):
            await cycle()
        before = alive()
        stray_before = styles_caches_without_widget()
        for _ in range(MEASURED):
            await cycle()
        after = alive()
        stray_after = styles_caches_without_widget()
    grew = {name: after[name] - before[name] for name in after
            if after[name] - before[name] > 0}
    # no widget's rendered lines outlive it
    assert stray_after == stray_before == 0, (stray_before, stray_after)
    # rendered lines are the bulk of what a kept dialog held: none more than the warm ones
    assert after[Strip.__qualname__] <= before[Strip.__qualname__] + 50, grew
    # and nothing else grows with the cycles (a few objects of Textual's bounded caches)
    assert sum(after.values()) - sum(before.values()) < 1_000, sorted(
        grew.items(), key=lambda kv: -kv[1])[:15]

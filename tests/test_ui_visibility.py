"""What must stay on screen whatever the operator opens: the status bar and the banners above
every dialog, the most urgent unacknowledged alarms in the alarm list and their count in the
status bar, the late-scan flag at every width.

Pilot tests in virtual time (a VirtualDriver: nothing scans unless the test runs time),
asserting on the text of the composed screen, at 80×24 and 160×48.
"""

from __future__ import annotations

import pytest
from textual.command import CommandPalette
from textual.screen import ModalScreen
from ui_harness import driver, region_text, run_for, run_until, screen_text
from ui_scenarios import VALVE, make_app

from hmi.engine.commands import InjectFault, StopDevice
from hmi.explain.alarms import ACTIVE_UNACK, CLEARED_UNACK
from hmi.project.injection import parse_injection
from hmi.timefmt import seconds
from hmi.ui.alarm_list import AlarmList, without_device
from hmi.ui.headless import press, wait_until

SIZES = [(80, 24), (160, 48)]


def top_lines(app, count: int) -> list[str]:
    return screen_text(app).splitlines()[:count]


async def open_comment(pilot) -> None:
    pilot.app.comment()


async def open_palette(pilot) -> None:
    await press(pilot, "ctrl+p")


async def open_fault(pilot) -> None:
    await press(pilot, "f")


async def open_reset(pilot) -> None:
    await press(pilot, "r")


async def open_policy(pilot) -> None:
    await press(pilot, "p")


async def open_step(pilot) -> None:
    await press(pilot, "n")


async def open_signals(pilot) -> None:
    await press(pilot, "g")


async def open_quit(pilot) -> None:
    await press(pilot, "q")


DIALOGS = [open_comment, open_palette, open_fault, open_reset, open_policy, open_step,
           open_signals, open_quit]


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("opener", DIALOGS, ids=lambda f: f.__name__[5:])
async def test_no_dialog_hides_the_status_bar_nor_the_banners(size, opener):
    """The comment dialog blanked the whole screen (status bar, banners, panels) while the
    cell ran on: a dialog's screen now lets the cell show through, and starts below the
    status bar and the banners (DEVICE STOPPED here, F13's alarm in the list)."""
    app = make_app(inject=("F13@2s",))
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 4)
        assert app.send(StopDevice("Valve V1")).accepted
        await run_for(pilot, 0.1)
        before = top_lines(app, 2)
        assert "AUTO" in before[0] and "DEVICE STOPPED" in before[1]
        await opener(pilot)
        await wait_until(pilot, lambda: isinstance(app.screen, ModalScreen),
                         "the dialog to open")
        await run_for(pilot, 0.1)  # the cell runs on under the dialog
        after = top_lines(app, 2)
        assert "AUTO" in after[0] and "DEVICE STOPPED" in after[1], \
            f"{type(app.screen).__name__} hides the top of the screen: {after}"
        if not isinstance(app.screen, CommandPalette):
            assert app.screen.styles.background.a < 1


# -- the most urgent alarms ------------------------------------------------------------------

SORTING = VALVE.parent / "sorting"


def urgent(app) -> list:
    alarms = app.link.last.alarms
    best = min(a.priority for a in alarms if a.state == ACTIVE_UNACK)
    return [a for a in alarms if a.state == ACTIVE_UNACK and a.priority == best]


def listed_rows(app) -> list[str]:
    return [line for line in region_text(app, "#alarms").splitlines() if "P" in line
            and ("UNACK" in line or "ACK" in line)]


def shows(rows: list[str], alarm) -> bool:
    """Whether one of the alarm list's rows is this alarm (its priority, time and the start of
    its text, with or without its device column)."""
    start = without_device(alarm.text, alarm.device)[:12]
    return any(f"P{alarm.priority}" in row and f"{seconds(alarm.raised_us)} s" in row
               and start in row for row in rows)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
async def test_new_p1_alarms_are_on_screen_above_an_older_selected_alarm(size):
    """The sorting cell's faulty program, everything acknowledged, then the turntable jams:
    three P1 alarms (LATCHED) sort above the acknowledged alarm the list had selected. They
    were out of sight (`↑ 5 more`) at both sizes; now they are on screen above the selection
    (which stays: what `a` acknowledges never changes by itself), and the status bar counts
    them."""
    app = make_app(SORTING, control="faulty")
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 20)
        await press(pilot, "A")
        await run_for(pilot, 0.5)
        assert app.send(InjectFault(parse_injection("table_jam@20.5s"))).accepted
        await run_until(pilot, lambda s: sum(a.priority == 1 and a.state == ACTIVE_UNACK
                                             for a in s.alarms) >= 3, 10, "three P1 alarms")
        await run_for(pilot, 1)
        top = urgent(app)
        assert len(top) >= 3 and top[0].priority == 1
        rows = listed_rows(app)
        hidden = [a.text for a in top if not shows(rows, a)]
        assert not hidden, f"P1 out of sight: {hidden}\n{region_text(app, '#alarms')}"
        assert any("› " in row for row in rows)  # and the selection
        status = top_lines(app, 1)[0]
        assert f"{len(top)} P1 unack" in status


@pytest.mark.parametrize("width", [60, 80, 100, 160])
async def test_the_urgent_count_and_the_late_flag_never_drop_from_the_status_bar(width):
    """`✗ 1 P1 unack…` and the late-scan flag stay in the status bar at every width (the
    late count was the first field dropped: a run that lost 12.5 % of real time showed
    `▶ run ×1`)."""
    app = make_app(inject=("F13@2s",))
    app.show_measured = True
    async with app.run_test(size=(width, 24)) as pilot:
        await run_for(pilot, 4)
        driver(pilot).overruns = 7
        await run_for(pilot, 0.1)
        status = top_lines(app, 1)[0]
        assert "1 P1 unack" in status and "7 " in status and "late" in status, status
        assert "AUTO" in status and "correct" in status, status


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
async def test_the_selection_stays_and_the_urgent_rows_are_pinned_above_it(size):
    """The operator's selection stays where they put it when new P1 alarms arrive; the most
    urgent rows are pinned above it (the list takes one row more for it)."""
    app = make_app(SORTING, control="faulty")
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 20)
        listing = app.query_one(AlarmList)
        listing.focus()
        await press(pilot, "end")  # the last row: one waiting for its acknowledgement
        chosen = listing.selected
        assert app.link.last.alarms[-1].state == CLEARED_UNACK
        assert app.send(InjectFault(parse_injection("table_jam@20.5s"))).accepted
        await run_until(pilot, lambda s: sum(a.priority == 1 and a.state == ACTIVE_UNACK
                                             for a in s.alarms) >= 3, 10, "three P1 alarms")
        await run_for(pilot, 1)
        assert listing.selected == chosen
        rows = listed_rows(app)
        assert any("› " in row for row in rows)
        top = urgent(app)
        seen = [a for a in top if shows(rows, a)]
        assert len(seen) == len(top) or len(seen) == len(rows) - 1, \
            region_text(app, "#alarms")

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
from ui_harness import driver, palette, region_text, run_for, run_until, screen_text
from ui_scenarios import VALVE, make_app

from hmi.engine.commands import InjectFault, StopDevice
from hmi.explain.alarms import ACTIVE_UNACK, CLEARED_UNACK
from hmi.history.historian import Historian
from hmi.history.target import Target
from hmi.project.injection import parse_injection
from hmi.timefmt import seconds
from hmi.ui.alarm_list import AlarmList, without_device
from hmi.ui.app import PlcHmiApp
from hmi.ui.headless import press, wait_until
from tests.conftest import make_session

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


async def open_trends(pilot) -> None:
    await press(pilot, "t")


@pytest.mark.parametrize("size", [(80, 24), (160, 54), (60, 24)],
                         ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("opener", [open_trends, open_fault, open_step],
                         ids=lambda f: f.__name__[5:])
async def test_a_banner_that_appears_under_an_open_dialog_stays_in_view(size, opener,
                                                                       tmp_path):
    """Manual mode asked, then a dialog (or the trend screen) opened before the next scan:
    the MANUAL banner appears with the dialog already open. The dialog was placed from the
    banners' last layout (none) and drew over the new banner on line 1 (the soak farm's
    seeds 68, 105, 143, 162 and 189); it now moves below the banner with the frame that
    shows it."""
    session = make_session(VALVE)
    historian = Historian(session, Target("sqlite", str(tmp_path / "h.sqlite")),
                          flush_s=0.05).attach()
    app = PlcHmiApp(session, live=False, show_measured=False)
    try:
        async with app.run_test(size=size) as pilot:
            await run_for(pilot, 1)
            assert "MANUAL" not in top_lines(app, 2)[1]
            await press(pilot, "m")
            await wait_until(pilot, lambda: isinstance(app.screen, ModalScreen),
                             "the manual dialog")
            await press(pilot, "y")
            await wait_until(pilot, lambda: not isinstance(app.screen, ModalScreen),
                             "the manual dialog to close")
            await opener(pilot)
            await wait_until(pilot, lambda: isinstance(app.screen, ModalScreen),
                             "the dialog to open")
            assert "MANUAL" not in top_lines(app, 2)[1]  # not scanned yet
            await run_for(pilot, 0.01)  # one scan: manual mode takes effect
            top = top_lines(app, 2)
            assert "MANUAL" in top[0] and "MANUAL / FORCES ACTIVE" in top[1], \
                f"{type(app.screen).__name__} hides the banner: {top}"
    finally:
        historian.close()


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


@pytest.mark.parametrize("width", [60, 64, 72, 80])
async def test_the_urgent_count_is_whole_when_the_fields_always_kept_are_too_wide(width):
    """In recovery, with the engineering view and nobody in control, the fields kept at
    every width were wider than 64 columns, and the crop cut the count to `✗ 1 P1 un…`.
    The engineering view, then who is in control, give way to the cell's state: the count
    is whole, and so are the mode, the policy and the run state."""
    app = make_app(inject=("F13@2s",))
    async with app.run_test(size=(width, 24)) as pilot:
        await press(pilot, "E")
        await run_for(pilot, 4)
        await palette(pilot, "Recovery: start", "Recovery: start")
        await press(pilot, "y")
        app.release_control()
        await run_for(pilot, 0.1)
        snap = app.link.last
        assert snap.snapshot.mode == "recovery" and app.frame.control.holder is None
        assert sum(a.priority == 1 and a.state == ACTIVE_UNACK for a in snap.alarms) == 1
        status = top_lines(app, 1)[0]
        for word in ("✗ 1 P1 unack", "▲ RECOVERY", "correct", "▶ run ×1"):
            assert word in status, status
        if width >= 80:  # room for all: nothing gives way
            assert "▲ nobody in control │ ▲ ENG │" in status, status


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


def test_every_screen_the_app_opens_is_a_dialog_kept_below_the_banners():
    """Every modal screen of the HMI is a Dialog: it is placed below the status bar and the
    banners (hmi.ui.dialogs.keep_clear) when it mounts and with every frame, and the soak's
    `dialog-hides-status-bar` checks every screen on the stack over the main one."""
    import importlib
    import pkgutil

    import hmi.ui
    from hmi.ui.dialogs import Dialog
    screens = []
    for info in pkgutil.iter_modules(hmi.ui.__path__):
        module = importlib.import_module(f"hmi.ui.{info.name}")
        screens += [value for value in vars(module).values()
                    if isinstance(value, type) and issubclass(value, ModalScreen)
                    and value.__module__ == module.__name__]
    assert len(screens) >= 10
    assert [s.__name__ for s in screens if not issubclass(s, Dialog)] == []


async def test_the_io_rows_the_selected_alarm_is_about_are_on_screen_at_80x24():
    """The sorting cell at 80x24 has room for three of its 19 I/O rows. Its faulty program's
    selected alarm ("turn refused, a box lies across the table's edge") is about the turn
    order ROT90 and the edge beam: the table showed tt_front, tt_0, tt_90. It now scrolls to
    the order the rule blocks (the rows around it as they fit), the cursor left alone."""
    app = make_app(SORTING, control="faulty")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 25)
        selected = app.query_one(AlarmList).selected
        assert selected is not None and selected.startswith("constraint:")
        rows = [line.split()[1] for line in region_text(app, "#io").splitlines()[2:-1]
                if len(line.split()) > 1]
        assert "ROT90" in rows, rows
        table = app.query_one("#io")
        assert table.cursor_row == len(app.link.last.snapshot.layout.inputs)  # where it starts

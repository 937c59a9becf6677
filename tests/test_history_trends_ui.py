"""The trend screen in the real app (virtual time, a real SQLite history, a real PostgreSQL one
for the blocked read): what it shows at 80×24, its keys, the status bar kept in view, no
history said plainly, and a read that hangs never holding the UI."""

from __future__ import annotations

import asyncio
import uuid
from datetime import UTC

import pytest

from hmi.engine.commands import InjectFault
from hmi.history.historian import Historian
from hmi.history.target import Target
from hmi.project.injection import Injection
from hmi.session.runio import open_journal
from hmi.ui.app import PlcHmiApp
from hmi.ui.headless import drain, press, wait_for_screen, wait_until
from hmi.ui.trend import column_end
from hmi.ui.trend_screen import TrendScreen, TrendSignalDialog
from tests.conftest import PROJECTS, make_session
from tests.ui_harness import palette, run_for, screen_text

EPOCH = 1_790_000_000_000_000  # 2026-09-21 14:13:20 UTC


def _app(target: Target | None, folder=None):
    session = make_session(PROJECTS / "cispi_valve")
    session.epoch_us = EPOCH
    journal = open_journal(session, folder / "journal.jsonl", "test") if folder else None
    historian = Historian(session, target, flush_s=0.05, journal=journal).attach() \
        if target else None
    app = PlcHmiApp(session, live=False, show_measured=False)
    app.trend_zone = UTC
    return app, session, historian


async def _trends(pilot) -> TrendScreen:
    await press(pilot, "t")
    screen = await wait_for_screen(pilot, TrendScreen)
    await wait_until(pilot, lambda: screen.up_to_date, "the first picture")
    return screen


async def test_trends_at_80x24(tmp_path):
    app, session, historian = _app(Target("sqlite", str(tmp_path / "h.sqlite")), tmp_path)
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 90)
        session.command(InjectFault(Injection("F13", session.engine.now)))
        await run_for(pilot, 40)
        assert historian.flush()
        screen = await _trends(pilot)
        text = screen_text(app).splitlines()
        assert text[0].startswith(" cispi_valve │")  # the cell's status stays in view
        assert "TRENDS" in text[1] and "15 min" in text[1] and "following now" in text[1]
        rows = {line.split()[0]: line for line in text[2:] if line.strip()}
        for name in ("C", "O", "fsc", "fso", "alarms"):
            assert name in rows, text
        assert "▲" in rows["alarms"]  # F13's alarm, on the time axis
        assert "·" in rows["fso"]  # before the cell started: nothing known, and said
        assert any("┊14:" in line for line in text)
        assert any(line.startswith("cursor 2026-09-21 14:") for line in text)
        # the cursor: one column left, the instant it reads moves back by a column
        before = next(line for line in text if line.startswith("cursor"))
        await press(pilot, "left")
        after = next(line for line in screen_text(app).splitlines() if line.startswith("cursor"))
        assert before != after
        # zoom in: 5 min, the cursor's instant kept within a column
        window = screen.chart.window
        instant = column_end(window, screen.chart.cursor)
        await press(pilot, "plus")
        await wait_until(pilot, lambda: screen.span_us == 5 * 60_000_000
                         and screen.chart.window.end_us - screen.chart.window.start_us
                         == screen.span_us, "the zoomed picture")
        zoomed = screen.chart.window
        slice_us = (zoomed.end_us - zoomed.start_us) // zoomed.width
        assert abs(column_end(zoomed, screen.chart.cursor) - instant) <= 2 * slice_us
        # earlier: no longer following; end: following again
        await press(pilot, "shift+left")
        await wait_until(pilot, lambda: not screen.following, "earlier")
        assert "following now" not in screen_text(app).splitlines()[1]
        await press(pilot, "end")
        await wait_until(pilot, lambda: screen.following, "now")
        # the signals: V1.state and O.travel added through the picker
        await press(pilot, "g")
        dialog = await wait_for_screen(pilot, TrendSignalDialog)
        names = [s.name for s in dialog.signals]
        for name in ("V1.state", "O.travel"):
            await press(pilot, *(["down"] * 0))
            dialog.query_one("#signals").highlighted = names.index(name)
            await press(pilot, "space")
        await press(pilot, "enter")
        await wait_until(pilot, lambda: "V1.state" in screen.signals and screen.chart.window
                         and any(d.signal.name == "O.travel" for d in screen.chart.window.drawn),
                         "the new signals drawn")
        shown = screen_text(app)
        assert "V1.state" in shown and "O.travel" in shown
        await press(pilot, "escape")
        await wait_until(pilot, lambda: len(app.screen_stack) == 1, "back to the cell")
        assert app.trends is None
    historian.close()


async def test_the_cell_goes_on_under_the_trends(tmp_path):
    app, session, historian = _app(Target("sqlite", str(tmp_path / "h.sqlite")))
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 30)
        historian.flush()
        screen = await _trends(pilot)
        end = screen.end_us
        await run_for(pilot, 30)  # following: the window moves with the cell
        historian.flush()
        await wait_until(pilot, lambda: screen.end_us >= end + 29_000_000, "the window moved")
        # app keys do not reach the cell through the trends: 'm' is not manual mode here
        await press(pilot, "m")
        assert session.last.snapshot.mode == "auto" and app.screen is screen
        # zoomed in on now (the cell a little past the picture, less than a column), it
        # stays on now and goes on following the cell
        await run_for(pilot, 0.5)
        assert screen.now_us > screen.end_us
        await press(pilot, "plus")
        await wait_until(pilot, lambda: screen.span_us == 5 * 60_000_000, "zoomed in")
        assert screen.following
        end = screen.end_us
        await run_for(pilot, 10)
        historian.flush()
        await wait_until(pilot, lambda: screen.end_us >= end + 4_000_000,
                         "the zoomed window moved")
    historian.close()


async def test_without_history_the_trends_say_so():
    app, _, _ = _app(None)
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 1)
        await press(pilot, "t")
        await drain(pilot)
        assert len(app.screen_stack) == 1
        assert "no history is kept for this session" in screen_text(app)


async def test_maintenance_from_the_palette(tmp_path):
    app, _, historian = _app(Target("sqlite", str(tmp_path / "h.sqlite")))
    async with app.run_test(size=(120, 36)) as pilot:
        await run_for(pilot, 60)
        historian.flush()
        await palette(pilot, "Trends: maintenance of Valve V1")
        screen = await wait_for_screen(pilot, TrendScreen)
        await wait_until(pilot, lambda: screen.up_to_date and screen.chart.window
                         and screen.chart.window.drawn, "the maintenance picture")
        assert screen.signals == ["O.travel", "O.operations", "C.travel", "C.operations"]
        assert screen.span_us == 60_000_000  # the whole history (a minute): the smallest zoom
        text = screen_text(app)
        assert "O.travel" in text and "1.9" in text  # ~1.92 s, read at the cursor
    historian.close()


@pytest.mark.xdist_group("postgres")
async def test_a_read_that_hangs_never_holds_the_ui(postgres):
    """The history's tables locked by another connection: the trend's read waits in its
    worker; the app meanwhile handles keys and frames, and the scans go on."""
    import psycopg
    url = postgres.database(f"hang_{uuid.uuid4().hex[:8]}")
    app, session, historian = _app(Target("postgresql", url))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 20)
        # the writer stopped first: its transactions take the same two tables' locks in
        # the other order (a deadlock the server breaks by failing the LOCK)
        historian.close()
        with psycopg.connect(url) as blocker:
            blocker.execute("LOCK TABLE plchmi_samples, plchmi_segments IN ACCESS EXCLUSIVE "
                            "MODE")
            await pilot.press("t")
            await pilot.pause()
            screen = app.screen
            assert isinstance(screen, TrendScreen)
            for _ in range(20):  # the worker is stuck in its query, the UI is not
                await asyncio.sleep(0.05)
                assert any(w.name == "trend" and w.is_running for w in app.workers)
            assert screen.reads == 0 and "reading" in str(
                screen.query_one("#trend-header").render())
            scan = session.engine.scan
            app.link.advance(2_000_000)  # the cell scans on; the frame shows it
            app.poll(force=True)
            assert session.engine.scan > scan and app.frame.snapshot.scan > scan
            await pilot.press("escape")
            await pilot.pause()
            assert len(app.screen_stack) == 1  # closed while its read still waits
            blocker.rollback()  # the lock goes: the read ends, its picture is dropped
        await wait_until(pilot, lambda: not any(w.is_running for w in app.workers),
                         "the worker to end")
        assert screen.reads == 0


async def test_on_now_the_cursor_reads_the_newest_history(tmp_path):
    """The history lags the cell (the writer commits every second; here it stopped 40 s
    ago): on now, the cursor sits on the newest column the history covers and reads its
    values, not "?" for every signal."""
    app, _, historian = _app(Target("sqlite", str(tmp_path / "h.sqlite")))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 60)
        historian.close()
        await run_for(pilot, 40)  # more than a column (15 s) past the history's end
        screen = await _trends(pilot)
        window = screen.chart.window
        cursor = screen.chart.cursor
        assert cursor < window.width - 1
        assert all(d.columns[cursor].known for d in window.drawn)
        assert not any(d.columns[cursor + 1].known for d in window.drawn)
        rows = {line.split()[0]: line.split()[1] for line in screen_text(app).splitlines()[2:]
                if line.strip() and "│" in line}
        for name in ("C", "O", "fsc", "fso"):
            assert rows[name] in ("0", "1"), rows

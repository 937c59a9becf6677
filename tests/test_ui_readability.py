"""Readable at 80x24 and 160x48, the small defects: monitor bounds in seconds, the
chronogram's mark explained and its names whole when wide, the I/O descriptions without a
device name every row repeats."""

from __future__ import annotations

from tests.conftest import PROJECTS


def test_monitor_bounds_are_seconds_not_a_unit_glued_to_s():
    """The palletizer's 200 ms bounds read `0.2 s`, never `200m s`."""
    from hmi.engine.monitors import MonitorState
    from hmi.ui.monitors_panel import plain_monitor_lines, x_text, y_text

    m = MonitorState("push", "push_fault", "Pusher pushing", "Pusher", "executing", 30_000,
                     30_000, 100_000, 200_000, 300_000, 1, 0, True, None, None, None, 0, 0,
                     "executing")
    for text in (x_text(m).plain, y_text(m).plain,
                 *(line.plain for line in plain_monitor_lines(m, 80, 2))):
        assert "m s" not in text and "ms s" not in text, text
    assert "0.03/0.3 s" in x_text(m).plain and "[0.1, 0.2]" in y_text(m).plain


async def test_the_chronogram_says_what_its_mark_means_and_keeps_whole_names_when_wide():
    from ui_harness import region_text, run_until
    from ui_scenarios import make_app

    app = make_app(control="faulty")
    async with app.run_test(size=(160, 48)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.filter_report is not None
                        and bool(s.snapshot.filter_report.changes), 10, "a filter correction")
        await run_until(pilot, lambda s: True, 0.05, "a frame")
        chrono = region_text(app, "#chronogram")
        assert "≠" in chrono and "≠: the filter changed it" in chrono
    from hmi.ui.chronogram import Chronogram
    app = make_app(PROJECTS / "palletizer")
    async with app.run_test(size=(160, 48)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.scan > 2, 1, "a few scans")
        chrono = app.query_one(Chronogram)
        rows = [line.strip("│ ").split() for line in
                region_text(app, "#chronogram").splitlines()[1:-2]]
        labels = [row[0] for row in rows if row and not row[0].startswith("+")]
        assert labels and any(len(label) > 8 for label in labels), labels
        assert all(label in chrono.signals for label in labels), labels  # none cut


async def test_the_io_descriptions_do_not_repeat_the_one_device_on_every_row():
    from ui_harness import region_text, run_for
    from ui_scenarios import make_app

    app = make_app()
    async with app.run_test(size=(160, 48)) as pilot:
        await run_for(pilot, 0.1)
        rows = region_text(app, "#io").splitlines()
        fsc = next(line for line in rows if line.startswith("│ fsc "))
        assert "closed end switch" in fsc and "Valve V1" not in fsc
        assert any("C: Valve V1 close order" in line for line in rows)  # the border: whole


async def test_the_policy_dialog_marks_the_current_policy_whole_and_its_list_stops_at_its_ends():
    """At 80×24 the current policy's marker came last and was cut ("(…"), and ↓ on the last
    policy jumped back to the first."""
    from ui_harness import run_for, screen_text
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ChoiceDialog
    from hmi.ui.headless import press, settle, wait_for_screen

    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        await press(pilot, "p")
        dialog = await wait_for_screen(pilot, ChoiceDialog)
        await settle(pilot)
        rows = [line for line in screen_text(app).splitlines()[1:]  # (the status bar's)
                if any(f" {p} " in line for p in ("monitor", "block", "correct"))]
        assert len(rows) == 3, rows  # one line each, no wrapped help
        assert any("● correct  now" in row for row in rows), rows
        options = dialog.query_one("#choices")
        assert options.highlighted == 2  # correct, the last
        await press(pilot, "down")
        assert options.highlighted == 2
        await press(pilot, "home", "up")
        assert options.highlighted == 0


async def test_the_palette_screenshot_says_where_it_saved_or_why_not(tmp_path, monkeypatch):
    """Textual's own entry saved to ~/Downloads, failed without a word when it was missing,
    and its SVGs ran coloured words together in viewers that drop a run's first spaces."""
    from ui_harness import palette, run_for
    from ui_scenarios import make_app

    monkeypatch.chdir(tmp_path)
    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        await palette(pilot, "Screenshot")
        (svg,) = tmp_path.glob("plchmi_cispi_valve_*.svg")
        assert f"screenshot: {svg}" in app.message.plain
        assert '<svg xml:space="preserve" ' in svg.read_text(encoding="utf-8")
        gone = tmp_path / "gone"
        gone.mkdir()
        monkeypatch.chdir(gone)
        gone.rmdir()
        await palette(pilot, "Screenshot")
        assert "NOT AVAILABLE" in app.message.plain and "not written" in app.message.plain
        assert "No such file or directory" in app.message.plain


async def test_a_long_state_never_pushes_the_io_descriptions_off_a_wide_screen():
    """Safe blocking at 160×48: the outputs' reason ("≠ held safe: a safety rule was broken —
    …") widened the State column for good and the Description column was gone."""
    from ui_harness import region_text, run_until
    from ui_scenarios import make_app

    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=(160, 48)) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 20, "safe blocking")
        await run_until(pilot, lambda s: True, 0.1, "a frame")
        io = region_text(app, "#io")
        assert "≠ held safe" in io
        for description in ("closed end switch", "open end switch", "close order",
                            "open order"):
            assert description in io, io


async def test_a_step_description_cut_to_fit_says_so():
    """At 80×24 the faulty valve's "Closing for a fixed 3 s, open order still on at first"
    read "Closing for a fixed 3 s," — a sentence that says something else."""
    from ui_harness import region_text, run_until
    from ui_scenarios import make_app

    app = make_app(control="faulty")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_until(pilot, lambda s: "X3" in s.snapshot.active_steps, 12, "closing")
        await run_until(pilot, lambda s: True, 0.05, "a frame")
        line = next(line for line in region_text(app, "#control").splitlines()
                    if "Closing for a fixed" in line)
        assert "…" in line and "3 s, " not in line.replace("…", ""), line

"""Pilot tests of the operator HMI: press the keys, then check the engine and the screen.

Every test runs the app on a VirtualDriver: no scan happens unless the test runs virtual
time, so what the screen shows is exactly repeatable. Waits are bounded (hmi.ui.headless).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from textual.command import CommandPalette
from ui_harness import (
    not_violating,
    palette,
    region_text,
    run_for,
    run_until,
    screen_text,
    violating,
    wait_for_main,
    wait_live,
)
from ui_scenarios import CONVEYOR, VALVE, make_app, select_row

from hmi.engine.commands import Pause, SetMode
from hmi.ui.actions import ACTIONS
from hmi.ui.app import PlcHmiApp
from hmi.ui.chronogram import Chronogram
from hmi.ui.dialogs import ChoiceDialog, ConfirmDialog, StepDialog
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.headless import WaitTimeout, drain, press, settle, wait_for_screen, wait_until
from hmi.ui.io_panel import IOPanel
from hmi.ui.signal_dialog import SignalDialog

SIZE = (100, 30)


def real_plant_app() -> PlcHmiApp:
    """An app on the simulated valve declaring itself a real plant (as a Modbus plant
    does) before the HMI reads what its plant can do."""
    session = make_app().link.session
    session.engine.plant.is_real = True
    return PlcHmiApp(session, live=False, show_measured=False)


def engine(app: PlcHmiApp):
    return app.link.session.engine


@pytest.fixture
def button_project(tmp_path: Path) -> Path:
    """The valve with a start push button that no simulated device drives."""
    folder = tmp_path / "valve_button"
    shutil.copytree(VALVE, folder)
    project = folder / "project.yaml"
    project.write_text(project.read_text().replace(
        "inputs:\n", "inputs:\n  start:\n    description: Start push button\n", 1))
    control = folder / "control.yaml"
    control.write_text(control.read_text().replace(
        "when: fsc_filter and X0.t >= 1s", "when: fsc_filter and X0.t >= 1s and start", 1))
    return folder


# -- the display ---------------------------------------------------------------------------


async def test_the_valve_is_seen_cycling():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, lambda s: "X2" in s.snapshot.active_steps, 10, "the valve open")
        snap = app.link.session.last
        assert snap.snapshot.value("fso") is True
        status = region_text(app, "#status")
        assert f"scan {snap.snapshot.scan}" in status and "AUTO" in status and "running" in status
        io = region_text(app, "#io")
        assert any(line.split()[1:2] == ["fso"] and " 1 " in line for line in io.splitlines())
        control = region_text(app, "#control")
        assert "● Open, filling" in control and "○ Opening" in control
        assert "X2" not in control  # the step names are the engineering view's
        await press(pilot, "E")
        await run_for(pilot, 0.01)
        control = region_text(app, "#control")
        assert "● X2" in control and "○ X1" in control
        # A whole cycle later the chronogram holds both edges of the open order.
        await run_until(pilot, lambda s: bool(s.snapshot.plant_counters)
                        and dict(s.snapshot.plant_counters)["cycles"] >= 1, 20, "a full cycle")
        chrono = region_text(app, "#chronogram")
        o_row = next(line for line in chrono.splitlines() if line.strip("│ ").startswith("O "))
        assert "▐" in o_row and "█" in o_row and "▌" in o_row and "▁" in o_row
        assert "cycles 1" in region_text(app, "#sim")


async def test_headless_virtual_time_paints_only_what_someone_looks_at(monkeypatch):
    """hmi.ui.driver: a headless screen in virtual time is laid out at rest, not painted
    (a headless terminal throws paints away); a look renders what is there now, and
    VirtualDriver.paint paints what changed since the last paint, once."""
    from textual._compositor import Compositor

    paints = []
    render_update = Compositor.render_update

    def counted(self, full=False, screen_stack=None, simplify=False):
        paints.append(full)
        return render_update(self, full, screen_stack, simplify)
    monkeypatch.setattr(Compositor, "render_update", counted)
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 1.0)
        await press(pilot, "ctrl+p")
        await wait_for_screen(pilot, CommandPalette)
        await press(pilot, "escape")
        await wait_for_main(pilot)
        await press(pilot, "space")
        assert paints == []
        assert "PAUSED" in region_text(app, "#status")  # the look draws the state of now
        assert paints == [True]
        await press(pilot, "space")
        assert app.driver.paint(app) and paints == [True, False]  # what changed, once
        assert not app.driver.paint(app) and paints == [True, False]


async def test_frames_follow_the_engine_without_extra_scans():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 1.0)
        scans = engine(app).scan
        shown = app.frames_shown
        assert app.poll() is False  # nothing new: nothing handed down
        assert app.frames_shown == shown
        assert engine(app).scan == scans  # the UI never scans by itself


async def test_the_footer_forgets_the_keys_it_removed():
    """Textual's footer keys each watch the footer (data_bind); the footer recomposes at
    every change of the bindings (the focus moving, a dialog) and, unless it forgets them,
    keeps every key it ever showed alive: memory grew without end in a soak."""
    from textual.widgets._footer import FooterKey

    from hmi.ui.footer import HmiFooter

    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.1)
        footer = app.query_one(HmiFooter)
        shown = []
        for _ in range(2):  # in and out of manual mode: the manual keys come and go
            await enter_manual(pilot)
            await run_for(pilot, 0.01)
            shown.append(id(footer.query(FooterKey).first()))
            await enter_manual(pilot)  # m again, confirmed: back to auto
            await run_for(pilot, 0.01)
            shown.append(id(footer.query(FooterKey).first()))
        assert engine(app).mode == "auto"
        assert len(set(shown)) > 3  # it did recompose
        keys = len(footer.query(FooterKey))
        watchers = getattr(footer, "__watchers")
        assert watchers and all(len(entries) <= keys for entries in watchers.values()), \
            {name: len(entries) for name, entries in watchers.items()}


async def test_the_footer_recomposes_once_for_the_changes_of_one_refresh(monkeypatch):
    """The bindings change several times before the first frame (the start, the focus
    given to the I/O table, the first snapshot shown): one recompose per refresh, with the
    bindings as they are then, not one per change (4 before the first frame, each
    building and styling every key again), and none when the keys would be those shown
    (the second refresh's); each key is compact (the footer's setting) from birth instead
    of being restyled once mounted. The focus moving between panels with the same keys
    builds nothing, nor does a dialog opening over the screen and closing; manual mode,
    whose keys join, does."""
    from textual.widgets._footer import FooterKey

    from hmi.ui.footer import HmiFooter

    focused = []
    recompose = HmiFooter.recompose

    async def counted(self) -> None:
        focused.append(self.screen.focused)
        await recompose(self)
    monkeypatch.setattr(HmiFooter, "recompose", counted)
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.1)
        assert len(focused) == 1, focused
        footer = app.query_one(HmiFooter)
        keys = list(footer.query(FooterKey))
        await press(pilot, "tab")  # the focus moves to the alarm list: the same keys
        assert len(focused) == 1 and list(footer.query(FooterKey)) == keys
        await press(pilot, "m")  # a dialog over the screen: its keys stay under the shade
        await wait_for_screen(pilot, ConfirmDialog)
        assert len(focused) == 1 and list(footer.query(FooterKey)) == keys
        await press(pilot, "escape")
        await wait_for_main(pilot)
        assert len(focused) == 1
        await enter_manual(pilot)
        await run_for(pilot, 0.01)  # the manual keys join: one recompose
        assert len(focused) == 2 and focused[-1] is app.screen.focused
        keys = list(footer.query(FooterKey))
        assert keys and all(key.compact and key.has_class("-compact") for key in keys)
        assert "Run/Pause" in region_text(app, "HmiFooter")


@pytest.mark.parametrize("size", [(80, 24), (160, 48)])
async def test_layout_keeps_status_footer_and_panels_on_screen(size):
    app = make_app()
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 5.0)
        screen = app.screen.region
        for selector in ("#status", "#io", "#control", "#chronogram", "#sim", "#message",
                         "HmiFooter"):
            region = app.query_one(selector).region
            assert region.area > 0, selector
            assert screen.contains_region(region), selector
        await wait_until(pilot, lambda: "Run/Pause" in "\n".join(
            screen_text(app).splitlines()[-2:]), "the footer laid out")
        text = screen_text(app).splitlines()
        assert "AUTO" in text[0]
        assert "Run/Pause" in "\n".join(text[-2:])
        # every operator key is visible in the footer, even at 80 columns
        footer = "\n".join(text[-2:])
        for action in ACTIONS:
            assert (action.label in footer) == action.footer, action.label
        io = region_text(app, "#io")
        if size[0] >= 160:
            assert "Valve V1 close order" in io  # room for the descriptions
            assert "cispi_valve" in text[0]


# -- run / pause / step / speed ------------------------------------------------------------


async def test_pause_and_resume_then_step_one_scan():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.5)
        await press(pilot, "space")
        await settle(pilot)
        assert app.link.session.state.running is False
        assert "PAUSED" in region_text(app, "#status")
        scan = engine(app).scan
        assert await run_for(pilot, 2.0) == 0
        assert engine(app).scan == scan
        await press(pilot, "space")
        await settle(pilot)
        assert app.link.session.state.running is True
        assert await run_for(pilot, 1.0) == 100
        assert "running" in region_text(app, "#status")
        # one scan stepped (one start for both), from running
        await run_for(pilot, 0.5)
        scan = engine(app).scan
        await press(pilot, "s")
        await settle(pilot)
        assert engine(app).scan == scan + 1
        assert app.link.session.state.running is False
        assert "STEPPING" in region_text(app, "#status")
        assert f"scan {scan + 1}" in region_text(app, "#status")
        assert "stepped 1 scan" in app.message.plain
        await press(pilot, "space")  # run again: no longer stepping
        await settle(pilot)
        assert "running" in region_text(app, "#status")


async def test_step_n_can_be_cancelled_then_scans_through_the_dialog():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        scan = engine(app).scan
        await press(pilot, "n")
        await wait_for_screen(pilot, StepDialog)
        await press(pilot, "escape")  # cancelled: nothing stepped, still running
        await wait_for_main(pilot)
        assert engine(app).scan == scan
        assert app.link.session.state.running is True
        await press(pilot, "n")  # then (one start for both) 25 scans asked
        dialog = await wait_for_screen(pilot, StepDialog)
        await press(pilot, "0", "enter")  # replaces the selected default: refused
        await drain(pilot)
        assert isinstance(app.screen, StepDialog)
        assert "from 1 to" in str(dialog.query_one("#error").render())
        await press(pilot, "backspace", "2", "5", "enter")
        await wait_for_main(pilot)
        assert engine(app).scan == scan + 25
        assert "STEPPING" in region_text(app, "#status")


async def test_speed_cycles_real_time_ten_times_max():
    app = make_app()
    async with app.run_test(size=(120, 30)) as pilot:
        seen = []
        for _ in range(3):
            await press(pilot, "v")
            await settle(pilot)
            seen.append((app.link.session.state.speed, region_text(app, "#status")))
        assert [s for s, _ in seen] == [10.0, None, 1.0]
        assert "×10" in seen[0][1] and "max" in seen[1][1] and "×1" in seen[2][1]


# -- manual mode ---------------------------------------------------------------------------


async def enter_manual(pilot) -> None:
    await press(pilot, "m")
    await wait_for_screen(pilot, ConfirmDialog)
    await press(pilot, "y")
    await wait_for_main(pilot)


async def test_manual_mode_needs_confirmation():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "m")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        assert "still goes through the safety filter" in screen_text(app)
        await press(pilot, "s")  # app keys are off while a dialog is open
        await press(pilot, "n")
        await wait_for_main(pilot)
        assert dialog.is_attached is False
        assert engine(app).mode == "auto"
        assert engine(app).scan == 1
        assert "cancelled" in app.message.plain


async def test_manual_request_is_written_and_shown():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.5)  # closed, waiting: X0
        await enter_manual(pilot)
        assert engine(app).mode == "manual"
        await run_for(pilot, 0.1)
        assert "MANUAL / FORCES ACTIVE" in region_text(app, "#banners")
        assert "MANUAL" in region_text(app, "#status")
        await select_row(pilot, "O")
        await press(pilot, "1")
        await settle(pilot)
        assert engine(app).manual == {"O": True}
        assert "O requested on" in app.message.plain  # the answer comes at once
        await run_for(pilot, 0.05)
        assert "written 1" in app.message.plain
        assert app.link.session.last.snapshot.output_map["O"] is True
        assert "forced 1" in region_text(app, "#io")
        assert "O=1" in region_text(app, "#banners")
        await run_for(pilot, 2.5)
        # the valve opened under the force
        assert app.link.session.last.snapshot.value("fso") is True
        await press(pilot, "x")
        await settle(pilot)
        assert engine(app).manual == {}
        await run_for(pilot, 0.05)
        assert app.link.session.last.snapshot.output_map["O"] is False


async def test_manual_request_on_an_input_is_refused_with_its_reason():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await enter_manual(pilot)
        await select_row(pilot, "fsc")
        await press(pilot, "1")
        await settle(pilot)
        assert "REFUSED" in app.message.plain and "not an output" in app.message.plain
        assert engine(app).manual == {}


async def test_manual_keys_are_hidden_outside_manual_mode():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await select_row(pilot, "O")
        await press(pilot, "1")
        await settle(pilot)
        assert engine(app).manual == {}
        footer = "\n".join(screen_text(app).splitlines()[-2:])
        assert "Release" not in footer
        await enter_manual(pilot)
        await run_for(pilot, 0.01)
        footer = "\n".join(screen_text(app).splitlines()[-2:])
        assert "Release" in footer and "On" in footer


async def test_in_manual_mode_the_control_panel_and_the_dialogs_say_the_program_waits():
    """conveyor_robot in X2 + X11 (the robot transferring under G): the enter-manual dialog
    names the steps the program waits at, the control panel says it waits (from the command
    on, before a scan shows manual mode), and the leave-manual dialog names the steps it
    resumes from and the order they give again."""
    app = make_app(CONVEYOR)
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 1.0)
        assert app.link.session.last.snapshot.active_steps == ("X2", "X11")
        assert "waiting" not in region_text(app, "#control")
        await press(pilot, "m")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        said = " ".join(map(str, dialog.lines))
        assert ("The control program waits at the steps it is in when you confirm (when "
                "this opened, at 1.000 s: “Conveyor carries the pallet to B”, “Robot "
                "transfers the pallet to the assembly station”): no step changes, and its "
                "step times and memories hold until you leave manual mode; it then resumes "
                "from there."
                ) in said
        assert "The control program waits at the steps it is in when you" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert "▲ waiting — manual mode: resumes from here" in region_text(app, "#control")
        await run_for(pilot, 5)
        control = region_text(app, "#control")
        assert "▲ waiting — manual mode" in control
        assert "● Conveyor carries the pallet to B" in control
        assert "● Robot transfers the pallet" in control
        assert app.link.session.last.snapshot.active_steps == ("X2", "X11")
        await press(pilot, "m")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        said = " ".join(map(str, dialog.lines))
        assert ("The program resumes from “Conveyor carries the pallet to B”, “Robot "
                "transfers the pallet to the assembly station”, its step times going on from "
                "where they stopped, and drives the outputs again.") in said
        assert "These steps order G again at the next scan." in said
        assert "The program resumes from “Conveyor" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert "the control program resumes from “Conveyor carries the pallet to B”, “Robot" \
            in app.message.plain
        assert "waiting" not in region_text(app, "#control")  # (commanded: resumes)
        await run_for(pilot, 0.05)
        assert "waiting" not in region_text(app, "#control")
        assert app.link.session.last.snapshot.active_steps == ("X3", "X11")


async def test_a_request_not_written_as_asked_says_why():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await enter_manual(pilot)
        # An internal error latches the outputs safe (as the engine does on an exception).
        engine(app).latch_safe("internal", "test latch")
        await run_for(pilot, 0.01)
        assert "OUTPUTS HELD IN SAFE STATE" in region_text(app, "#banners")
        await select_row(pilot, "O")
        await press(pilot, "1")
        await run_for(pilot, 0.01)
        message = app.message.plain
        assert "NOT AS REQUESTED" in message and "written 0" in message
        assert "held safe: internal error" in message
        io = region_text(app, "#io")
        assert "≠ held safe" in io  # FOV 1, written 0, with the reason


async def test_leaving_manual_releases_every_output():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await enter_manual(pilot)
        await select_row(pilot, "O")
        await press(pilot, "1")
        await select_row(pilot, "C")
        await press(pilot, "0")
        await run_for(pilot, 0.1)
        assert engine(app).manual == {"O": True, "C": False}
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "O=1" in screen_text(app)  # the dialog lists what is released
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).mode == "auto" and engine(app).manual == {}
        assert "released C, O" in app.message.plain
        await run_for(pilot, 0.05)
        assert not app.query_one("#banners").display


# -- fault reset, policy, fault injection, push buttons -----------------------------------


async def test_fault_reset_lists_what_it_resets_and_releases_the_latch():
    app = make_app()
    async with app.run_test(size=(120, 30)) as pilot:
        await run_for(pilot, 0.5)
        engine(app).latch_safe("internal", "simulated internal error")
        await run_for(pilot, 0.1)
        assert "SAFE STATE" in region_text(app, "#status")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "will be reset: outputs held safe: internal error" in text
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).latched == []
        assert "released: outputs held safe: internal error" in app.message.plain
        await run_for(pilot, 0.1)
        assert "SAFE STATE" not in region_text(app, "#status")


async def test_fault_reset_cancelled_keeps_the_latch():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        engine(app).latch_safe("internal", "x")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "escape")
        await wait_for_main(pilot)
        assert len(engine(app).latched) == 1


async def test_fault_reset_with_nothing_latched_says_so():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "Nothing is latched" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert "nothing was latched" in app.message.plain


async def test_policy_switch_is_confirmed():
    app = make_app()
    async with app.run_test(size=(120, 30)) as pilot:
        await press(pilot, "p")
        await wait_for_screen(pilot, ChoiceDialog)
        await press(pilot, "up", "enter")  # correct is highlighted; up is block
        await wait_for_screen(pilot, ConfirmDialog)
        assert "correct → block" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).policy == "block"
        await run_for(pilot, 0.01)
        assert "filter block" in region_text(app, "#status")
        # monitor is marked abnormal on the status bar
        await press(pilot, "p")
        await wait_for_screen(pilot, ChoiceDialog)
        await press(pilot, "home", "enter")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "Unsafe orders will reach the plant" in screen_text(app)
        await press(pilot, "n")
        await wait_for_main(pilot)
        assert engine(app).policy == "block"
        # the policy already in effect: nothing to confirm, nothing sent nor journalled
        sent = []
        app.link.session.listeners.append(lambda cmd, result, snap: sent.append(cmd))
        await press(pilot, "p")
        await wait_for_screen(pilot, ChoiceDialog)
        await press(pilot, "enter")  # the highlighted one is the current one, block
        await wait_for_main(pilot)
        assert len(app.screen_stack) == 1 and not sent
        assert "already block — nothing changed" in app.message.plain
        assert engine(app).policy == "block"


async def test_fault_injection_now_jams_the_valve():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await run_until(pilot, lambda s: "X1" in s.snapshot.active_steps, 5, "opening")
        await run_for(pilot, 0.5)
        await press(pilot, "f")
        await wait_for_screen(pilot, FaultDialog)
        assert "SIMULATION" in screen_text(app)
        await press(pilot, "end", "enter", "enter")
        await wait_for_main(pilot)
        assert "valve blocked between fsc and fso" in app.message.plain
        assert "SIMULATION" in app.message.plain
        await run_for(pilot, 3.0)
        snap = app.link.session.last
        assert dict(snap.snapshot.plant_state)["jammed"] is True
        # {F3, F13} masks the valve; fso is read from its estimate, which says "open" once
        # the open order was held a full travel (2.45 s): the program goes on, masked.
        assert snap.snapshot.diagnosers[0].labels == ("F3", "F13")
        assert snap.snapshot.masked == ("C", "O")
        sim = region_text(app, "#sim")
        assert "SIMULATION" in sim and "JAMMED" in sim and "blocked between fsc and fso" in sim
        assert "damage" in sim  # the motor stalled against the jam


async def test_fault_injection_later():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await press(pilot, "f")
        dialog = await wait_for_screen(pilot, FaultDialog)
        await press(pilot, "enter")  # the first fault: F1
        await drain(pilot)
        assert dialog.query_one("#delay").has_focus
        await press(pilot, "backspace", "2", "enter")
        await wait_for_main(pilot)
        assert "stuck at 0 in 2.000 s" in region_text(app, "#sim")
        await run_for(pilot, 2.1)
        assert "stuck at 0 since 2.000 s" in region_text(app, "#sim")


async def test_fault_delay_counts_from_the_confirmation():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await press(pilot, "f")
        dialog = await wait_for_screen(pilot, FaultDialog)
        await press(pilot, "enter")  # F1; the delay field has the focus
        await run_for(pilot, 5.0)  # the operator takes 5 s to type the delay
        confirmed_at = engine(app).now
        assert confirmed_at >= 4_900_000
        await press(pilot, "backspace", "3", "enter")
        await wait_for_main(pilot)
        assert dialog.is_attached is False
        (fault,) = app._injected
        assert fault.injection.at_us == confirmed_at + 3_000_000
        await run_for(pilot, 2.9)
        assert "stuck at 0 in" in region_text(app, "#sim")  # not yet: 3 s after confirming
        await run_for(pilot, 0.2)
        assert "stuck at 0 since" in region_text(app, "#sim")


async def test_fault_dialog_rejects_a_bad_delay():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await press(pilot, "f")
        dialog = await wait_for_screen(pilot, FaultDialog)
        await press(pilot, "enter", "backspace", "s", "o", "o", "n", "enter")
        await drain(pilot)
        assert isinstance(app.screen, FaultDialog)
        assert "delay" in str(dialog.query_one("#error").render())


async def test_push_button_for_a_free_input(button_project):
    app = make_app(button_project)
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 2.0)
        assert app.link.session.last.snapshot.active_steps == ("X0",)  # waits for the button
        assert "button up" in region_text(app, "#io")
        await select_row(pilot, "start")
        await press(pilot, "b")
        await run_for(pilot, 0.05)
        assert app.link.session.last.snapshot.value("start") is True
        assert "button pressed" in region_text(app, "#io")
        assert "X1" in app.link.session.last.snapshot.active_steps
        await press(pilot, "b")
        await run_for(pilot, 0.05)
        assert app.link.session.last.snapshot.value("start") is False


async def test_push_button_on_a_driven_input_is_refused(button_project):
    app = make_app(button_project)
    async with app.run_test(size=SIZE) as pilot:
        await select_row(pilot, "fsc")
        await press(pilot, "b")
        await settle(pilot)
        assert "REFUSED" in app.message.plain and "driven by the simulated plant" in \
            app.message.plain


# -- chronogram ----------------------------------------------------------------------------


async def test_choose_chronogram_signals_with_the_key():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        before = app.query_one(Chronogram).signals
        assert before == ("C", "O", "fsc", "fso")  # the timers: in the engineering view
        await press(pilot, "g")
        await wait_for_screen(pilot, SignalDialog)
        await press(pilot, "space")  # untick the first (C)
        await press(pilot, "end", "space")  # tick the last (O.fov)
        await press(pilot, "enter")
        await wait_for_main(pilot)
        after = app.query_one(Chronogram).signals
        assert "C" not in after and "O.fov" in after
        assert "O fov" in region_text(app, "#chronogram")


async def test_chronogram_window_key():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "w")
        await settle(pilot)
        assert app.query_one(Chronogram).window_us == 30_000_000
        assert "last 30 s" in region_text(app, "#chronogram")


# -- the command palette -------------------------------------------------------------------


async def test_every_binding_has_a_palette_entry(button_project):
    app = make_app(button_project)
    async with app.run_test(size=SIZE) as pilot:
        app.send(SetMode(True))
        await run_for(pilot, 0.01)
        covered = {e.action for e in app.palette_entries() if e.action}
        keys = {b.action for b in PlcHmiApp.BINDINGS} | {b.action for b in IOPanel.BINDINGS}
        assert keys <= covered, keys - covered


async def test_palette_runs_commands():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await palette(pilot, "Run / pause")
        assert app.link.session.state.running is False
        await palette(pilot, "Step 10 scans")
        assert engine(app).scan == 11
        await palette(pilot, "Filter policy: monitor")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).policy == "monitor"
        await press(pilot, "s")
        await settle(pilot)
        assert "▲ filter monitor" in region_text(app, "#status")
        await palette(pilot, "Chronogram: show X1")
        assert "X1" in app.query_one(Chronogram).signals
        await palette(pilot, "SIMULATION: inject now: Valve stuck at the closed position",
                      "stuck at the closed")
        assert any(f.injection.code == "F5" for f in app.frame.injected)
        await palette(pilot, "SIMULATION: repair the faulty devices")
        assert not app._injected and "stuck at the closed position removed" in \
            region_text(app, "#message")
        await palette(pilot, "Run speed: as fast as possible")
        assert app.link.session.state.speed is None


async def test_palette_manual_requests_only_in_manual_mode():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        assert not any(e.title.startswith("Manual:") for e in app.palette_entries())
        await enter_manual(pilot)
        await palette(pilot, "Manual: O on")
        assert engine(app).manual == {"O": True}


async def test_palette_closes_without_running_anything():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "ctrl+p")
        await wait_for_screen(pilot, CommandPalette)
        await press(pilot, "escape")
        await wait_for_main(pilot)
        assert app.link.session.state.running is True


# -- every action goes through Session.command -----------------------------------------


async def test_operator_actions_reach_the_session_listeners():
    app = make_app()
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(type(cmd).__name__))
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "space", "s")
        await enter_manual(pilot)
        await select_row(pilot, "O")
        await press(pilot, "1")
        await press(pilot, "f")
        await wait_for_screen(pilot, FaultDialog)
        await press(pilot, "enter", "enter")
        await wait_for_main(pilot)
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
    assert seen == ["Pause", "StepScans", "SetMode", "ManualOutput", "InjectFault",
                    "FaultReset"]


# -- the live runner -----------------------------------------------------------------------


async def test_live_mode_scans_in_a_thread_and_refreshes():
    app = make_app()
    live = PlcHmiApp(app.link.session, live=True)
    async with live.run_test(size=SIZE) as pilot:
        await wait_live(pilot, lambda: live.link.session.engine.scan > 20, "20 live scans")
        await wait_live(pilot, lambda: live.frames_shown > 3, "a few UI frames")
        # the measured scan time: "µs/scan", or "µs" when a loaded machine adds "n scans
        # late" and the bar takes its short forms
        assert re.search(r"\d+ µs", region_text(live, "#status"))
        live.send(Pause())  # under the session's lock: no scan starts after it
        scan = live.link.session.engine.scan
        await pilot.pause(0.1)  # (a check that nothing happens: a sleep cannot make it flaky)
        assert live.link.session.engine.scan == scan
    assert not live.driver.runner.alive


async def test_wait_helpers_are_bounded():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        with pytest.raises(WaitTimeout, match="nothing left to do"):
            await wait_until(pilot, lambda: False, "never")
        with pytest.raises(WaitTimeout):
            await run_until(pilot, lambda s: False, 0.1, "never")


# -- the safety filter's report ------------------------------------------------------------


def _changed(cell) -> bool:
    return cell.snapshot.filter_report is not None and bool(cell.snapshot.filter_report.changes)


async def test_filter_changes_are_shown_with_their_constraint():
    app = make_app(control="faulty")
    async with app.run_test(size=(120, 36)) as pilot:
        await press(pilot, "E")  # the rules by their names
        await run_until(pilot, _changed, 10, "a filter correction")
        snap = app.link.session.last
        change = snap.snapshot.filter_report.changes[0]
        io = region_text(app, "#io")
        row = next(line for line in io.splitlines() if f"│ {change.output} " in line)
        assert "≠ filter" in row and change.by[0] in row
        constraints = region_text(app, "#constraints")
        for name in snap.snapshot.filter_report.violated_names:
            line = next(line for line in constraints.splitlines() if f" {name} " in line)
            assert "▲ corrected" in line
        assert "violated" in region_text(app, "#status")
        chrono = region_text(app, "#chronogram")
        assert any(line.strip("│ ").startswith(f"{change.output}") and "≠" in line
                   for line in chrono.splitlines())
        # later, the history stays: counted, with its last time
        await run_until(pilot, not_violating, 10, "a scan without violation")
        constraints = region_text(app, "#constraints")
        assert f"{change.by[0]} · ×" in constraints and "last" in constraints


async def test_a_past_violation_keeps_its_level_1_explanation():
    app = make_app(control="faulty")
    async with app.run_test(size=(200, 40)) as pilot:
        await press(pilot, "E")  # the rules by their names
        await run_until(pilot, _changed, 10, "a filter correction")
        snap = app.link.session.last
        name = snap.snapshot.filter_report.violated_names[0]
        what = next(e.what for e in snap.explanations if e.key == f"constraint:{name}")
        description = next(c.description for c in app.project.constraints if c.name == name)
        assert what != description
        await run_until(pilot, not_violating, 10, "a scan without violation")
        assert app.link.recorder.constraint_stats()[name].what == what
        row = next(line for line in region_text(app, "#constraints").splitlines()
                   if f" {name} " in line)
        assert "· ×" in row and "last" in row
        assert what[:40] in row and description[:40] not in row


async def test_manual_request_refused_by_the_filter_names_the_constraint():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await run_until(pilot, lambda s: "X2" in s.snapshot.active_steps, 10, "the valve open")
        await enter_manual(pilot)
        await select_row(pilot, "O")
        await press(pilot, "1")  # open order on an open valve: CSs2
        await run_for(pilot, 0.05)
        message = app.message.plain
        assert "NOT AS REQUESTED" in message and "written 0" in message
        assert "never hold the open order when the valve is open" in message
        assert app.link.session.last.snapshot.output_map["O"] is False
        assert "≠ safety filter" in region_text(app, "#io")
        await press(pilot, "E")  # the engineering view: the constraint's name
        await run_for(pilot, 0.01)
        assert "≠ filter CSs2" in region_text(app, "#io")


async def test_reset_under_safe_blocking_says_what_stays():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=(120, 36)) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 10, "safe blocking")
        await run_until(pilot, violating, 10, "the program still violating")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "stays" in text and "its cause is still present" in text
        await press(pilot, "n")
        await wait_for_main(pilot)
        await run_until(pilot, not_violating, 10, "the program no longer violating")
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "will be reset: outputs held safe: a safety rule was broken" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).latched == []


async def test_simulation_controls_are_off_for_a_real_plant():
    app = real_plant_app()  # as a Modbus plant declares: no speed, no faults
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "v", "f")
        await settle(pilot)
        assert app.link.session.state.speed == 1.0
        assert len(app.screen_stack) == 1  # no fault dialog
        titles = [e.title for e in app.palette_entries()]
        assert not any("SIMULATION" in t or t.startswith("Run speed") for t in titles)
        app.action_speed(10.0)  # even if asked directly, refused with its reason
        assert app.link.session.state.speed == 1.0
        assert "NOT AVAILABLE" in app.message.plain and "real plant" in app.message.plain


async def test_a_lost_plant_is_shown_and_its_inputs_marked_stale(monkeypatch):
    from hmi.plant.base import PlantError, PlantStatus

    app = make_app()
    plant = engine(app).plant

    def unreachable(now_us):
        raise PlantError("connection refused")

    async with app.run_test(size=(120, 36)) as pilot:
        await run_for(pilot, 0.5)
        # what a Modbus plant does when the link drops (monkeypatch restores the class)
        monkeypatch.setattr(plant, "read", unreachable)
        monkeypatch.setattr(type(plant), "status", property(lambda self: PlantStatus(
            "modbus", "modbus 127.0.0.1:5020 unit 1", connected=False,
            message="connection refused")))
        await run_for(pilot, 0.1)
        assert "DISCONNECTED" in region_text(app, "#status")
        banners = region_text(app, "#banners")
        assert "PLANT DISCONNECTED" in banners and "connection refused" in banners
        assert "OUTPUTS HELD IN SAFE STATE" in banners
        io = region_text(app, "#io")
        assert io.count("✗ stale") == 2  # fsc and fso: last values read, not the plant's


# -- quitting ------------------------------------------------------------------------------


async def test_quit_asks_first_and_says_what_happens():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.5)
        await enter_manual(pilot)
        await select_row(pilot, "O")
        await press(pilot, "1")
        await run_for(pilot, 0.1)
        await press(pilot, "q")  # a stray q: asked, not obeyed
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "Quit plchmi?" in text and "The scan stops" in text
        assert "simulated plant stops" in text and "requests (O=1) end" in text
        await press(pilot, "n")
        await wait_for_main(pilot)
        assert app.is_running and app.return_code is None
        assert "cancelled: quit" in app.message.plain
        await run_for(pilot, 0.1)
        assert app.link.session.last.snapshot.output_map["O"] is True  # still in control
        await press(pilot, "q")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_until(pilot, lambda: app.return_code is not None, "the app to exit")
    assert app.return_code == 0


async def test_quit_from_the_palette_is_confirmed_too():
    app = make_app()
    async with app.run_test(size=SIZE) as pilot:
        await palette(pilot, "Quit")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "enter")  # only moves the focus: quitting needs y
        assert app.is_running and isinstance(app.screen, ConfirmDialog)
        await press(pilot, "y")
        await wait_until(pilot, lambda: app.return_code is not None, "the app to exit")


async def test_quit_on_a_real_plant_says_the_outputs_are_written_safe():
    app = real_plant_app()  # as a Modbus plant declares
    async with app.run_test(size=SIZE) as pilot:
        await press(pilot, "q")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "Real plant" in text and "safe value (C=0, O=0)" in text
        assert "watchdog" in text
        await press(pilot, "escape")
        await wait_for_main(pilot)
        assert app.return_code is None


async def test_late_scans_are_explained_on_the_status_bar():
    app = make_app()
    app.show_measured = True
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        status = app.query_one("#status")
        assert "cispi_valve" in region_text(app, "#status")
        assert status.tooltip is None
        app.driver.overruns = 2  # as a busy machine would make the live runner count
        await settle(pilot)
        assert "cispi_valve" in region_text(app, "#status")  # kept at 80 columns
        assert "2 scans late" in str(status.tooltip)
        assert "behind schedule" in str(status.tooltip)


async def test_the_same_fault_is_not_injected_twice():
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await palette(pilot, "SIMULATION: inject now: Valve blocked", expect="blocked")
        await run_for(pilot, 0.5)
        assert len(app._injected) == 1
        await palette(pilot, "SIMULATION: inject now: Valve blocked", expect="blocked")
        assert len(app._injected) == 1
        assert "NOT AVAILABLE" in app.message.plain and "already in effect" in \
            app.message.plain
        assert region_text(app, "#sim").count("blocked between") == 1


async def test_home_and_end_in_the_io_table_go_to_the_first_and_last_signal():
    app = make_app(VALVE.parent / "sorting")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.1)
        table = app.query_one(IOPanel)
        table.focus()
        await press(pilot, "end")
        await settle(pilot)
        last = app.project.outputs[-1].name  # the table lists inputs, then outputs
        assert table.selected == last and table.scroll_x == 0
        io = region_text(app, "#io")
        assert "Signal" in io and "Value" in io  # names and values still in view
        await press(pilot, "home")
        await settle(pilot)
        assert table.selected == app.project.inputs[0].name and table.scroll_x == 0

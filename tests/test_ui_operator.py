"""Readable at 80×24: the small things an operator tripped over, each
checked on the real app in virtual time."""

from __future__ import annotations

from ui_harness import region_text, run_for, screen_text, wait_for_main
from ui_scenarios import CONVEYOR, make_app

from hmi.engine.commands import FaultReset, SetSpeed
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.headless import press, settle, wait_for_screen, wait_until


async def test_mode_and_policy_never_drop_from_the_status_bar_even_at_60x20():
    app = make_app(control="faulty")
    async with app.run_test(size=(60, 20)) as pilot:
        await run_for(pilot, 3.0)
        status = region_text(app, "#status")
        assert "AUTO" in status and "correct" in status


async def test_b_without_push_buttons_says_so_and_messages_say_their_words_once():
    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        await press(pilot, "b")
        await settle(pilot)
        assert "NOT AVAILABLE push button: this project has no push button" in \
            app.message.plain
        app.send(FaultReset())
        assert app.message.plain.count("fault reset:") == 1
        app.send(SetSpeed(1.0))
        assert app.message.plain.count("speed: x1") == 1


async def test_the_fault_dialog_says_its_keys_first_and_takes_a_duration():
    app = make_app(CONVEYOR)
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.2)
        await press(pilot, "f")
        await wait_for_screen(pilot, FaultDialog)
        lines = screen_text(app).splitlines()
        hint = next(k for k, line in enumerate(lines) if "enter again: inject" in line)
        first_fault = next(k for k, line in enumerate(lines) if "C1: conveyor halted" in line)
        assert hint < first_fault  # on screen when the dialog opens, above the list
        await press(pilot, "enter")  # the first fault (C1.stop); then its time
        await press(pilot, "tab")  # to the duration
        await press(pilot, "2", "enter")
        await wait_for_main(pilot)
        injection = app._injected[-1].injection
        assert injection.code == "stop" and injection.duration_us == 2_000_000


async def test_the_highlighted_signal_s_description_is_on_the_io_border():
    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.2)
        io = app.query_one("#io")
        io.focus()
        io.move_cursor(row=0)
        await wait_until(pilot, lambda: io.border_subtitle == "fsc: Valve V1 closed end switch",
                         "the description on the border")

"""What the control panel, the dialogs and the answers say in the operator view (the default):
a step's condition in the words of what it reads, one word for the program, the steps by
their descriptions, and in recovery mode a program that waits rather than one that runs.

Pilot tests in virtual time, asserting on the text of the composed screen; the engineering
view (E) still shows the expressions and names.
"""

from __future__ import annotations

import pytest
from ui_harness import region_text, run_for, run_until, screen_text, wait_for_main
from ui_scenarios import VALVE, make_app, recovery

from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.grafcet_panel import GrafcetPanel
from hmi.ui.headless import press, wait_for_screen

SORTING = VALVE.parent / "sorting"
SIZES = [(80, 24), (160, 48)]


def control(app) -> str:
    """The control panel's text, its wrapped lines joined."""
    lines = [line.strip("│╭╮╰╯─ ") for line in region_text(app, "#control").splitlines()]
    return " ".join(" ".join(lines).split())


async def test_a_condition_with_no_description_is_said_with_what_it_reads():
    """The sorting cell's faulty program goes from step 1 on fall(tt_back), a transition with
    no description: the control panel read `waits for “prev(tt_back) and not tt_back”`. It
    now says the edge in the words of the sensor (its I/O name and value beside them), the
    expression in the engineering view only; the step times and the memory read by the next
    step are said in words too (it read `its condition (…)`)."""
    app = make_app(SORTING, control="faulty")
    async with app.run_test(size=(200, 48)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.active_steps == ("X1",), 30, "step 1")
        text = control(app)
        assert "waits for the end of “box across the turntable's back edge" in text, text
        # the whole line, before the panel cuts it to fit
        words = [app.query_one(GrafcetPanel).words(w) for w in app.link.last.snapshot.waits]
        assert words == ["the end of “box across the turntable's back edge” (tt_back now 0)"]
        assert "prev(" not in text and "tt_back and" not in text
        await run_until(pilot, lambda s: s.snapshot.active_steps == ("X2",), 30, "step 2")
        text = control(app)
        assert "waits for 3 s or more in this step (now 0." in text, text
        assert "its condition" not in text and "M_high" not in text and "X2.t" not in text
        words = [app.query_one(GrafcetPanel).words(w) for w in app.link.last.snapshot.waits]
        assert [w.split(" (now 0.")[0] + " | " + w.split(" s) ")[1] for w in words] == [
            "3 s or more in this step | and “the box being handled is high” (now 1)",
            "3 s or more in this step | and not “the box being handled is high” (now 1)"], words
        await press(pilot, "E")  # the engineering view: the expressions
        await run_for(pilot, 0.01)
        assert "X2.t ≥ 3s and M_high" in control(app)


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
async def test_the_manual_dialog_says_control_program_as_every_other_screen(size):
    """The manual dialog said "control law" in its first line and "control program" after
    it; the operator reads one word for the program, everywhere."""
    app = make_app()
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 2)
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "control program stops driving the outputs" in " ".join(text.split())
        assert "control law" not in text


async def test_entering_manual_mode_names_the_step_by_its_description():
    """The answer to manual mode (the message line, and the journal that keeps it) named the
    step the program waits at by its GRAFCET name (`waits at X1`): it names its description,
    the name after it for the engineer; the message line leaves the name out."""
    app = make_app()
    answers: list[str] = []  # the session's answers, as the journal records them
    app.link.session.listeners.append(lambda cmd, result, snap: answers.append(result.message))
    async with app.run_test(size=(160, 48)) as pilot:
        await run_until(pilot, lambda s: s.snapshot.active_steps == ("X1",), 20, "opening")
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        said = app.message.plain
        assert "the control program waits at “Opening" in said, said
        assert "X1" not in said
        assert answers[-1].startswith("manual mode: the control program waits at "
                                      "“Opening” (X1);"), answers


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
async def test_in_recovery_mode_the_control_panel_says_the_program_waits(size):
    """During the valve's recovery the control panel showed `● Open, filling 0.51 s` and what
    that step waited for, as if the program ran, while the recovery held its outputs. It now
    says the program waits (and starts again from its first step), the step it was in held."""
    app = make_app(inject=("F13@10.4s",))
    async with app.run_test(size=size) as pilot:
        await recovery(pilot)
        text = control(app)
        assert "waiting — recovery" in text, text
        assert "● " not in text and "waits for" not in text
        assert "‖ Open, filling" in text and "(held)" in text
        await run_for(pilot, 5)  # done: still waiting until recovery is left
        assert "waiting — recovery" in control(app)


async def test_a_timer_reads_its_time_and_preset_in_one_unit():
    """The control panel's timers read `0.03/200ms` (the palletizer) and `0.78/2.45s`: the
    time run in seconds without a unit, the preset in the project's own notation. Both are
    seconds now, with the unit once: `0.00/2.45 s`."""
    app = make_app()
    async with app.run_test(size=(160, 48)) as pilot:
        await run_for(pilot, 12.3)
        text = control(app)
        assert "/2.45 s" in text and "/2.45s" not in text, text

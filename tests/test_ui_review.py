"""What a hands-on review of the HMI found, one test each."""

from __future__ import annotations

import pytest
from ui_harness import palette, region_text, run_for, screen_text, wait_for_main
from ui_scenarios import diagnosis_ambiguous_state, make_app

from hmi.explain.alarms import ACTIVE_UNACK, CLEARED_UNACK, Alarm
from hmi.ui.alarm_list import alarm_row
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import drain, key_event, press, settle, wait_for_screen
from hmi.ui.style import STYLE, Level


def words(text: str) -> str:
    """A panel's text as one line of words (borders and line breaks gone)."""
    return " ".join(text.replace("│", " ").split())


def commands_seen(app) -> list[str]:
    seen: list[str] = []
    app.link.session.listeners.append(lambda c, r, s: seen.append(type(c).__name__))
    return seen


# -- a late dialog, an early key -----------------------------------------------------------


async def test_a_key_typed_before_the_dialog_was_shown_is_dropped():
    """A stray Enter (or y) typed while the reset dialog was still opening must not answer
    it: the dialog takes only keys typed once it is on screen."""
    app = make_app()
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 1.0)
        seen = commands_seen(app)
        early = [key_event("y"), key_event("enter")]  # typed now, before r's dialog
        await press(pilot, "r")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        assert dialog.shown_at is not None and all(e.time < dialog.shown_at for e in early)
        for event in early:  # delivered late, as a busy terminal would
            event.set_sender(app)
            app._driver.send_message(event)
            await drain(pilot)
        assert app.screen is dialog and seen == []
        await press(pilot, "y")  # typed with the dialog on screen
        await wait_for_main(pilot)
        assert seen == ["FaultReset"]


async def test_enter_only_moves_the_focus_in_a_confirmation():
    app = make_app()
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 1.0)
        seen = commands_seen(app)
        await press(pilot, "m")
        dialog = await wait_for_screen(pilot, ConfirmDialog)
        assert app.focused.id == "no"  # the focus starts on Cancel
        await press(pilot, "enter")
        assert app.focused.id == "yes" and app.screen is dialog
        await press(pilot, "enter")
        assert app.focused.id == "no" and app.screen is dialog and seen == []
        assert "y: confirm" in screen_text(app) and "enter: confirm" not in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert seen == ["SetMode"]


# -- the explanation, level by level, at 80x24 and 100x30 ----------------------------------


@pytest.mark.parametrize("size", [(80, 24), (100, 30)])
async def test_the_level_opened_is_scrolled_into_view_with_a_scroll_hint(size):
    app = make_app(control="faulty")
    async with app.run_test(size=size) as pilot:
        await run_for(pilot, 8.7)
        panel = app.explanation_panel
        for level, heading in ((2, "▾ Why"), (3, "▾ Consequences"),
                               (4, "▾ Policies")):
            await press(pilot, "e")
            await settle(pilot)
            assert panel.level == level
            text = region_text(app, "#explain")
            lines = text.splitlines()
            # on the panel's first line, or scrolled as far as it goes (all of it shown)
            assert heading in lines[1] or (
                heading in text and panel.scroll_y == panel.max_scroll_y), (level, text)
            assert f"level {level}/5" in lines[-1] and "↑↓ scroll" in lines[-1]
        # the arrows scroll it (the focus is on the recommended policy, inside it)
        top = panel.scroll_y
        await press(pilot, "up")
        assert panel.scroll_y == top - 1


# -- stale explanations --------------------------------------------------------------------


async def test_a_policy_answer_is_forgotten_after_a_successful_reset():
    """F1: the diagnoser concludes {F1, F13}; "Fault reset" chosen in the explanation is
    answered "stays in A1" (fsc still reads 0). The technician repairs, the operator resets
    with r: the reset succeeds, and the panel must no longer say it stays in A1."""
    app = make_app()
    async with app.run_test(size=(120, 36)) as pilot:
        await diagnosis_ambiguous_state(pilot)
        await palette(pilot, "Policy: Fault reset")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        said = words(region_text(app, "#explain"))  # in the preview's words, not "in A1"
        assert "Fault reset chosen: fault reset: stays: Valve V1's diagnosis" in said, said
        assert "A1" not in said
        await palette(pilot, "SIMULATION: repair the faulty devices")
        await run_for(pilot, 1.0)
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert "released: Valve V1's diagnosis" in app.message.plain
        await run_for(pilot, 1.0)
        shown = words(region_text(app, "#explain"))
        assert "Valve V1" in shown and "Fault reset chosen" not in shown


async def test_no_level_shown_beside_no_alarm_to_explain():
    """The selected alarm's explanation open to level 4; its condition clears; A
    acknowledges it and it leaves the list: nothing is explained, and no level is shown."""
    app = make_app(control="faulty")
    async with app.run_test(size=(120, 36)) as pilot:
        await run_for(pilot, 8.7)
        await press(pilot, "e", "e", "e")
        assert "level 4/5" in region_text(app, "#explain")
        await press(pilot, "m")  # manual, nothing requested: the program's orders stop
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 5.0)
        assert app.alarm_list.alarms and all(a.state == CLEARED_UNACK
                                             for a in app.alarm_list.alarms)
        await press(pilot, "A")
        await run_for(pilot, 0.01)  # the list the next scan shows
        assert not app.alarm_list.alarms
        text = region_text(app, "#explain")
        assert "no alarm to explain" in text and "level" not in text


def _p1(state: str, severity: str) -> Alarm:
    return Alarm("k", state, severity, "Valve V1: open and close ordered together",
                 "Valve V1", "constraint", 1, 0, 0)


def style_at(text, word: str):
    """The style of the span over `word` in a Rich Text."""
    start = text.plain.index(word)
    return next(s.style for s in text.spans if s.start <= start < s.end)


def test_p1_is_red_p2_and_p3_amber_as_docs_ui_says():
    assert style_at(alarm_row(_p1(ACTIVE_UNACK, "high"), 80), "P1") == STYLE[Level.ALARM]
    assert style_at(alarm_row(_p1(ACTIVE_UNACK, "medium"), 80), "P2") == \
        STYLE[Level.ATTENTION]
    assert style_at(alarm_row(_p1(CLEARED_UNACK, "high"), 80), "P1") != STYLE[Level.ALARM]


# -- resize --------------------------------------------------------------------------------


@pytest.mark.parametrize("control", [None, "faulty"])
async def test_a_resize_from_80x24_to_160x48_gives_the_wide_layout(control):
    async def screen(start, explain: bool) -> str:
        app = make_app(control=control)
        async with app.run_test(size=start) as pilot:
            await run_for(pilot, 8.7)
            if explain:
                await press(pilot, "e")
            if start != (160, 48):
                await pilot.resize_terminal(160, 48)
            await settle(pilot)
            return screen_text(app)

    explain = control is not None
    assert await screen((80, 24), explain) == await screen((160, 48), explain)

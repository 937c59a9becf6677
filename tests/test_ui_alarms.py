"""Pilot tests of the alarm list, the explanation panel, the monitors panel and their controls.

As in test_ui_app.py: a VirtualDriver (no scan unless the test runs virtual time), bounded
waits, and assertions on the engine *and* on what the widgets show.
"""

from __future__ import annotations

from pathlib import Path

from ui_harness import (
    not_violating,
    palette,
    region_text,
    run_for,
    run_until,
    screen_text,
    wait_for_main,
)
from ui_scenarios import VALVE, make_app

from hmi.engine.commands import InjectFault, StopDevice
from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK, CLEARED_UNACK
from hmi.project.injection import Injection
from hmi.timefmt import seconds
from hmi.ui.alarm_list import AlarmList, without_device
from hmi.ui.chronogram import Chronogram
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.explain_panel import ExplanationPanel
from hmi.ui.headless import click, press, settle, wait_for_screen, wait_until

CONVEYOR = VALVE.parent / "conveyor_robot"
WIDE = (120, 36)


def engine(app):
    return app.link.session.engine


def alarms(app) -> dict[str, str]:
    """The engine's alarms, key -> ISA-18.2 state (what the next snapshot will list)."""
    return {a.key: a.state for a in app.link.session.alarms.alarms.values()}


def flat(app, selector: str) -> str:
    """A panel's text with its wrapped lines joined: what a sentence reads across lines."""
    lines = [line.strip("│╭╮╰╯─ ") for line in region_text(app, selector).splitlines()]
    return " ".join(" ".join(lines).split())


def panel(app) -> ExplanationPanel:
    return app.query_one(ExplanationPanel)


async def conveyor_fault(pilot) -> None:
    """002 §4 (paper scenario): the conveyor stops for 2 s after 1 s of work; its monitor
    fires at x = 3 s, y = 1 s."""
    pilot.app.send(InjectFault(Injection("stop", 1_000_000, "C1", 2_000_000)))
    await run_until(pilot, lambda s: any(m.detection for m in s.snapshot.monitors), 5,
                    "the conveyor monitor's fault")


# -- the alarm list ------------------------------------------------------------------------


async def test_alarm_list_shows_state_priority_time_and_text_and_a_click_selects():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 8.7)
        snap = app.link.session.last
        assert {a.state for a in snap.alarms} == {ACTIVE_UNACK, CLEARED_UNACK}
        listed = region_text(app, "#alarms")
        rows = [line for line in listed.splitlines() if "UNACK" in line]
        assert len(rows) == 4 and len(snap.alarms) == 5
        assert "5 unacknowledged / 5" in listed and "↓ 1 more" in listed
        words = {ACTIVE_UNACK: "▲ UNACK ", CLEARED_UNACK: "○ CLEARED-UNACK"}
        for row, alarm in zip(rows, snap.alarms, strict=False):  # row for row, in order
            assert words[alarm.state] in row
            assert f"P{alarm.priority} {seconds(alarm.raised_us)} s" in row
            assert without_device(alarm.text, alarm.device)[:20] in row
        # active ones first, then those already clear that wait for the acknowledgement
        order = [a.state for a in snap.alarms]
        assert order == sorted(order, key=[ACTIVE_UNACK, CLEARED_UNACK].index)
        assert any("×2" in row for row in rows)  # returned once: counted
        # the same list (one start for both): a click on a row selects its alarm
        listed = app.link.session.last.alarms
        alarm_list = app.query_one(AlarmList)
        assert await click(pilot, "#alarms", 10, 3)  # the border, then rows 0, 1, 2
        await settle(pilot)
        assert alarm_list.selected == listed[2].key
        assert panel(app).key == listed[2].key


async def test_a_click_on_the_emptied_alarm_list_is_harmless():
    """The conveyor's monitor latches, a fault reset releases it and `A` acknowledges what
    cleared: the list empties. A click where its rows were raised a contained IndexError
    (the soak farm's seed 93): the rows on screen were remembered as indices into the list
    as it was. Now the click on "no alarm" does nothing, and a click on a row still selects
    the alarm drawn there."""
    app = make_app(CONVEYOR)
    async with app.run_test(size=(80, 24)) as pilot:
        await conveyor_fault(pilot)
        await run_for(pilot, 5)
        listed = app.link.session.last.alarms
        assert len(listed) == 2
        alarm_list = app.query_one(AlarmList)
        assert await click(pilot, "#alarms", 10, 2)  # the border, then rows 0, 1
        await settle(pilot)
        assert alarm_list.selected == listed[1].key
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.5)
        await press(pilot, "A")
        await run_for(pilot, 0.1)
        assert app.link.session.last.alarms == (), app.message.plain
        assert "no alarm" in region_text(app, "#alarms")
        for row in (1, 2):
            assert await click(pilot, "#alarms", 10, row)
            await settle(pilot)
        assert app.containment.latest is None, app.containment.latest
        assert alarm_list.selected is None


async def test_acknowledge_the_selected_alarm_with_a():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: any(a.state == ACTIVE_UNACK for a in s.alarms), 5,
                        "an unacknowledged alarm")
        selected = app.query_one(AlarmList).selected
        assert selected == app.link.session.last.alarms[0].key
        await press(pilot, "a")
        await settle(pilot)
        assert alarms(app)[selected] == ACTIVE_ACK
        assert "acknowledged 1 alarm" in app.message.plain
        # named as the alarm list names it, not by its key (constraint:CSs…)
        text = next(a.text for a in app.link.session.last.alarms if a.key == selected)
        assert f"acknowledged 1 alarm: {text}"[:60] in app.message.plain
        assert selected not in app.message.plain
        await run_for(pilot, 0.01)
        assert "● ACK" in region_text(app, "#alarms")
        # a second time (the soak's operator did it often): said as it is, not "no alarm"
        await press(pilot, "a")
        await settle(pilot)
        text = app.link.session.alarms.alarms[selected].text
        assert "REFUSED" in app.message.plain
        assert "already acknowledged" in app.message.plain and text[:20] in app.message.plain


async def test_acknowledge_while_paused_says_when_it_shows():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 3.0)
        await press(pilot, "space", "A")
        await settle(pilot)
        assert all(s == ACTIVE_ACK for s in alarms(app).values())
        assert "applies at the next scan (paused)" in app.message.plain


async def test_acknowledge_with_no_alarm_is_refused_with_its_reason():
    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 1.0)
        await press(pilot, "a")
        await settle(pilot)
        assert "NOT AVAILABLE" in app.message.plain and "no alarm" in app.message.plain
        assert "✓ no alarm" in region_text(app, "#alarms")


async def test_acknowledge_from_the_palette():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 3.0)
        await palette(pilot, "Alarms: acknowledge all")
        assert all(s == ACTIVE_ACK for s in alarms(app).values())
        await run_for(pilot, 3.0)  # CSc1 raised meanwhile
        key = next(k for k, s in alarms(app).items() if s == ACTIVE_UNACK)
        text = app.link.session.alarms.alarms[key].text
        await palette(pilot, f"Alarms: acknowledge {text}", text)
        assert alarms(app)[key] == ACTIVE_ACK


async def test_select_an_alarm_with_the_keys_then_acknowledge_all_with_shift_a():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 8.7)
        listed = app.link.session.last.alarms
        alarm_list = app.query_one(AlarmList)
        alarm_list.focus()
        await press(pilot, "down")
        await settle(pilot)
        assert alarm_list.selected == listed[1].key
        assert panel(app).key == listed[1].key
        assert listed[1].text in region_text(app, "#explain").replace("\n", " ") or \
            listed[1].text[:40] in region_text(app, "#explain")
        assert "› " + "▲ UNACK" in region_text(app, "#alarms").replace("│ ", "")
        await press(pilot, "a")  # acknowledges the selected one, not the first
        await settle(pilot)
        assert alarms(app)[listed[1].key] == ACTIVE_ACK
        assert alarms(app)[listed[0].key] == listed[0].state
        # then shift+A (one start for both): every other one acknowledged, and those
        # already clear leave the list
        before = alarms(app)
        cleared = [k for k, s in before.items() if s == CLEARED_UNACK]
        assert cleared
        await press(pilot, "A")
        await settle(pilot)
        after = alarms(app)
        assert all(k not in after for k in cleared)  # acknowledged and already clear: gone
        assert all(s == ACTIVE_ACK for s in after.values())
        await run_for(pilot, 0.01)
        listed = region_text(app, "#alarms")
        assert "UNACK" not in listed and "● ACK" in listed
        assert "0 unacknowledged" in listed


async def test_alarm_list_survives_80x24_with_many_alarms():
    app = make_app(control="faulty")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 8.7)
        assert len(app.link.session.last.alarms) == 5
        screen = app.screen.region
        for selector in ("#status", "#alarms", "#message", "HmiFooter"):
            region = app.query_one(selector).region
            assert region.area > 0 and screen.contains_region(region), selector
        rows = [line for line in region_text(app, "#alarms").splitlines() if "UNACK" in line]
        assert len(rows) == 3  # three rows, never fewer
        assert "↓ 2 more" in region_text(app, "#alarms")
        chrono = app.query_one(Chronogram).region
        assert chrono.height >= 4  # the chronogram gave the rows, but is still there
        # the footer lays itself out again after the list grew (the selected alarm's line)
        footer = await wait_until(pilot, lambda: footer_with(app, "Explain"), "the footer")
        for label in ("Ack", "Ack all", "Explain"):
            assert label in footer
        # the selected alarm's whole first sentence is readable on its own line
        selected = app.query_one(AlarmList).selected_alarm
        assert "↳ " + selected.text in " ".join(region_text(app, "#alarms").split())


# -- the explanation panel -----------------------------------------------------------------


def footer_with(app, label: str, rows: int = 2) -> str | None:
    """The footer's lines once they show `label` (a footer re-lays itself out a frame after
    the screen's layout changed), else None."""
    text = "\n".join(screen_text(app).splitlines()[-rows:])
    return text if label in text else None


async def test_expand_the_explanation_level_by_level():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        app.explain("safe_state:filter", open_level=1)
        await settle(pilot)
        exp = next(e for e in app.link.session.last.explanations if e.key == "safe_state:filter")
        text = region_text(app, "#explain")
        assert exp.what[:30] in text and "LATCHED" in text
        assert "▸ Why" in text and "▸ Consequences" in text and "▸ Policies" in text
        assert exp.why[:30] not in text.replace("\n", " ")
        await press(pilot, "e")
        await settle(pilot)
        text = region_text(app, "#explain")
        assert "▾ Why" in text and "Under safe blocking the first unsafe order" in text
        await press(pilot, "e")
        await settle(pilot)
        assert "▾ Consequences" in region_text(app, "#explain")
        await press(pilot, "e")
        await wait_until(pilot, lambda: app.focused is not None
                         and "policy-button" in app.focused.classes, "a policy button")
        focused = app.focused
        assert focused.policy.recommended and focused.policy.id == "reset"
        assert "★ Fault reset" in str(focused.label)
        assert panel(app).level == 4
        await press(pilot, "e")  # the engineering detail, one level deeper
        await settle(pilot)
        assert panel(app).level == 5
        panel(app).scroll_end(animate=False)
        await settle(pilot)
        assert "▾ Engineering detail" in region_text(app, "#explain")
        assert "Latch filter at scan" in region_text(app, "#explain")
        await press(pilot, "e")  # folds back to the first level
        await settle(pilot)
        assert panel(app).level == 1
        assert "▸ Why" in region_text(app, "#explain")


async def test_the_explanation_heading_gives_the_priority_the_alarm_list_shows():
    """Soak seed 101 (valve, normal): F8 is first an ambiguous diagnosis (high, P1), then a
    certain one the cell runs degraded with (medium). The alarm keeps P1 while listed
    (ISA-18.2, hmi.explain.alarms); its explanation's heading said `P2 medium` under a row
    saying P1. It gives the alarm's priority, and the situation's severity now beside it."""
    app = make_app(control="normal", inject=("F8@120ms",))
    async with app.run_test(size=WIDE) as pilot:
        def demoted(snap) -> bool:
            exp = next((e for e in snap.explanations if e.key == "diagnosis:V1"), None)
            return exp is not None and exp.severity == "medium"
        await run_until(pilot, demoted, 5, "the diagnosis certain, medium")
        alarm = next(a for a in app.link.session.last.alarms if a.key == "diagnosis:V1")
        assert alarm.priority == 1 and app.alarm_list.selected == "diagnosis:V1"
        assert "P1 " in region_text(app, "#alarms")
        head = region_text(app, "#explain").splitlines()[1]
        assert "P1 high · now medium" in head and "P2" not in head, head


async def test_click_a_level_heading_opens_and_folds_it():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        app.explain("safe_state:filter", open_level=1)
        await settle(pilot)
        assert await click(pilot, "#explain-consequences")
        await settle(pilot)
        assert panel(app).level == 3  # consequences, and why before it
        text = region_text(app, "#explain")
        assert "▾ Consequences" in text  # the level opened, scrolled into view
        panel(app).scroll_home(animate=False, immediate=True)
        await settle(pilot)
        assert "▾ Why" in region_text(app, "#explain")  # above it, open too
        assert await click(pilot, "#explain-why")
        await settle(pilot)
        assert panel(app).level == 1
        assert "▸ Why" in region_text(app, "#explain")


async def test_narrow_screen_explanation_takes_the_chronogram_place():
    app = make_app(control="faulty")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 3.0)
        assert not panel(app).display  # level 1 is the alarm list's own line
        assert app.query_one("#col-time").display
        await press(pilot, "e")
        await settle(pilot)
        assert panel(app).display and not app.query_one("#col-time").display
        assert "▾ Why" in region_text(app, "#explain")
        await press(pilot, "e", "e", "e", "e")  # policies, engineering detail, folded
        await settle(pilot)
        assert not panel(app).display and app.query_one("#col-time").display


async def test_explain_with_nothing_to_explain_is_refused():
    app = make_app()
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 1.0)
        assert "no alarm to explain" in region_text(app, "#explain")
        await press(pilot, "e")
        await settle(pilot)
        assert "NOT AVAILABLE" in app.message.plain


async def test_click_a_constraint_opens_its_explanation():
    app = make_app(control="faulty")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: s.snapshot.filter_report is not None and "CSs2" in
                        s.snapshot.filter_report.violated_names, 5, "CSs2 violated")
        rows = app.query_one("#constraints").row_names
        assert await click(pilot, "#constraints", 3, 1 + rows.index("CSs2"))
        await settle(pilot)
        assert panel(app).key == "constraint:CSs2"
        assert app.query_one(AlarmList).selected == "constraint:CSs2"
        assert "▾ Why" in region_text(app, "#explain")
        assert "never hold the open order" in region_text(app, "#explain")


# -- policies ------------------------------------------------------------------------------


async def open_policies(pilot, key: str) -> None:
    app = pilot.app
    app.explain(key, open_level=4)
    await wait_until(pilot, lambda: app.focused is not None
                     and "policy-button" in app.focused.classes, "the policy buttons")
    await settle(pilot)


async def test_policy_without_a_command_is_chosen_at_once():
    app = make_app(control="faulty")
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(cmd))
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: any(a.state == ACTIVE_UNACK for a in s.alarms), 5,
                        "a corrected constraint")
        key = app.link.session.last.alarms[0].key
        await open_policies(pilot, key)
        assert app.focused.policy.id == "continue"  # the recommended one, focused
        await press(pilot, "enter")
        await settle(pilot)
        assert len(app.screen_stack) == 1  # no confirmation: nothing changes in the plant
        assert type(seen[-1]).__name__ == "ChoosePolicy" and seen[-1].policy == "continue"
        assert "✓ Continue chosen: let the filter keep correcting" in flat(app, "#explain")
        assert "chosen" in app.message.plain and key not in app.message.plain


async def test_policy_fault_reset_is_confirmed_with_the_reset_preview():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        await run_until(pilot, not_violating, 10, "the program no longer violating")
        await open_policies(pilot, "safe_state:filter")
        await press(pilot, "enter")  # the recommended: fault reset
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "Fault reset?" in text and "will be reset: outputs held safe: a safety rule" in text
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).latched == []
        # the answer in the words of the preview confirmed, not the engine's (safe blocking
        # on CSs…)
        said = flat(app, "#explain")
        assert "✓ Fault reset chosen: fault reset: released: outputs held safe" in said, said
        assert "safe blocking" not in said and "CSs" not in said


async def test_policy_cancelled_sends_nothing():
    app = make_app(control="faulty", policy="block")
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(cmd))
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        await open_policies(pilot, "safe_state:filter")
        await press(pilot, "enter")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "n")
        await wait_for_main(pilot)
        assert seen == [] and engine(app).latched
        assert "cancelled" in app.message.plain


async def test_policy_manual_enters_manual_mode_after_confirmation():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        await open_policies(pilot, "safe_state:filter")
        await press(pilot, "tab")  # the next policy
        assert app.focused.policy.id == "manual"
        await press(pilot, "enter")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "still goes through the safety filter" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).mode == "manual"
        assert app.frame.manual_keys  # the manual keys work before the next scan
        await run_for(pilot, 0.01)
        assert "MANUAL / FORCES ACTIVE" in region_text(app, "#banners")


async def test_policy_stop_device_then_release_it_from_the_palette():
    app = make_app(control="faulty")
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(type(cmd).__name__))
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: any(a.key.startswith("constraint:")
                                             for a in s.alarms), 5, "a constraint alarm")
        await open_policies(pilot, app.link.session.last.alarms[0].key)
        button = next(b for b in app.query(".policy-button")
                      if b.policy.id == "stop_device")
        button.focus()
        await press(pilot, "enter")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "Every output of Valve V1 (C, O) is held at its safe value" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).stopped_devices == {"Valve V1"}
        await run_for(pilot, 0.05)
        snap = app.link.session.last
        assert snap.snapshot.outputs == (False, False) and snap.snapshot.fov == (False, False)
        assert "DEVICE STOPPED" in region_text(app, "#banners")
        assert region_text(app, "#io").count("▲ stopped") == 2
        await palette(pilot, "Release device Valve V1")
        assert engine(app).stopped_devices == set()
        await run_for(pilot, 0.05)
        assert not app.query_one("#banners").display
        assert seen == ["ChoosePolicy", "ReleaseDevice"]


async def test_policy_switch_the_filter_to_correct_under_monitor():
    app = make_app(control="faulty", policy="monitor")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: any(a.severity == "high" for a in s.alarms), 5,
                        "an unsafe vector written")
        key = next(a.key for a in app.link.session.last.alarms if a.severity == "high")
        app.explain(key, open_level=1)
        await settle(pilot)
        assert "✗ P1 high" in region_text(app, "#explain")  # unsafe vector written: red
        await open_policies(pilot, key)
        assert app.focused.policy.id == "correct"
        await press(pilot, "enter")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "The safety filter switches to correct" in screen_text(app)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).policy == "correct"


async def test_policies_are_in_the_palette():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=WIDE) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        app.explain("safe_state:filter", open_level=1)
        await settle(pilot)
        titles = [e.title for e in app.palette_entries()]
        assert any(t.startswith("Policy: Fault reset (recommended)") for t in titles)
        assert any(t.startswith("Explain: ") for t in titles)
        await palette(pilot, "Policy: Switch to manual", "Switch to manual")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert engine(app).mode == "manual"


# -- monitors ------------------------------------------------------------------------------


async def test_monitors_panel_shows_windows_and_a_latched_fault():
    app = make_app(CONVEYOR)
    async with app.run_test(size=(160, 48)) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await run_for(pilot, 0.5)
        text = region_text(app, "#monitors")
        assert "Monitors · 2" in text
        assert "▶ conveyor" in text and "executing" in text
        assert "x ▕" in text and "/5 s" in text and "in [3, 4]" in text
        await conveyor_fault(pilot)
        text = region_text(app, "#monitors")
        assert "✗ conveyor" in text and "FAULTY" in text and "conveyor_fault" in text
        assert "at 3.000 s: x 3.000 s, y 1.000 s" in text
        assert "1 faulty" in text
        listed = region_text(app, "#alarms")
        assert "▲ UNACK" in listed and "LATCHED" in listed and "P2" in listed


async def test_monitors_panel_gives_up_detail_rather_than_rows():
    app = make_app(CONVEYOR)
    async with app.run_test(size=WIDE) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        await conveyor_fault(pilot)
        # 120×36: no room for the detection line (it is in the explanation): the panel
        # keeps location, bars and label for both tasks, and its lower border shows
        lines = region_text(app, "#monitors").splitlines()
        assert lines[-1].startswith("╰")
        text = "\n".join(lines)
        assert "✗ conveyor FAULTY conveyor_fault" in text and "○ robot" in text
        assert "at 3.000 s" not in text
    app = make_app(CONVEYOR)
    async with app.run_test(size=(80, 24)) as pilot:
        await press(pilot, "E")
        await conveyor_fault(pilot)
        lines = region_text(app, "#monitors").splitlines()
        assert any("✗ conveyor FAULTY conveyor_fault" in line for line in lines)
        assert any("○ robot" in line and "x ▕" in line for line in lines)


async def test_monitor_fault_reset_preview_and_policies():
    app = make_app(CONVEYOR)
    async with app.run_test(size=WIDE) as pilot:
        await conveyor_fault(pilot)
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        # the condemned attempt still runs: the label stays
        assert "stays: Conveyor C1 carrying a pallet" in text and "conveyor_fault" not in text
        assert "can no longer end in time" in text
        await press(pilot, "n")
        await wait_for_main(pilot)
        await run_until(pilot, lambda s: not next(m for m in s.snapshot.monitors
                                                   if m.name == "conveyor").running,
                        5, "the late pallet arrives")
        app.send(StopDevice("Robot R1"))
        await run_for(pilot, 0.01)  # the dialog previews the last snapshot
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        text = screen_text(app)
        assert "will be reset: Conveyor C1 carrying a pallet" in text
        assert "1 latched alarm clears with its latch" in text
        assert "stays: Robot R1 stopped by the operator" in text
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.01)
        snap = app.link.session.last
        assert not any(m.detection for m in snap.snapshot.monitors)
        assert "Robot R1" in snap.snapshot.stopped_devices
        assert "○ CLEARED-UNACK" in region_text(app, "#alarms")


async def test_monitor_fault_explanation_offers_its_policies():
    app = make_app(CONVEYOR)
    async with app.run_test(size=WIDE) as pilot:
        await conveyor_fault(pilot)
        assert panel(app).key == "monitor:conveyor"
        await open_policies(pilot, "monitor:conveyor")
        labels = [b.policy.id for b in app.query(".policy-button")]
        assert labels == ["continue", "stop_device", "reset"]
        # the focused recommended policy is scrolled into view once laid out
        text = await wait_until(pilot, lambda: "★ Continue" in region_text(app, "#explain")
                                and region_text(app, "#explain"), "the recommended policy")
        assert "★ Continue" in text and "recommended" in text


async def test_new_controls_reach_the_session_listeners(tmp_path: Path):
    app = make_app(control="faulty")
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(type(cmd).__name__))
    async with app.run_test(size=WIDE) as pilot:
        await run_for(pilot, 3.0)
        await press(pilot, "a", "A")
        await open_policies(pilot, app.link.session.last.alarms[0].key)
        await press(pilot, "enter")
        await settle(pilot)
    assert seen == ["Acknowledge", "Acknowledge", "ChoosePolicy"]


async def test_every_key_stays_in_the_footer_at_80_columns_in_manual_mode():
    from hmi.engine.commands import SetMode
    from hmi.ui.actions import ACTIONS
    from hmi.ui.io_panel import IOPanel

    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        app.send(SetMode(True))
        await run_for(pilot, 0.1)
        footer = app.query_one("HmiFooter")
        text = await wait_until(pilot, lambda: footer_with(app, "Run/Pause", 3), "the footer")
        assert footer.region.height == 3  # two lines are too narrow for 17 keys
        labels = [a.label for a in ACTIONS if a.footer] + [b.description for b in IOPanel.BINDINGS
                                               if b.action != "button"]
        for label in labels:
            assert label in text, label
        assert screen_text(app).splitlines()[0].startswith(" cispi_valve")  # status kept


async def test_manual_keys_work_with_the_focus_on_a_policy_button():
    app = make_app(control="faulty", policy="block")
    async with app.run_test(size=(80, 24)) as pilot:
        await run_until(pilot, lambda s: bool(s.snapshot.latched), 5, "safe blocking")
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.05)
        app.explain("safe_state:filter", open_level=1)
        await settle(pilot)
        await press(pilot, "e", "e", "e")
        await wait_until(pilot, lambda: app.focused is not None
                         and "policy-button" in app.focused.classes, "a policy button")
        footer = "\n".join(screen_text(app).splitlines()[-2:])
        assert "On" in footer and "Off" in footer  # still offered
        selected = app.query_one("#io").selected
        await press(pilot, "1")
        await settle(pilot)
        assert engine(app).manual == {selected: True}
        assert f"{selected} requested on" in app.message.plain
        await press(pilot, "x")
        await settle(pilot)
        assert engine(app).manual == {}


async def test_manual_keys_outside_manual_mode_say_why():
    app = make_app()
    async with app.run_test(size=(80, 24)) as pilot:
        await press(pilot, "1")
        await settle(pilot)
        assert engine(app).manual == {}
        assert "NOT AVAILABLE" in app.message.plain and "manual mode" in app.message.plain

"""A screen never states a guess as a fact, and one message never contradicts the next.

Pilot tests in virtual time, asserting on what the operator reads (the alarm list, the
message line, the dialogs)."""

from __future__ import annotations

from ui_harness import palette, region_text, run_for, run_until, screen_text, wait_for_main
from ui_scenarios import CONVEYOR, make_app

from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import press, wait_for_screen

SIZE = (160, 48)


def texts(app) -> list[str]:
    return [a.text for a in app.frame.cell.alarms]


async def test_a_valve_seen_between_its_ends_is_not_said_to_be_stopped_there():
    """F1 (fsc stuck at 0) on a closed valve at 0.5 % raised "valve V1 is stopped between its
    end positions — recovery needed": the position is inferred from a broken switch. The
    alarm says what is seen, that the position is unknown, and names the valve once."""
    app = make_app(inject=("F1@2s",))  # the valve then closes to 0.5 %, fsc never made
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, lambda s: any(a.key.startswith("recovery_needed")
                                             for a in s.alarms), 20, "recovery needed")
        await run_for(pilot, 0.1)
        [alarm] = [t for t in texts(app) if "recovery needed" in t]
        assert "is stopped" not in alarm and "position unknown" in alarm, alarm
        assert "seen between its end positions" in alarm
        assert alarm.lower().count("valve v1") == 1, alarm
        assert "is stopped between" not in screen_text(app)


async def test_the_repair_message_promises_nothing_the_reset_then_refuses():
    """After repairing F13 the message said "a fault reset now re-synchronises the
    diagnosers"; the reset dialog opened next said it cannot (the valve stands between its
    ends) and offered a recovery."""
    app = make_app(inject=("F13@10.4s",))
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 14)
        await palette(pilot, "SIMULATION: repair the faulty devices")
        said = region_text(app, "#message")
        assert "blocked between fsc and fso removed" in said and "re-synchronises" not in said, \
            said
        await press(pilot, "r")
        await wait_for_screen(pilot, ConfirmDialog)
        assert "recovery" in screen_text(app).lower()  # the reset cannot: it says so
        await press(pilot, "n")
        await wait_for_main(pilot)


async def test_a_cell_without_diagnoser_is_not_told_of_diagnosers_after_a_repair():
    app = make_app(CONVEYOR, inject=("C1.stop@1s",))
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 4)
        await palette(pilot, "SIMULATION: repair the faulty devices")
        said = region_text(app, "#message")
        assert "removed" in said and "diagnoser" not in said, said


async def test_under_monitor_every_unprotected_violation_is_p1():
    """"Open and close ordered together — NOT corrected" stayed P2 under the monitor policy
    (the project rates CSc1 medium when the filter keeps the orders apart) while lesser
    unprotected violations were P1."""
    app = make_app(control="faulty", policy="monitor")
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, lambda s: any(a.key == "constraint:CSc1" for a in s.alarms),
                        30, "open and close ordered together")
        await run_for(pilot, 0.1)
        alarms = {a.key: a for a in app.frame.cell.alarms}
        both = alarms["constraint:CSc1"]
        assert "NOT corrected" in both.text and both.priority == 1, both
        assert all(a.priority == 1 for k, a in alarms.items() if k.startswith("constraint:"))

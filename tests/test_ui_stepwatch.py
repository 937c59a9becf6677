"""The conveyor's dead end at 80×24, as the operator reads it and gets out of it (virtual
time): the alarm row, the explanation's what and why, the control panel's "waits for"; then
manual mode, the pusher on until a pallet waits at B, released, automatic mode: the cell
cycles again and the alarm clears."""

from __future__ import annotations

from ui_harness import region_text, run_for, run_until, wait_for_main
from ui_scenarios import CONVEYOR, make_app, select_row

from hmi.ui.alarm_list import AlarmList
from hmi.ui.headless import press, settle, wait_until


def transfers(cell) -> int:
    return dict(cell.snapshot.plant_counters)["R1.transfers"]


async def test_the_stuck_conveyor_says_what_it_waits_for_and_the_way_back_works():
    app = make_app(CONVEYOR)
    async with app.run_test(size=(80, 24)) as pilot:
        await press(pilot, "E")  # the engineering view: the model's names
        session = app.link.session
        await run_for(pilot, 1)
        await press(pilot, "m", "y")  # manual mode mid-transfer (the soak's step list)
        await wait_for_main(pilot)
        await run_for(pilot, 5)
        await press(pilot, "m", "y")
        await wait_for_main(pilot)
        await run_until(pilot, lambda s: "X3" in s.snapshot.overdue_steps, 12, "X3 overdue")
        await settle(pilot)
        control = region_text(app, "#control")
        assert "✗ stuck" in control and "✗ X3  A pallet waits at B" in control
        assert "↳ waits for B and e — B 0, e 1" in control
        alarms = region_text(app, "#alarms")
        assert "▲ UNACK          P2 16.020 s  Program stuck at “A pallet waits at B”" in alarms
        # the operator selects it and opens its explanation
        await press(pilot, "tab")
        await wait_until(pilot, lambda: isinstance(app.focused, AlarmList), "the list")
        await press(pilot, "home")
        await settle(pilot)
        assert "↳ Program stuck at “A pallet waits at B” — waiting more than" in \
            region_text(app, "#alarms")
        await press(pilot, "e")
        await settle(pilot)
        why = " ".join(w for w in region_text(app, "#explain").split()
                       if w not in ("│", "▄", "▇", "█", "▀"))
        assert "Explanation · sequence" in why
        assert "The program has waited at “A pallet waits at B” since 6.010 s" in why, why
        # the way back: manual mode, the pusher on until a pallet waits at B, released
        before = transfers(session.last)
        await press(pilot, "m", "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.1)
        assert "stuck" not in region_text(app, "#control")
        await select_row(pilot, "d")
        await press(pilot, "1")
        await run_until(pilot, lambda s: s.snapshot.value("B"), 5, "a pallet at B")
        await settle(pilot)
        assert "waits for B and e — B 1, e 1 ✓" in region_text(app, "#control")
        await press(pilot, "x")
        await press(pilot, "m", "y")
        await wait_for_main(pilot)
        await run_for(pilot, 20)
        assert transfers(session.last) >= before + 5
        assert session.last.snapshot.overdue_steps == ()
        assert not any(a.key.startswith("step:") and a.state.startswith("active")
                       for a in session.last.alarms)
        assert "stuck" not in region_text(app, "#control")

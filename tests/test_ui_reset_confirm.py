"""The fault reset dialog never acts on a stale promise (hmi.ui.reset.changes).

The cell keeps running while the dialog is open. With F9 (fso rises unexpectedly) injected at
10 s, the diagnoser of valve V1 stays in S9 while the valve keeps cycling on its estimated
sensor, so what a reset would do moves with the valve: re-synchronise to N5 (closed, 11-14 s),
nothing (travelling), re-synchronise to N1 (open, 16-17 s). The operator opens the dialog at
12 s and confirms later: the app checks again at the confirmation, does nothing if the
promise changed, says what changed, journals it and asks again. Virtual time throughout.
"""

from __future__ import annotations

import json
from pathlib import Path

from ui_harness import run_for, run_until, screen_text, wait_for_main
from ui_scenarios import make_app

from hmi.explain.journal import Journal
from hmi.session.journal_recorder import JournalRecorder
from hmi.ui.dialogs import ConfirmDialog
from hmi.ui.headless import press, wait_until

SIZE = (100, 30)


def diagnoser(app):
    return next(d for d in app.link.session.last.snapshot.diagnosers if d.name == "V1")


def resync_to(target: str):
    return lambda s: any(d.name == "V1" and d.faulty and d.resync == target
                         for d in s.snapshot.diagnosers)


async def dialog_text(pilot, since: ConfirmDialog | None = None) -> str:
    """The text of the confirmation on screen (a new one, if `since` was on screen)."""
    await wait_until(pilot, lambda: isinstance(pilot.app.screen, ConfirmDialog)
                     and pilot.app.screen is not since
                     and pilot.app.screen.shown_at is not None, "a new confirmation")
    lines = " ".join(getattr(line, "plain", str(line)) for line in pilot.app.screen.lines)
    return " ".join(screen_text(pilot.app).split()) + " " + " ".join(lines.split())


def actions(path: Path) -> list[dict]:
    entries = [json.loads(line) for line in path.read_text().splitlines()]
    return [e for e in entries if e["type"] == "action"]


async def test_a_reset_confirmed_after_the_cell_moved_is_asked_again_with_what_changed(
        tmp_path):
    app = make_app(inject=("F9@10s",))
    journal = tmp_path / "journal.jsonl"
    JournalRecorder(app.link.session, Journal(journal), "test")
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, resync_to("N5"), 13, "V1 faulty, a reset re-synchronising it")
        opened_at = app.link.session.last.snapshot.scan
        await press(pilot, "r")
        text = await dialog_text(pilot)
        assert "will be reset: Valve V1's diagnosis: unexpected fso" in text
        assert "show now: fsc=0, fso=1, C=0, O=0" in text
        first = app.screen
        # the valve moves on while the operator reads: a reset would now go to N1
        await run_until(pilot, resync_to("N1"), 8, "V1 open: a reset would go to N1")
        assert diagnoser(app).faulty
        await press(pilot, "y")
        text = await dialog_text(pilot, since=first)
        # nothing was done, and the operator reads why and what the reset would do now
        assert diagnoser(app).faulty and diagnoser(app).state == "S9"
        assert f"CHANGED The cell moved since you read this (scan {opened_at}" in text
        assert "nothing was done" in text
        assert "no longer: ✓ will be reset: Valve V1's diagnosis: unexpected fso" in text
        assert "► ✓ will be reset: Valve V1's diagnosis: unexpected fso" in text
        assert text.index("show now: fsc=0, fso=1, C=0, O=0") < \
            text.index("show now: fsc=1, fso=0, C=0, O=0")
        assert "REFUSED" in app.message.plain and "asked again" in app.message.plain
        # this promise still holds: y carries it out, to the state it names
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert "released: Valve V1's diagnosis" in app.message.plain
        await run_for(pilot, 0.01)  # the next scan shows it
        assert not diagnoser(app).faulty and diagnoser(app).state == "N1"
    resets = [e for e in actions(journal) if e["event"] == "fault reset"]
    assert [e["accepted"] for e in resets] == [False, True]
    assert "not done, asked again: what it would do changed" in resets[0]["message"]
    assert "was: ✓ will be reset: Valve V1's diagnosis" in resets[0]["message"]
    assert "re-synchronised to N5" in resets[0]["message"]
    assert "re-synchronised to N1" in resets[1]["message"]


async def test_a_reset_that_would_now_do_nothing_is_not_sent_as_if_it_would(tmp_path):
    app = make_app(inject=("F9@10s",))
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append(result))
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, resync_to("N5"), 13, "V1 faulty, a reset re-synchronising it")
        await press(pilot, "r")
        await dialog_text(pilot)
        first = app.screen
        # travelling: no normal state matches, a reset would leave the diagnoser where it is
        await run_until(pilot, lambda s: any(d.name == "V1" and d.faulty and not d.resync
                                             for d in s.snapshot.diagnosers), 5, "V1 travelling")
        await press(pilot, "y")
        text = await dialog_text(pilot, since=first)
        assert "► ▲ stays: Valve V1's diagnosis: unexpected fso" in text
        assert [r.accepted for r in seen] == [False]
        # the operator cancels the new dialog: nothing more is sent
        await press(pilot, "n")
        await wait_for_main(pilot)
        assert [r.accepted for r in seen] == [False] and diagnoser(app).faulty


async def test_a_reset_whose_promise_held_is_carried_out_at_once():
    app = make_app(inject=("F9@10s",))
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, resync_to("N5"), 13, "V1 faulty, a reset re-synchronising it")
        await press(pilot, "r")
        await dialog_text(pilot)
        await run_for(pilot, 0.5)  # the cell moves, the promise stands (still N5)
        assert resync_to("N5")(app.link.session.last)
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.01)  # the next scan shows it
        assert not diagnoser(app).faulty and diagnoser(app).state == "N5"


async def test_the_fault_reset_policy_checks_its_promise_too(tmp_path):
    app = make_app(inject=("F9@10s",))
    seen = []
    app.link.session.listeners.append(lambda cmd, result, snap: seen.append((cmd, result)))
    async with app.run_test(size=SIZE) as pilot:
        await run_until(pilot, resync_to("N5"), 13, "V1 faulty, a reset re-synchronising it")
        explanation = next(e for e in app.link.session.last.explanations
                           if e.key == "diagnosis:V1")
        reset = next(p for p in explanation.policies if p.id == "reset")
        app.choose_policy("diagnosis:V1", reset)
        text = await dialog_text(pilot)
        assert "show now: fsc=0, fso=1, C=0, O=0" in text
        first = app.screen
        await run_until(pilot, resync_to("N1"), 8, "V1 open: a reset would go to N1")
        await press(pilot, "y")
        text = await dialog_text(pilot, since=first)
        assert app.screen.id == "policy-choice"
        assert "CHANGED" in text and "► ✓ will be reset: Valve V1's diagnosis" in text
        assert [(type(c).__name__, r.accepted) for c, r in seen] == [("ChoosePolicy", False)]
        await press(pilot, "y")
        await wait_for_main(pilot)
        assert [r.accepted for _, r in seen] == [False, True]
        assert "re-synchronised to N1" in seen[-1][1].message


async def test_a_reset_confirmed_on_nothing_latched_after_a_fault_came_is_asked_again():
    app = make_app(inject=("F9@10s",))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 9.0)
        await press(pilot, "r")
        text = await dialog_text(pilot)
        assert "Nothing is latched: the reset will change nothing." in text
        first = app.screen
        await run_until(pilot, resync_to("N5"), 5, "F9 diagnosed")
        await press(pilot, "y")
        text = await dialog_text(pilot, since=first)
        assert "no longer: nothing latched, the reset changing nothing" in text
        assert "► ✓ will be reset: Valve V1's diagnosis: unexpected fso" in text
        assert "Reset (y)" in text  # the dialog still fits at 80×24, its buttons too
        assert diagnoser(app).faulty

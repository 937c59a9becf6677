"""Alarm management operators ask for: shelving (timed and one-shot, ISA-18.2 §11
and OPC UA Part 9 semantics), comments, CSV export of the journal and alarm history with
filters, and the optional bell on a new unacknowledged P1. Virtual time throughout.
"""

from __future__ import annotations

import csv
import io

import pytest

from hmi.cli import main
from hmi.engine.commands import (
    Acknowledge,
    CommentAlarm,
    Shelve,
    Unshelve,
)
from hmi.explain.alarms import ACTIVE_UNACK, AlarmManager
from hmi.explain.journal import Journal, read
from hmi.explain.model import Explanation
from hmi.session.journal_recorder import JournalRecorder
from tests.conftest import PROJECTS
from tests.examples import make_session

S = 1_000_000
VALVE = PROJECTS / "cispi_valve"


def journalled(tmp_path, **kwargs):
    session = make_session(VALVE, **kwargs)
    journal = Journal(tmp_path / "journal.jsonl")
    return session, JournalRecorder(session, journal), journal.path


def first_active(snap, latched: bool = False):
    return next(a for a in snap.alarms if a.active and a.latched == latched)


def test_a_timed_shelf_hides_the_alarm_journals_it_and_gives_it_back(tmp_path):
    session, recorder, path = journalled(tmp_path, control="faulty")
    snap = session.run_for(3 * S)
    alarm = first_active(snap)
    result = session.command(Shelve(alarm.key, 5 * S))
    assert result.accepted and "shelved for 5s" in result.message
    snap = session.scan_once()
    assert alarm.key not in [a.key for a in snap.alarms]
    assert [a.key for a, _ in snap.shelved] == [alarm.key]
    assert alarm.key in session.alarms.alarms  # still tracked: states go on
    assert not session.command(Shelve(alarm.key, 5 * S)).accepted  # already shelved
    session.command(Acknowledge(None))  # acknowledge all leaves the shelved one alone
    assert session.alarms.alarms[alarm.key].state == ACTIVE_UNACK
    snap = session.run_for(5 * S)
    assert not snap.shelved
    recorder.close()
    entries = read(path).entries
    events = [(e["event"], e.get("message", "")) for e in entries
              if e["type"] == "alarm" and e.get("key") == alarm.key]
    assert ("shelved", "for 5s") in events
    assert ("unshelved", "shelving time over") in events
    assert any(e["type"] == "action" and e["event"] == f"shelve alarm {alarm.key} for 5s"
               and e["accepted"] for e in entries)


def test_a_one_shot_shelf_ends_when_the_condition_clears_and_unshelve_works(tmp_path):
    session, recorder, path = journalled(tmp_path, control="faulty")
    snap = session.run_for(3 * S)
    alarm = first_active(snap)
    assert session.command(Shelve(alarm.key)).accepted
    # The faulty program violates its constraints once per cycle: the condition clears.
    session.run_for(8 * S)
    recorder.close()
    unshelved = [e for e in read(path).entries
                 if e["type"] == "alarm" and e["event"] == "unshelved"]
    assert unshelved and unshelved[0]["message"] in (
        "condition cleared: one-shot shelving over", "returned to normal")
    assert not session.alarms.shelved
    session2 = make_session(VALVE, control="faulty")
    snap = session2.run_for(3 * S)
    alarm = first_active(snap)
    session2.command(Shelve(alarm.key))
    result = session2.command(Unshelve(alarm.key))
    assert result.accepted and "back in the list" in result.message
    assert not session2.command(Unshelve(alarm.key)).accepted


def test_a_latched_safety_alarm_cannot_be_shelved():
    session = make_session(VALVE, control="faulty", policy="block")
    snap = session.run_for(4 * S)
    latched = next(a for a in snap.alarms if a.latched and a.active)
    result = session.command(Shelve(latched.key, 60 * S))
    assert not result.accepted and "latched safety alarm cannot be shelved" in result.message
    assert latched.key in [a.key for a in session.scan_once().alarms]


def _explanation(key: str, latched: bool) -> Explanation:
    return Explanation(key, "diagnosis", "high", "Valve V1", f"{key} what", "", "", (), 0, 0,
                       latched=latched)


def test_an_alarm_that_latches_while_shelved_comes_back_at_once():
    manager = AlarmManager()
    manager.update((_explanation("x", False),), 1, 0)
    events, why = manager.shelve("x", 60 * S, 1, 0)
    assert not why and [e.event for e in events] == ["shelved"]
    assert manager.listed() == ()
    events = manager.update((_explanation("x", True),), 2, 10_000)
    assert [(e.event, e.note) for e in events] == [
        ("unshelved", "latched: a safety alarm is never hidden")]
    assert [a.key for a in manager.listed()] == ["x"]
    assert manager.shelve("x", None, 3, 20_000)[1].startswith("a latched safety alarm")
    assert manager.shelve("x", 9 * 3600 * S, 3, 20_000)[1]  # longer than 8 h: refused


def test_comments_are_journalled_and_kept_on_the_alarm(tmp_path):
    session, recorder, path = journalled(tmp_path, control="faulty")
    snap = session.run_for(3 * S)
    alarm = first_active(snap)
    assert not session.command(CommentAlarm(alarm.key, "   ")).accepted
    assert not session.command(CommentAlarm("nope", "x")).accepted
    result = session.command(CommentAlarm(alarm.key, "checked the end stop,\nall fine"))
    assert result.accepted
    assert session.alarms.alarms[alarm.key].comment == "checked the end stop, all fine"
    recorder.close()
    comments = [e for e in read(path).entries if e["event"] == "comment"]
    assert len(comments) == 1 and comments[0]["key"] == alarm.key
    assert comments[0]["message"] == "checked the end stop, all fine"


def test_the_journal_exports_the_alarm_history_as_csv_with_filters(tmp_path, capsys):
    session, recorder, path = journalled(tmp_path, control="faulty")
    snap = session.run_for(3 * S)
    alarm = first_active(snap)
    session.command(CommentAlarm(alarm.key, "note, with a comma"))
    session.command(Shelve(alarm.key, 2 * S))
    session.run_for(3 * S)
    recorder.close()
    capsys.readouterr()
    assert main(["journal", str(VALVE), "--path", str(path), "--csv", "--kind", "alarm",
                 "--since", "1h"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert rows and {r["type"] for r in rows} == {"alarm"}
    events = {r["event"] for r in rows}
    assert {"raised", "shelved", "unshelved", "comment"} <= events
    assert any(r["message"] == "note, with a comma" for r in rows)
    assert all(r["state"] for r in rows if r["event"] == "raised")
    assert main(["journal", str(VALVE), "--path", str(path), "--csv",
                 "--kind", "action,session"]) == 0
    kinds = {r["type"] for r in csv.DictReader(io.StringIO(capsys.readouterr().out))}
    assert kinds == {"action", "session"}
    assert main(["journal", str(VALVE), "--path", str(path), "--kind", "alarms"]) == 2
    assert "--kind alarms: expected action, alarm" in capsys.readouterr().err


@pytest.mark.parametrize("bell", [True, False])
async def test_the_bell_rings_once_per_new_unacknowledged_p1(bell):
    from ui_harness import run_for, run_until
    from ui_scenarios import make_app

    app = make_app(inject=("F13@10.4s",))
    app.bell_on_p1 = bell
    rung = []
    app.bell = lambda: rung.append(app.link.session.last.snapshot.scan)  # the terminal's, counted
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 9)
        assert rung == []
        await run_until(pilot, lambda s: any(a.priority == 1 for a in s.alarms), 10,
                        "a P1 alarm")
        await run_for(pilot, 2)
        assert len(rung) == (1 if bell else 0)
        assert app.bells == len(rung)


async def test_the_operator_shelves_and_comments_from_the_palette():
    from ui_harness import palette, region_text, run_for, wait_for_main
    from ui_scenarios import make_app

    from hmi.ui.dialogs import ChoiceDialog, TextDialog
    from hmi.ui.headless import press, settle, wait_for_screen

    app = make_app(control="faulty")
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 3)
        alarm = first_active(app.link.session.last)
        await palette(pilot, f"Alarms: comment on {alarm.text}")
        dialog = await wait_for_screen(pilot, TextDialog)
        await press(pilot, *"seen it")
        await press(pilot, "enter")
        await wait_for_main(pilot)
        assert app.link.session.alarms.alarms[alarm.key].comment == "seen it"
        await palette(pilot, f"Alarms: shelve… {alarm.text}")
        dialog = await wait_for_screen(pilot, ChoiceDialog)
        assert dialog.id == "shelve-dialog"
        await press(pilot, "down", "enter")  # for 5 min
        await wait_for_main(pilot)
        await run_for(pilot, 0.05)
        await settle(pilot)
        assert "1 shelved" in region_text(app, "#alarms")
        assert alarm.key not in [a.key for a in app.link.session.last.alarms]


async def test_a_latched_alarm_is_not_offered_for_shelving_and_the_refusal_fits_80_columns():
    """The palette offered to shelve a latched alarm, opened the duration picker, and
    refused only after a choice, its reason cut at 80 columns: now it offers no shelving for
    it, and the shelve action refuses before asking, in words that fit."""
    from ui_harness import run_until
    from ui_scenarios import make_app

    from hmi.ui.headless import settle

    app = make_app(inject=("F13@10.4s",))
    async with app.run_test(size=(80, 24)) as pilot:
        await run_until(pilot, lambda s: any(a.latched and a.active for a in s.alarms), 20,
                        "a latched alarm")
        alarm = first_active(app.link.session.last, latched=True)
        titles = [entry.title for entry in app.palette_entries()]
        assert f"Alarms: comment on {alarm.text}…" in titles
        assert f"Alarms: shelve… {alarm.text}" not in titles
        app.shelve(alarm.key)
        await settle(pilot)
        assert app.screen is app.screen_stack[0]  # no duration picker
        said = app.message.plain
        assert "NOT AVAILABLE" in said and "latched" in said and len(said) <= 80


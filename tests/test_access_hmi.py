"""Who is at the screen, and why: the commands that need a reason (the filter policy,
forcing, manual mode, recovery, shelving) carry one from the person who sent them into the
journal, switching the filter to monitor asks for their password again, and a screen left
untouched warns, then locks until the password is typed again — checked at the runtime's hub
(a real users file, real argon2 hashes, a real journal) and seen in the HMI (pilot tests,
the idle clock injected)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from textual.widgets import Input
from ui_harness import run_for, wait_for_main
from ui_scenarios import VALVE, select_row

from hmi.access import users
from hmi.engine.commands import ChoosePolicy, ManualOutput, Pause, SetMode, SetPolicy, Shelve
from hmi.engine.scan import Engine
from hmi.explain.journal import Journal
from hmi.link.base import Identity
from hmi.link.local import LocalLink
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from hmi.project.kept import load_once
from hmi.runtime.admission import Admission
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.session import Session
from hmi.ui.app import PlcHmiApp
from hmi.ui.dialogs import ConfirmDialog, LockScreen, ReasonDialog
from hmi.ui.headless import press, settle, wait_for_screen

PASSWORD = "carol-password"
SIZE = (100, 30)


@pytest.fixture
def users_path() -> Path:
    path = Path(os.environ["PLCHMI_DATA"]) / "users"
    users.add(path, "carol", "engineer", PASSWORD)
    return path


def cell(tmp_path: Path, users_path: Path, *faults: str) -> tuple[LocalLink, Path]:
    """The valve's session behind a hub that admits from `users_path`, carol signed in at
    the terminal; its journal. `faults` injected as the command line writes them."""
    plant = SimPlant(load_once(VALVE, None))
    for fault in faults:
        plant.inject(parse_injection(fault))
    session = Session(Engine(load_once(VALVE, None), plant))
    journal = tmp_path / "journal.jsonl"
    recorder = JournalRecorder(session, Journal(journal))
    link = LocalLink(session, identity=Identity("carol", "engineer", "terminal", "s1"),
                     journal=recorder, admission=Admission(users_path), password=PASSWORD)
    return link, journal


def actions(journal: Path) -> list[dict]:
    return [json.loads(line) for line in journal.read_text().splitlines()
            if '"type":"action"' in line]


def test_the_runtime_refuses_these_commands_without_a_reason_or_the_password(
        tmp_path, users_path):
    link, journal = cell(tmp_path, users_path)
    assert link.accountable
    refused = link.command(SetMode(True)).result
    assert not refused.accepted and "needs a reason" in refused.message
    assert link.command(SetMode(True), reason="  inspecting the seat ").result.accepted
    assert not link.command(ManualOutput("O", True)).result.accepted
    assert link.command(ManualOutput("O", True), reason="stroke test").result.accepted
    assert link.command(ManualOutput("O", None)).result.accepted  # a release needs none
    monitor = link.command(SetPolicy("monitor"), reason="commissioning").result
    assert not monitor.accepted and "asks for your password again" in monitor.message
    wrong = link.command(SetPolicy("monitor"), reason="commissioning",
                         password="not-hers-at-all").result
    assert not wrong.accepted and "wrong user name or password" in wrong.message
    assert link.command(SetPolicy("monitor"), reason="commissioning",
                        password=PASSWORD).result.accepted
    assert not link.command(SetPolicy("block")).result.accepted  # a reason for any policy
    assert not link.command(Shelve("diagnosis:V1", None)).result.accepted
    assert not link.command(SetMode(True), reason="x" * 501).result.accepted
    link.stop()
    entries = actions(journal)
    manual = next(e for e in entries if e["event"] == "enter manual mode" and e["accepted"])
    assert (manual["user"], manual["role"], manual["reason"]) == (
        "carol", "engineer", "inspecting the seat")
    forced = [e for e in entries if e.get("reason") == "stroke test"]
    assert len(forced) == 1 and forced[0]["accepted"]
    policy = [e for e in entries if e.get("reason") == "commissioning"]
    assert [e["accepted"] for e in policy] == [False, False, True]
    text = journal.read_text()
    assert PASSWORD not in text and "not-hers-at-all" not in text


def test_an_explanations_policy_needs_the_reason_of_what_it_carries_out(
        tmp_path, users_path):
    link, journal = cell(tmp_path, users_path, "F5@1s")
    session = link.session
    for _ in range(3000):
        session.scan_once()
        offered = [(e.key, p.id) for e in session.explanations for p in e.policies
                   if p.id == "manual"]
        if offered:
            break
    assert offered, "no explanation offered manual mode"
    key, policy = offered[0]
    refused = link.command(ChoosePolicy(key, policy)).result
    assert not refused.accepted and "enter manual mode needs a reason" in refused.message
    assert session.engine.mode == "auto"
    assert link.command(ChoosePolicy(key, policy), reason="stuck sensor").result.accepted
    assert session.engine.mode == "manual"
    link.stop()
    chosen = [e for e in actions(journal) if e.get("reason") == "stuck sensor"]
    assert len(chosen) == 1 and chosen[0]["user"] == "carol"


def test_without_a_users_file_nothing_more_is_asked(tmp_path):
    link, _ = cell(tmp_path, tmp_path / "no-users")
    assert not link.accountable
    assert link.command(SetMode(True)).result.accepted
    assert link.command(ManualOutput("O", True)).result.accepted


async def write(pilot, text: str) -> None:
    await press(pilot, *("space" if c == " " else c for c in text))


async def test_the_hmi_asks_why_before_manual_mode_forcing_and_monitor(tmp_path, users_path):
    link, journal = cell(tmp_path, users_path)
    app = PlcHmiApp(link, live=False, show_measured=False)
    engine = link.session.engine
    async with app.run_test(size=SIZE) as pilot:
        await run_for(pilot, 0.5)
        # manual mode: confirmed, then why; escape sends nothing
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        dialog = await wait_for_screen(pilot, ReasonDialog)
        assert "Why: enter manual mode?" in str(dialog.query_one(".dialog-title").render())
        await press(pilot, "escape")
        await wait_for_main(pilot)
        assert engine.mode == "auto" and "cancelled" in app.message.plain
        await press(pilot, "m")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        await wait_for_screen(pilot, ReasonDialog)
        await press(pilot, "enter")  # an empty reason is not one
        await settle(pilot)
        assert isinstance(app.screen, ReasonDialog)
        await write(pilot, "seat inspection")
        await press(pilot, "enter")
        await wait_for_main(pilot)
        assert engine.mode == "manual"
        # forcing an output: why, then forced
        await select_row(pilot, "O")
        await press(pilot, "1")
        await wait_for_screen(pilot, ReasonDialog)
        await write(pilot, "stroke test")
        await press(pilot, "enter")
        await wait_for_main(pilot)
        assert engine.manual == {"O": True}
        # monitor: why, and the password again (not echoed)
        app.action_policy("monitor")
        await wait_for_screen(pilot, ConfirmDialog)
        await press(pilot, "y")
        dialog = await wait_for_screen(pilot, ReasonDialog)
        await write(pilot, "commissioning")
        await press(pilot, "enter")
        await settle(pilot)
        secret = dialog.query_one("#password", Input)
        assert secret.has_focus and secret.password
        await write(pilot, PASSWORD)
        await press(pilot, "enter")
        await wait_for_main(pilot)
        assert engine.policy == "monitor"
    link.stop()
    entries = actions(journal)
    assert [(e["event"], e["reason"]) for e in entries if "reason" in e] == [
        ("enter manual mode", "seat inspection"), ("manual O on", "stroke test"),
        ("filter policy: monitor", "commissioning")], entries
    assert all(e["user"] == "carol" for e in entries if "reason" in e)
    assert PASSWORD not in journal.read_text()


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


async def test_an_untouched_screen_warns_then_locks_until_the_password(tmp_path, users_path):
    users_path.write_text("idle-lock = 5m\nidle-warning = 1m\n" + users_path.read_text())
    link, journal = cell(tmp_path, users_path)
    assert (link.idle_lock_us, link.idle_warning_us) == (300_000_000, 60_000_000)
    clock = Clock()
    app = PlcHmiApp(link, live=False, show_measured=False, idle_clock=clock)
    async with app.run_test(size=SIZE) as pilot:
        clock.now += 3 * 60
        app.check_idle_lock()
        assert app.idle_state == "active"
        clock.now += 61  # a minute before the lock: warned
        app.check_idle_lock()
        assert app.idle_state == "warning"
        assert "LOCKS SOON" in app.message.plain and "locks in 59 s" in app.message.plain
        await press(pilot, "down")  # the person is there: stays signed in
        assert app.idle_state == "active" and "still here" in app.message.plain
        clock.now += 4 * 60 + 30
        app.check_idle_lock()
        assert app.idle_state == "warning"
        clock.now += 31
        app.check_idle_lock()  # five minutes untouched: locked
        lock = await wait_for_screen(pilot, LockScreen)
        assert app.idle_state == "locked"
        refused = link.command(Pause()).result  # the runtime refuses this screen meanwhile
        assert not refused.accepted and "locked" in refused.message
        await write(pilot, "not-her-password")
        await press(pilot, "enter")
        await settle(pilot)
        assert isinstance(app.screen, LockScreen)
        assert "wrong user name or password" in str(lock.query_one("#error").render())
        await press(pilot, "escape")  # does not leave the lock
        assert isinstance(app.screen, LockScreen)
        await write(pilot, PASSWORD)
        await press(pilot, "enter")
        await wait_for_main(pilot)
        assert app.idle_state == "active"
        assert link.command(Pause()).result.accepted
    link.stop()
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    events = [e["event"] for e in entries if e["event"] in (
        "session-locked", "session-unlocked", "sign-in-refused")]
    assert events == ["session-locked", "sign-in-refused", "session-unlocked"]
    locked = next(e for e in entries if e["event"] == "session-locked")
    assert locked["by"] == "terminal:carol" and locked["role"] == "engineer"
    assert "not-her-password" not in journal.read_text()


def test_a_screen_nobody_signs_in_to_never_locks(tmp_path):
    link, _ = cell(tmp_path, tmp_path / "no-users")
    assert PlcHmiApp(link, live=False, show_measured=False).idle_timer is None


def test_a_terminal_given_its_role_by_the_users_file_never_locks(tmp_path, users_path):
    """local-terminal = ROLE: nobody signed in at that terminal, so nothing can be asked
    again — it never locks, and monitor needs a screen that signed in."""
    users_path.write_text("local-terminal = engineer\nidle-lock = 5m\n"
                          + users_path.read_text())
    session = Session(Engine(load_once(VALVE, None), SimPlant(load_once(VALVE, None))))
    link = LocalLink(session, identity=Identity("kiosk", "engineer", "terminal", "k1"),
                     admission=Admission(users_path))
    assert link.identity.role == "engineer" and link.accountable
    assert (link.idle_lock_us, link.idle_warning_us) == (0, 0)
    assert PlcHmiApp(link, live=False, show_measured=False).idle_timer is None
    assert not link.command(SetMode(True)).result.accepted  # a reason is still asked
    assert link.command(SetMode(True), reason="kiosk test").result.accepted
    monitor = link.command(SetPolicy("monitor"), reason="commissioning",
                           password=PASSWORD).result
    assert not monitor.accepted and "did not sign in" in monitor.message
    link.stop()

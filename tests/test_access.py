"""Users, sign-in, lockout, sessions and roles (hmi/access): real files, real argon2."""

from __future__ import annotations

import io
import subprocess
import sys
import threading
import typing
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hmi.access import roles, users
from hmi.access.sessions import IdleTimer, SessionTable
from hmi.access.signin import MAX_WAITING, WRONG, Authenticator
from hmi.cli import main
from hmi.engine import commands as c
from hmi.errors import UsageError


class Clock:
    def __init__(self, now: float = 1_000_000.0):
        self.now = now

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def hashes() -> dict[str, str]:
    """Hashes made once per module (each costs about 50 ms)."""
    h = users.hasher()
    return {"alice": h.hash("alice-password"), "bob": h.hash("bob-password"),
            "erin": h.hash("erin-password")}


def users_file(tmp_path: Path, hashes: dict[str, str], extra: str = "") -> Path:
    path = tmp_path / "users"
    path.write_text(extra + f"alice:operator:active:{hashes['alice']}\n"
                    f"bob:viewer:active:{hashes['bob']}\n"
                    f"erin:engineer:locked:{hashes['erin']}\n", encoding="utf-8")
    return path


def run_cli(argv: list[str], stdin: str = "", monkeypatch=None) -> int:
    old = sys.stdin
    sys.stdin = io.StringIO(stdin)
    try:
        return main(argv)
    finally:
        sys.stdin = old


# -- the users file --------------------------------------------------------------------

def test_cli_adds_changes_locks_and_removes(tmp_path, capsys):
    path = tmp_path / "users"
    assert run_cli(["users", "--file", str(path), "add", "alice", "--role", "operator",
                    "--stdin"], "correct horse\n") == 0
    assert (path.stat().st_mode & 0o777) == 0o600
    text = path.read_text()
    assert "correct horse" not in text and ":operator:active:$argon2id$" in text
    assert run_cli(["users", "--file", str(path), "add", "alice", "--role", "viewer",
                    "--stdin"], "another one\n") == 2
    assert "exists" in capsys.readouterr().err
    assert run_cli(["users", "--file", str(path), "add", "bob", "--role", "viewer",
                    "--stdin"], "short\n") == 2
    assert "at least 8" in capsys.readouterr().err
    auth = Authenticator(path)
    assert auth.check("alice", "correct horse").accepted
    assert run_cli(["users", "--file", str(path), "passwd", "alice", "--stdin"],
                   "battery staple\n") == 0
    assert not auth.check("alice", "correct horse").accepted  # the file is read again
    assert auth.check("alice", "battery staple").role == "operator"
    assert run_cli(["users", "--file", str(path), "role", "alice", "engineer"]) == 0
    assert auth.check("alice", "battery staple").role == "engineer"
    assert run_cli(["users", "--file", str(path), "lock", "alice"]) == 0
    refused = auth.check("alice", "battery staple")
    assert not refused.accepted and "locked by an administrator" in refused.reason
    assert run_cli(["users", "--file", str(path), "unlock", "alice"]) == 0
    assert auth.check("alice", "battery staple").accepted
    assert run_cli(["users", "--file", str(path), "list"]) == 0
    assert "alice" in capsys.readouterr().out
    assert run_cli(["users", "--file", str(path), "remove", "alice"]) == 0
    assert run_cli(["users", "--file", str(path), "remove", "alice"]) == 2
    assert "no user 'alice'" in capsys.readouterr().err


def test_no_default_credentials(tmp_path):
    """No users file: nobody signs in, whatever they try."""
    auth = Authenticator(tmp_path / "users")
    for name, password in (("admin", "admin"), ("root", ""), ("operator", "operator")):
        result = auth.check(name, password)
        assert not result.accepted and "no users file" in result.reason


def test_bad_lines_name_file_and_line(tmp_path, hashes):
    path = users_file(tmp_path, hashes, "lockout-time = 2m\nidle-lock = soon\n")
    with pytest.raises(UsageError, match=r"users:2: idle-lock = 'soon' is not a duration"):
        users.read(path)
    path.write_text(f"alice:root:active:{hashes['alice']}\n")
    with pytest.raises(UsageError, match=r"users:1: role 'root'"):
        users.read(path)
    path.write_text("alice:operator:active:plaintext\n")
    with pytest.raises(UsageError, match=r"users:1: expected NAME:ROLE:STATE:HASH"):
        users.read(path)


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(max_size=400))
def test_any_text_reads_or_is_a_usage_error(tmp_path, text):
    try:
        found = users.parse(tmp_path / "users", text)
    except UsageError as exc:
        assert str(exc).startswith(str(tmp_path / "users"))
    else:
        assert all(u.role in roles.ROLES for u in found.users.values())


# -- sign-in and lockout -----------------------------------------------------------------

def test_five_wrong_passwords_lock_for_the_configured_time(tmp_path, hashes):
    path = users_file(tmp_path, hashes, "lockout-time = 2m\n")
    clock = Clock()
    auth = Authenticator(path, clock)
    for attempt in range(1, 6):
        result = auth.check("alice", f"guess-{attempt}")
        assert not result.accepted
        assert result.reason.startswith(WRONG)
        assert ("locked for 2m" in result.reason) == (attempt == 5)
    sixth = auth.check("alice", "alice-password")  # the right one, too late
    assert not sixth.accepted and "locked for another" in sixth.reason
    other = Authenticator(path, clock)  # another door, another process: the same count
    assert not other.check("alice", "alice-password").accepted
    assert auth.check("bob", "bob-password").accepted  # another user is not locked
    clock.now += 121
    assert auth.check("alice", "alice-password").accepted
    # a success clears the count: four more wrong ones do not lock
    for _ in range(4):
        auth.check("alice", "nope-nope")
    assert auth.check("alice", "alice-password").accepted


def test_unknown_names_answer_like_known_ones(tmp_path, hashes, monkeypatch):
    """The same words, the same lockout and the same work (one argon2 verification) for a
    user who exists and one who does not."""
    path = users_file(tmp_path, hashes)
    auth = Authenticator(path, Clock())
    calls: list[str] = []
    real = auth._verify
    monkeypatch.setattr(auth, "_verify", lambda h, p: calls.append(h) or real(h, p))
    known = [auth.check("alice", "wrong-password").reason for _ in range(6)]
    unknown = [auth.check("mallory", "wrong-password").reason for _ in range(6)]
    assert known == unknown
    assert len(calls) == 12 and calls.count(hashes["alice"]) == 6
    # the locked account, the over-long password, the odd name: one verification each
    calls.clear()
    auth.check("erin", "x" * 5000)
    auth.check("../etc/passwd\x00", "pw")
    assert len(calls) == 2


def test_checks_beyond_the_bound_are_refused_at_once(tmp_path, hashes, monkeypatch):
    auth = Authenticator(users_file(tmp_path, hashes))
    gate = threading.Event()
    monkeypatch.setattr(auth, "check", lambda n, p: gate.wait(30) and None)
    waiting = [auth.submit("alice", "pw") for _ in range(MAX_WAITING)]
    extra = auth.submit("alice", "pw")
    assert extra.done() and "too many sign-in attempts" in extra.result().reason
    gate.set()
    for future in waiting:
        future.result(timeout=30)
    monkeypatch.undo()
    assert auth.submit("alice", "alice-password").result(timeout=30).accepted
    auth.close()


async def test_check_async_runs_off_the_loop(tmp_path, hashes):
    auth = Authenticator(users_file(tmp_path, hashes))
    result = await auth.check_async("bob", "bob-password")
    assert result.accepted and result.role == "viewer"
    auth.close()


# -- sessions ------------------------------------------------------------------------------

def test_sessions_per_user_and_dead_processes(tmp_path, hashes):
    path = users_file(tmp_path, hashes)
    table = SessionTable(path)
    first, _ = table.open("alice", "browser", limit=2)
    second, _ = table.open("alice", "terminal", limit=2)
    assert first and second
    third, why = table.open("alice", "opcua", limit=2)
    assert third is None and "2 sessions open already" in why and "browser since" in why
    assert table.open("bob", "browser", limit=2)[0] is not None
    table.close(first.id)
    assert table.open("alice", "opcua", limit=2)[0] is not None
    # a session whose process is gone no longer counts
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(gone.stdout)
    table2 = SessionTable(tmp_path / "users2")
    assert table2.open("carol", "browser", limit=1, pid=pid)[0] is not None
    assert table2.open("carol", "browser", limit=1)[0] is not None


def test_idle_timer_warns_a_minute_before_it_locks():
    clock = Clock(0.0)
    timer = IdleTimer(15 * 60, 60, clock)
    clock.now = 13 * 60
    assert timer.state() == "active"
    clock.now = 14 * 60 + 1
    assert timer.state() == "warning" and 58 < timer.left() <= 60
    timer.touch()
    assert timer.state() == "active"
    clock.now += 15 * 60
    assert timer.state() == "locked"


# -- roles -----------------------------------------------------------------------------

EVERY_COMMAND = [c.Pause(), c.Resume(), c.StepScans(2), c.SetSpeed(1.0), c.SetMode(True),
                 c.SetMode(False), c.ManualOutput("O", True), c.ManualOutput("O", None),
                 c.FaultReset(), c.SetPolicy("block"), c.SetPolicy("monitor"),
                 c.RepairFaults(), c.SetInput("b", True), c.Acknowledge(None),
                 c.StopDevice("V1"), c.ReleaseDevice("V1"), c.ChoosePolicy("k", "p"),
                 c.StartRecovery("p"), c.EndRecovery(), c.Shelve("k", None), c.Unshelve("k"),
                 c.CommentAlarm("k", "t")]


def test_every_command_type_has_a_role():
    assert set(typing.get_args(c.Command)) == set(roles.REQUIRED)


def test_roles_fail_closed():
    for command in EVERY_COMMAND:
        assert not roles.may("viewer", command)
        assert "a viewer may look but not act" in roles.refusal("viewer", command)
        assert roles.may("engineer", command)
        assert not roles.may("", command) and not roles.may("Engineer", command)
        assert not roles.may("admin", command)
    assert not roles.may("operator", c.SetPolicy("correct"))
    assert "an engineer's command (signed in as operator)" in roles.refusal(
        "operator", c.SetPolicy("correct"))
    assert not roles.may("operator", c.ManualOutput("O", True))  # forcing
    assert roles.may("operator", c.ManualOutput("O", None))  # releasing a force
    assert roles.may("operator", c.Acknowledge("k"))

    class Unknown:
        pass
    assert not roles.may("engineer", Unknown())  # type: ignore[arg-type]
    assert roles.needs_password(c.SetPolicy("monitor"))
    assert not roles.needs_password(c.SetPolicy("block"))
    assert [roles.needs_reason(x) for x in (c.SetPolicy("block"), c.SetMode(True),
            c.SetMode(False), c.ManualOutput("O", False), c.StartRecovery("p"),
            c.Shelve("k", 10), c.Acknowledge(None))] == [True, True, False, True, True,
                                                          True, False]


# -- tickets: a door's sign-in handed to the screen it starts ------------------------------

def test_a_ticket_is_redeemed_once_and_expires(tmp_path):
    from hmi.access import tickets
    path = tmp_path / "users"
    clock = Clock()
    name = tickets.issue(path, "alice", "browser", "w1", clock=clock)
    assert (tickets.folder(path).stat().st_mode & 0o777) == 0o700
    assert ((tickets.folder(path) / name).stat().st_mode & 0o777) == 0o600
    ticket, why = tickets.redeem(path, name, clock=clock)
    assert ticket == tickets.Ticket("alice", "browser", "w1") and why == ""
    again, why = tickets.redeem(path, name, clock=clock)
    assert again is None and "used already" in why
    late = tickets.issue(path, "alice", "browser", clock=clock)
    clock.now += tickets.TICKET_S + 1
    gone, why = tickets.redeem(path, late, clock=clock)
    assert gone is None and "expired" in why
    for bad in ("", "../users", "x" * 32, name.upper()):
        assert tickets.redeem(path, bad, clock=clock)[0] is None
    stale = tickets.issue(path, "bob", "browser", clock=clock)
    clock.now += tickets.TICKET_S + 1
    assert tickets.sweep(path, clock=clock) == 1
    assert tickets.redeem(path, stale, clock=clock)[0] is None


def test_two_redeemers_of_one_ticket_never_both_get_it(tmp_path):
    from hmi.access import tickets
    path = tmp_path / "users"
    for _ in range(20):
        name = tickets.issue(path, "alice", "browser")
        got: list[object] = []
        barrier = threading.Barrier(4)

        def redeem(name: str = name, barrier: threading.Barrier = barrier,
                   got: list[object] = got) -> None:
            barrier.wait()
            got.append(tickets.redeem(path, name)[0])
        threads = [threading.Thread(target=redeem) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert sum(g is not None for g in got) == 1

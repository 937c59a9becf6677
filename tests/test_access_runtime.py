"""Who is at the controls of a running cell: every screen signs in at the runtime (a real
``plchmi serve`` process, its real socket, a real users file with argon2 hashes), its role is
the users file's, every command is checked against that role and journalled with the user,
the role and the door."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from hmi.access import tickets, users
from hmi.engine.commands import Acknowledge, Pause, SetMode, SetPolicy
from hmi.explain.journal import read
from hmi.link.base import Identity
from hmi.link.client import AttachError, SocketLink
from hmi.project.kept import fingerprint, load_once
from tests.conftest import PROJECTS
from tests.runtimes import runtime

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000
PASSWORDS = {"alice": "alice-password", "bob": "bob-password", "carol": "carol-password"}
ROLES = {"alice": "operator", "bob": "viewer", "carol": "engineer"}


@pytest.fixture
def users_path(tmp_path) -> Path:
    path = Path(os.environ["PLCHMI_DATA"]) / "users"
    for name, password in PASSWORDS.items():
        users.add(path, name, ROLES[name], password)
    return path


@pytest.fixture
def sock(tmp_path):
    return tmp_path / "data" / "cell" / "runtime.sock"


def attach(sock: Path, user: str, password: str = "", door: str = "terminal",
           role: str = "operator", ticket: str = "", want_control: bool = True) -> SocketLink:
    project = load_once(VALVE, None)
    link = SocketLink(project, sock, fingerprint(VALVE, None),
                      Identity(user, role, door, f"{user}-s"), want_control,
                      password=password, ticket=ticket)
    assert link.first_frame.wait(120)
    return link


def journal(tmp_path) -> list[dict]:
    return read(tmp_path / "journal.jsonl").entries


def test_screens_sign_in_and_the_users_file_says_the_role(tmp_path, sock, users_path):
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl")) as cell:
        with pytest.raises(AttachError, match="sign in first"):
            attach(sock, "alice")  # no password: a users file exists
        with pytest.raises(AttachError, match="wrong user name or password"):
            attach(sock, "alice", "not-her-password")
        with pytest.raises(AttachError, match="wrong user name or password"):
            attach(sock, "mallory", "anything-at-all")
        # alice says engineer; the users file says operator
        alice = attach(sock, "alice", PASSWORDS["alice"], role="engineer")
        assert alice.identity.user == "alice" and alice.identity.role == "operator"
        assert alice.command(SetMode(True), reason="seat inspection").result.accepted
        refused = alice.command(SetPolicy("monitor"), reason="trying").result
        assert not refused.accepted and "an engineer's command" in refused.message
        # a viewer sees and cannot act, nor take control
        bob = attach(sock, "bob", PASSWORDS["bob"])
        assert bob.identity.role == "viewer"
        assert bob.view().cell is not None
        assert not bob.take_control().accepted
        assert not bob.command(Acknowledge(None)).result.accepted
        # an engineer takes over and changes the policy
        carol = attach(sock, "carol", PASSWORDS["carol"])
        assert carol.take_control().accepted
        assert carol.command(SetPolicy("block"), reason="dry run over").result.accepted
        assert cell.process.poll() is None
        for link in (alice, bob, carol):
            link.leave()
    entries = journal(tmp_path)
    actions = [e for e in entries if e["type"] == "action"]
    manual = next(e for e in actions if e["event"] == "enter manual mode")
    assert (manual["by"], manual["user"], manual["role"], manual["door"],
            manual["reason"]) == ("terminal:alice", "alice", "operator", "terminal",
                                  "seat inspection")
    policy = [e for e in entries if "monitor" in e.get("event", "")]
    assert policy and all(e["by"] == "terminal:alice" for e in policy)
    assert any("refused" in str(e.get("result", "")) or e.get("accepted") is False
               for e in policy), policy
    refusals = [e for e in entries if e.get("event") == "sign-in-refused"]
    assert len(refusals) == 3
    assert [e["by"] for e in refusals] == ["terminal:alice", "terminal:alice",
                                           "terminal:mallory"]
    assert not any("not-her-password" in str(e) for e in entries)


def test_the_sixth_wrong_password_is_refused_as_locked(tmp_path, sock, users_path):
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl")):
        for _ in range(5):
            with pytest.raises(AttachError, match="wrong user name or password"):
                attach(sock, "alice", "guessing-wrong")
        with pytest.raises(AttachError, match="locked"):
            attach(sock, "alice", PASSWORDS["alice"])  # even the right one, now
    events = [(e["event"], e["by"], e["source"]) for e in journal(tmp_path)
              if e["event"] in ("sign-in-refused", "account-locked")]
    assert events == [("sign-in-refused", "terminal:alice", "this machine")] * 4 + [
        ("account-locked", "terminal:alice", "this machine"),
        ("sign-in-refused", "terminal:alice", "this machine")]


def test_a_ticket_lets_one_screen_in_once(sock, users_path):
    with runtime(VALVE, sock):
        name = tickets.issue(users_path, "alice", "browser", "web1")
        link = attach(sock, "whoever", ticket=name, door="browser")
        assert (link.identity.user, link.identity.role, link.identity.door) == (
            "alice", "operator", "browser")
        with pytest.raises(AttachError, match="used already"):
            attach(sock, "whoever", ticket=name, door="browser")
        link.leave()


def test_no_users_file_refuses_the_browser_door_and_keeps_the_terminal(sock):
    with runtime(VALVE, sock):
        with pytest.raises(AttachError, match="no users file"):
            attach(sock, "alice", door="browser")
        link = attach(sock, "alice")  # as before any user existed
        assert link.identity.role == "operator" and link.command(Pause()).result.accepted
        link.leave()


def test_sessions_per_user_are_counted(sock, users_path):
    text = users_path.read_text()
    users_path.write_text("sessions-per-user = 1\n" + text)
    with runtime(VALVE, sock):
        first = attach(sock, "alice", PASSWORDS["alice"])
        with pytest.raises(AttachError, match="sessions open already"):
            attach(sock, "alice", PASSWORDS["alice"])
        first.leave()
        # the runtime closes the session when the screen leaves
        from tests.runtimes import wait_for
        wait_for(lambda: not [s for s in __import__("hmi.access.sessions", fromlist=["x"])
                              .SessionTable(users_path).list() if s.user == "alice"],
                 "alice's session to close")
        attach(sock, "alice", PASSWORDS["alice"]).leave()


def test_a_gateways_users_are_checked_against_the_users_file(tmp_path, sock, users_path):
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl")):
        gateway = attach(sock, "gateway", door="opcua")  # a component: no password
        assert gateway.view().control.holder.identity.door == "opcua"
        # the gateway says bob is an operator; the users file says viewer
        said = Identity("bob", "operator", "opcua", "g1")
        refused = gateway.command(SetMode(True), on_behalf=said).result
        assert not refused.accepted and "viewer" in refused.message
        nobody = gateway.command(SetMode(True), on_behalf=Identity("mallory", "engineer",
                                                                   "opcua", "g1")).result
        assert not nobody.accepted and "not a user" in nobody.message
        ok = gateway.command(SetMode(True), on_behalf=Identity("alice", "operator",
                                                               "opcua", "g1")).result
        assert ok.accepted
        gateway.leave()
    actions = [e for e in journal(tmp_path) if e["type"] == "action"]
    assert [(e["by"], e["role"]) for e in actions if e["event"] == "enter manual mode"] == [
        ("opcua:bob", "viewer"), ("opcua:mallory", "engineer"), ("opcua:alice", "operator")]


def test_the_opcua_users_file_is_every_door_s_and_the_terminal_signs_in(tmp_path, sock):
    """``--opcua-users FILE`` (no users file of the machine): the runtime's doors are FILE's
    users too, so the terminal is a named user, never the login name with every right."""
    pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
    import socket as sockets
    import subprocess
    import sys

    from tests.runtimes import ROOT
    cell_users = tmp_path / "cell-users"
    users.add(cell_users, "alice", "operator", PASSWORDS["alice"])
    assert not users.default_path().exists()
    with sockets.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl"), "--opcua",
                 f"opc.tcp://127.0.0.1:{port}", "--opcua-users", str(cell_users)):
        with pytest.raises(AttachError, match="sign in first"):
            attach(sock, "root")
        alice = attach(sock, "alice", PASSWORDS["alice"], role="engineer")
        assert (alice.identity.user, alice.identity.role) == ("alice", "operator")
        alice.leave()
        # the terminal's screen (plchmi attach) finds it must sign in, and asks
        tried = subprocess.run(
            [sys.executable, "-m", "hmi.cli", "attach", str(VALVE), "--socket", str(sock)],
            input="alice\nwrong-one\nalice\nwrong-two\nalice\nwrong-three\n", text=True,
            capture_output=True, cwd=ROOT, timeout=120)
    assert tried.returncode != 0
    assert "sign in" in tried.stderr and "wrong user name or password (3 tries)" in \
        tried.stderr, tried.stderr
    refused = [e["by"] for e in journal(tmp_path) if e["event"] == "sign-in-refused"]
    # (root here; then the screen's first try, under the login name, before it asked)
    assert refused[0] == "terminal:root" and refused[1].startswith("terminal:")
    assert refused[2:] == ["terminal:alice"] * 3


def test_the_terminal_s_users_file_follows_opcua_users(tmp_path):
    import argparse

    from hmi.cli.screens import signs_in, users_file
    given = tmp_path / "cell-users"
    assert users_file(argparse.Namespace(opcua_users=given)) == given
    assert users_file(argparse.Namespace()) == users.default_path()
    assert not signs_in(given)  # no such file yet: nobody to sign in as
    users.add(given, "alice", "operator", PASSWORDS["alice"])
    assert signs_in(given)

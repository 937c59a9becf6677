"""The HMI says that it serves the cell over OPC UA, and when it stops.

The app runs in virtual time (pilot); the server in its own thread. A test waits on the
server's own state (its status: a session seen, a failure) and then on the app (a frame
drawn), never on the wall clock alone: `until` has a deadline only as a safety net.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
from asyncua import Client
from ui_harness import palette, region_text, run_for, screen_text, wait_for_main

from hmi.explain.journal import Journal
from hmi.opcua.options import journal_listener, server_certificate
from hmi.opcua.server import ServeOptions
from hmi.session.journal_recorder import JournalRecorder
from hmi.ui.app import PlcHmiApp
from hmi.ui.dialogs import InfoDialog
from hmi.ui.headless import press, settle, wait_for_screen
from tests.opcua_cells import ROOT, serve, trust_list, users, valve_session

WAIT_S = 120.0  # a safety net only: every wait ends on the state it waits for
PASSWORD = "correct horse"


async def until(predicate, what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError(f"waited {WAIT_S:g} s for {what}")
        await asyncio.sleep(0.01)


class Served:
    """A valve cell served with users and its own certificate (so it offers encryption),
    journalled, shown by a virtual-time app."""

    def __init__(self, tmp: Path):
        self.session = valve_session()
        self.journal_path = tmp / "journal.jsonl"
        self.recorder = JournalRecorder(self.session, Journal(self.journal_path), "test")
        cert, key = server_certificate(tmp / "pki", "cispi_valve", "127.0.0.1")
        known = users(tmp, {"alice": "operator"}, PASSWORD)
        self.server = serve(self.session, lambda port: ServeOptions(
            port=port, writable=True, users=known, certificate=cert, private_key=key,
            trust=trust_list(tmp)),
            listeners=[journal_listener(self.recorder)])
        self.app = PlcHmiApp(self.session, live=False, show_measured=False,
                             served=self.server)

    def journal(self) -> list[dict]:
        return [json.loads(line) for line in self.journal_path.read_text().splitlines()]

    def close(self) -> None:
        self.server.stop()
        self.recorder.close()


@pytest.fixture
def served(tmp_path):
    cell = Served(tmp_path)
    yield cell
    cell.close()


def status_bar(app: PlcHmiApp) -> str:
    return region_text(app, "#status")


async def test_the_status_bar_counts_the_clients_and_the_palette_names_them_even_at_80x24(
        served):
    app = served.app
    async with app.run_test(size=(120, 36)) as pilot:
        await run_for(pilot, 0.5)
        assert "OPC UA: no clients" in status_bar(app)
        client = Client(served.server.url, timeout=WAIT_S)
        client.set_user("alice")
        client.set_password(PASSWORD)
        async with client:
            await until(lambda: served.server.status().sessions == 1, "alice's session")
            await settle(pilot)
            assert "OPC UA: 1 client" in status_bar(app)
            await palette(pilot, "OPC UA server")
            dialog = await wait_for_screen(pilot, InfoDialog)
            page = screen_text(app)
            assert f"Serving at {served.server.url} (this machine only)" in page
            assert "Security: None, Basic256Sha256 Sign, Basic256Sha256 SignAndEncrypt" in page
            assert "Operator commands: on, for 1 user" in page
            assert "1 client in session:" in page
            peer = served.server.status().clients[0]
            assert f"{peer.peer}  alice  security None" in page
            assert dialog.id == "opcua-dialog"
            await press(pilot, "escape")
            await wait_for_main(pilot)
        await until(lambda: served.server.status().sessions == 0, "the client gone")
        await settle(pilot)
        assert "OPC UA: no clients" in status_bar(app)
    entries = [e for e in served.journal() if e["event"].startswith("opcua")]
    assert [e["event"] for e in entries] == ["opcua-serving"]
    assert served.server.url in entries[0]["message"]
    assert "operator commands enabled" in entries[0]["message"]
    # The same cell (its server started once for both: ~2 s of CPU) shown again at 80x24,
    # where the server's word must never push the mode or the policy off the status bar.
    await at_80x24_the_server_never_pushes_mode_or_policy_out(served)


async def at_80x24_the_server_never_pushes_mode_or_policy_out(served) -> None:
    app = PlcHmiApp(served.session, live=False, show_measured=False, served=served.server)
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        policy = app.link.session.engine.policy
        bar = status_bar(app)
        assert "OPC UA: no clients" in bar and "AUTO" in bar and policy in bar, bar
        await press(pilot, "m")  # manual mode, confirmed: the longest mode word
        await press(pilot, "y")
        await wait_for_main(pilot)
        await run_for(pilot, 0.2)
        bar = status_bar(app)
        assert "MANUAL" in bar and policy in bar and "run" in bar, bar
        assert "OPC UA: no clients" in bar, bar  # before the scan number and time


async def test_a_failed_server_is_a_banner_a_status_word_and_a_journal_entry(served):
    app = served.app
    async with app.run_test(size=(80, 24)) as pilot:
        await run_for(pilot, 0.5)
        assert "OPC UA" not in region_text(app, "#banners")

        def broken():  # an unexpected error in the server's own loop
            raise RuntimeError("deliberate failure of the OPC UA server")

        served.server._clients = broken
        served.server._clients_due = 0.0
        await until(lambda: served.server.status().failed, "the failure")
        await run_for(pilot, 0.1)  # the cell runs on
        banner = region_text(app, "#banners")
        assert "OPC UA FAILED" in banner, banner
        assert "deliberate failure" in screen_text(app)
        bar = status_bar(app)
        assert "OPC UA FAILED" in bar and "AUTO" in bar, bar
        assert app.link.session.engine.policy in bar, bar
        await palette(pilot, "OPC UA server")
        await wait_for_screen(pilot, InfoDialog)
        assert "FAILED was serving at" in screen_text(app)
        await press(pilot, "escape")
        await wait_for_main(pilot)
    failed = next(e for e in served.journal() if e["event"] == "opcua-failed")
    assert "RuntimeError: deliberate failure of the OPC UA server" in failed["message"]
    assert "the SCADA no longer sees this cell" in failed["message"]


async def test_a_server_stopped_while_the_hmi_runs_is_said_and_journalled(served):
    app = served.app
    async with app.run_test(size=(100, 30)) as pilot:
        await run_for(pilot, 0.5)
        served.server.stop()
        await until(lambda: served.server.status().state == "stopped", "the stop")
        await settle(pilot)
        assert "OPC UA STOPPED" in region_text(app, "#banners")
        assert "OPC UA STOPPED" in status_bar(app)
    events = [e["event"] for e in served.journal() if e["event"].startswith("opcua")]
    assert events == ["opcua-serving", "opcua-stopped"]


def test_without_opcua_the_hmi_imports_nothing_of_opcua():
    """The HMI without --opcua, run and its palette listed, loads no module of OPC UA
    (a fresh interpreter: this one has them loaded by the tests)."""
    code = (
        "import asyncio, sys\n"
        "sys.path.insert(0, 'tests')\n"
        "from ui_scenarios import make_app\n"
        "from ui_harness import region_text, run_for\n"
        "async def main():\n"
        "    app = make_app()\n"
        "    async with app.run_test(size=(80, 24)) as pilot:\n"
        "        await run_for(pilot, 0.2)\n"
        "        assert not any('OPC UA' in e.title for e in app.palette_entries())\n"
        "        assert 'OPC UA' not in region_text(app, '#status')\n"
        "asyncio.run(main())\n"
        "print(sorted(m for m in sys.modules if 'opcua' in m.lower()))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"

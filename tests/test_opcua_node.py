"""An independent client, node-opcua (JavaScript), against the cell's OPC UA server.

asyncua is both our server and the other tests' client: a mistake shared by the two would go
unseen. node-opcua-client, installed from npm once into the user's cache folder (see
node_modules below), browses, reads, subscribes to the alarm events, asks for a
ConditionRefresh and acknowledges the alarm with a user whose password it encrypts with the
server's certificate. Skipped, with the reason, where node or npm is missing or npm cannot
install the package.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import pytest

pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")

from hmi.explain.journal import Journal
from hmi.opcua.options import server_certificate
from hmi.opcua.server import ServeOptions
from hmi.session.journal_recorder import JournalRecorder
from tests.opcua_cells import serve, trust_list, users, valve_session

ROOT = Path(__file__).resolve().parent.parent
NODE_OPCUA = "node-opcua-client@2.182.2"  # pinned: the version this test was written against
SCRIPT = Path(__file__).with_name("opcua_node_client.js")


def _installed(folder: Path) -> bool:
    """Whether `folder` holds a whole install of the pinned node-opcua-client."""
    package = folder / "node_modules" / "node-opcua-client" / "package.json"
    try:
        version = json.loads(package.read_text(encoding="utf-8"))["version"]
    except (OSError, ValueError, KeyError):
        return False
    return f"node-opcua-client@{version}" == NODE_OPCUA and (folder / "complete").exists()


@pytest.fixture(scope="module")
def node_modules() -> Path:
    """node-opcua-client installed once for the user (like npm's own cache, in
    $XDG_CACHE_HOME or ~/.cache): an install costs ~6 CPU s and ~10 s of wall (npm reads
    125 packages), the test itself less. A new pin installs beside the old one; an install
    is built in a folder of its own, marked complete, then renamed into place, so that a
    half-done or concurrent install is never used."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node and npm are needed for the node-opcua cross-check "
                    "(apt-get install nodejs npm)")
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "plchmi-tests"
    final = cache / NODE_OPCUA
    if not _installed(final):
        cache.mkdir(parents=True, exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix="node-install-", dir=cache))
        try:
            done = subprocess.run([npm, "install", "--no-audit", "--no-fund",
                                   "--loglevel=error", "--prefix", str(folder), NODE_OPCUA],
                                  capture_output=True, text=True, timeout=600)
        except subprocess.TimeoutExpired:
            shutil.rmtree(folder, ignore_errors=True)
            pytest.skip(f"npm did not install {NODE_OPCUA} within 10 minutes")
        if done.returncode != 0:
            shutil.rmtree(folder, ignore_errors=True)
            pytest.skip(f"npm could not install {NODE_OPCUA} (registry unreachable?): "
                        + done.stderr.strip()[-300:])
        (folder / "complete").touch()
        if final.exists():  # an old, broken install (or another run's, just renamed)
            shutil.rmtree(final, ignore_errors=True)
        try:
            folder.rename(final)
        except OSError:  # another run put its install there first
            shutil.rmtree(folder, ignore_errors=True)
        assert _installed(final), f"{final}: no whole install of {NODE_OPCUA}"
    return final / "node_modules"


def test_node_opcua_browses_reads_and_acknowledges_as_a_user(node_modules, tmp_path):
    session = valve_session()
    project = session.engine.project
    journal = tmp_path / "journal.jsonl"
    recorder = JournalRecorder(session, Journal(journal))
    cert, key = server_certificate(tmp_path / "pki", project.name, "127.0.0.1")
    server = serve(session, lambda port: ServeOptions(
        port=port, writable=True, certificate=cert, private_key=key,
        users=users(tmp_path, {"bob": "operator"}, "node-secret"),
        trust=trust_list(tmp_path)))
    for _ in range(1000):  # F5 at 8.2 s is diagnosed at 9.19 s
        session.scan_once()
    stop = threading.Event()

    def cell_runs() -> None:  # the cell keeps scanning, at its 10 ms period, while node works
        # (every 5 ms, twice that, cost ~1.5 CPU s more in scans and publishing)
        while not stop.wait(0.01):
            session.scan_once()

    scanner = threading.Thread(target=cell_runs, daemon=True)
    scanner.start()
    try:
        done = subprocess.run(["node", str(SCRIPT), server.url, "bob", "node-secret"],
                              capture_output=True, text=True, timeout=300,
                              env={"NODE_PATH": str(node_modules),
                                   "PATH": os.environ.get("PATH", "/usr/bin:/bin")})
    finally:
        stop.set()
        scanner.join(10)
        server.stop()
        recorder.close()
    assert done.returncode == 0, done.stderr[-2000:]
    # node-opcua logs its own notices on stdout; the result is the line that is JSON.
    seen = json.loads(next(line for line in reversed(done.stdout.splitlines())
                           if line.startswith("{")))
    assert {"Valve V1", "Status", "Constraints", "Alarms", "Commands"} <= set(seen["children"])
    assert seen["scanCount"] >= 1000 and seen["sourceTimestamp"]
    alarm = next(a for a in session.last.alarms if a.key == "diagnosis:V1")
    assert seen["alarm"] == {"severity": 900, "message": alarm.text, "active": True,
                             "acked": False, "retain": True, "source": "Valve V1"}
    assert seen["anonymousAck"] == "BadUserAccessDenied"
    assert seen["ack"] == "Good"
    assert seen["acked"] == {"user": "bob", "active": True, "retain": True}
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    action = next(e for e in entries if e.get("event") == "acknowledge alarm diagnosis:V1")
    assert action["by"] == "opcua:bob (node-opcua was here)" and action["accepted"]

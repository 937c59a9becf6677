"""The plant link in the journal, against a real `plchmi serve-plant` process (no mock).

Connections, reconnections, the retries before a connection (first failure, then a summary),
exception responses and scan overruns (first one, then counts): never one entry per scan.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time

from hmi.engine.commands import FaultReset
from hmi.explain.journal import Journal, read
from hmi.session.journal_recorder import JournalRecorder
from tests import test_modbus
from tests.conftest import ROOT
from tests.test_modbus import VALVE, WAIT, Live, _free_port, quick_valve

server = test_modbus.server  # the fixture that starts (and stops) real server processes


def plant_entries(path, overruns: bool = False) -> list[dict]:
    """The plant entries; without scan overruns unless asked (a loaded machine makes some)."""
    return [e for e in read(path).entries if e["type"] == "plant"
            and (overruns or not e["event"].startswith("scan-overrun"))]


def test_a_late_server_journals_the_first_failure_then_a_summary(server, tmp_path):
    path = tmp_path / "j.jsonl"
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "300ms",
         "--plant", f"modbus://127.0.0.1:{port}", "--connect-timeout", "60s",
         "--journal", str(path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stderr is not None
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + WAIT
    while not any("attempt 4" in line for line in lines) and time.monotonic() < deadline:
        time.sleep(0.05)
    srv = server(VALVE, port=port)
    proc.wait(120)
    reader.join(5)
    assert proc.returncode == 0, "".join(lines)
    srv.stop()
    entries = plant_entries(path)
    events = [e["event"] for e in entries]
    assert events == ["connect-failed", "connected"], events
    failed, connected = entries
    assert failed["attempt"] == 1 and "Connection refused" in failed["message"]
    assert connected["failed_attempts"] >= 4 and connected["attempt"] > 4
    assert connected["failing_since"] == failed["wall"] <= connected["wall"]


def test_giving_up_journals_the_retries_summary(tmp_path):
    path = tmp_path / "j.jsonl"
    proc = subprocess.run(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "5s",
         "--plant", f"modbus://127.0.0.1:{_free_port()}", "--connect-timeout", "800ms",
         "--journal", str(path)],
        capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 1
    entries = plant_entries(path)
    assert [e["event"] for e in entries] == ["connect-failed", "connect-retries"]
    assert entries[1]["failed_attempts"] == proc.stderr.count("attempt ") + 1
    last = read(path).entries[-1]  # never "ended normally" after an error
    assert last["event"] == "abnormal-end" and "ended abnormally" in last["message"], last


def test_loss_and_reconnection_are_journalled(server, tmp_path):
    path = tmp_path / "j.jsonl"
    valve = quick_valve(tmp_path / "valve")
    srv = server(valve)
    port = srv.port
    live = Live(valve, port)
    recorder = JournalRecorder(live.session, Journal(path), "test")
    with live:
        live.wait(lambda s: s.output_map["O"], "the valve opening")
        srv.kill()
        live.wait(lambda s: "cannot connect" in s.plant.message, "failed retries")
        srv.port = port
        srv.start(WAIT)
        live.wait(lambda s: s.plant.connected, "the reconnection", since=len(live.snaps))
        assert live.session.command(FaultReset()).accepted
    recorder.close()
    entries = plant_entries(path)
    events = [e["event"] for e in entries]
    assert events == ["connected", "lost", "connect-failed", "reconnected"], events
    assert "connection was closed" in entries[1]["message"]
    assert entries[3]["failed_attempts"] >= 1
    alarms = [e["event"] for e in read(path).entries if e["type"] == "alarm"]
    assert "raised" in alarms  # the connection-lost alarm is still there too


def test_exception_responses_are_one_entry_then_a_count(server, tmp_path):
    path = tmp_path / "j.jsonl"
    srv = server(VALVE, "--inject", "busy@0s+2s")
    live = Live(VALVE, srv.port)
    recorder = JournalRecorder(live.session, Journal(path), "test")
    with live:
        live.wait(lambda s: "Server Device Busy" in s.plant.message, "busy answers")
        back = live.wait(lambda s: s.plant.message.startswith("connected"), "the end of busy")
        live.wait(lambda s: s.scan >= back.scan + 5, "a few good scans")
        answered = live.plant.stats["exceptions"]
    recorder.close()
    entries = plant_entries(path)
    assert [e["event"] for e in entries] == ["connected", "exception", "exceptions"]
    first, counted = entries[1], entries[2]
    assert first["name"] == "Server Device Busy" and "exception 6" in first["message"]
    assert counted["episode_total"] == answered > 2 and counted["count"] == answered - 1
    assert "episode over" in counted["message"]


def test_scan_overruns_are_one_entry_then_a_count(server, tmp_path):
    path = tmp_path / "j.jsonl"
    srv = server(VALVE, "--delay", "25ms")
    live = Live(VALVE, srv.port)
    recorder = JournalRecorder(live.session, Journal(path), "test")
    with live:
        live.wait(lambda s: live.runner.overruns >= 5, "overruns")
    overruns = live.runner.overruns
    recorder.close()
    entries = [e for e in plant_entries(path, overruns=True)
               if e["event"].startswith("scan-overrun")]
    assert [e["event"] for e in entries] == ["scan-overrun", "scan-overruns"]
    assert entries[0]["total"] == 1 and entries[1]["episode_total"] == overruns

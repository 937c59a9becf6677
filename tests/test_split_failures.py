"""Failures stay on their side of the split: a screen killed, a screen that never reads, the
runtime killed; and control among several screens. Real processes (``plchmi serve``, screens
in processes of their own where one is killed), real sockets, waits on state only."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import textwrap

import pytest

from hmi.engine.commands import Pause, SetMode
from hmi.explain.alarms import ACTIVE_ACK
from hmi.explain.journal import read
from hmi.link.base import Identity
from hmi.project.kept import fingerprint
from hmi.wire import messages as m
from hmi.wire.framing import frame
from tests.conftest import PROJECTS
from tests.runtimes import ROOT, RuntimeProcess, runtime, wait_for

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000

# A screen in a process of its own: attaches in control, makes the faulty valve raise its
# alarms, acknowledges one, shelves another, enters manual mode, says what it did, then
# waits to be killed.
SCREEN = textwrap.dedent("""
    import json, sys, time
    from pathlib import Path
    from hmi.engine.commands import Acknowledge, SetMode, Shelve
    from hmi.link.base import Identity
    from hmi.link.client import SocketLink
    from hmi.project.kept import fingerprint, load_once
    project, sock = Path(sys.argv[1]), Path(sys.argv[2])
    link = SocketLink(load_once(project), sock, fingerprint(project, None),
                      Identity("doomed", "operator", "terminal", "d1"))
    link.first_frame.wait(60)
    link.advance(8_000_000)
    alarms = link.last.alarms
    assert link.command(Acknowledge(alarms[0].key)).result.accepted
    assert link.command(Shelve(alarms[1].key, 3_600_000_000)).result.accepted
    assert link.command(SetMode(True)).result.accepted
    link.advance(20_000)
    last = link.last
    print(json.dumps({"acked": alarms[0].key, "alarms": [[a.key, a.state] for a in last.alarms],
                      "shelved": [a.key for a, _ in last.shelved],
                      "mode": last.snapshot.mode, "scan": last.snapshot.scan}), flush=True)
    time.sleep(3600)
""")


def journal(path) -> list[dict]:
    return read(path).entries


def test_kill_9_of_a_screen_leaves_the_cell_as_it_was_for_the_next(tmp_path):
    sock = tmp_path / "data" / "k" / "runtime.sock"
    path = tmp_path / "journal.jsonl"
    with runtime(VALVE, sock, "--control", "faulty", "--journal", str(path)) as cell:
        screen = subprocess.Popen([sys.executable, "-c", SCREEN, str(VALVE), str(sock)],
                                  cwd=ROOT, stdout=subprocess.PIPE, text=True)
        seen = json.loads(screen.stdout.readline())
        assert seen["mode"] == "manual" and seen["shelved"]
        screen.send_signal(signal.SIGKILL)
        screen.wait()
        wait_for(lambda: any(e["event"] == "client-lost" for e in journal(path)),
                 "the journal to say the screen was lost")
        after = cell.attach("next")  # control is free: the next screen takes it
        assert after.view().control.holder.identity.user == "next"
        last = after.last
        assert last.snapshot.scan == seen["scan"]  # virtual time: nothing ran since
        assert [[a.key, a.state] for a in last.alarms] == seen["alarms"]
        assert [a.key for a, _ in last.shelved] == seen["shelved"]
        assert last.snapshot.mode == "manual"
        acked = [a.state for a in last.alarms if a.key == seen["acked"]]
        assert acked in ([], [ACTIVE_ACK])  # acknowledged (or since cleared)
        after.leave()
    lost = [e for e in journal(path) if e["event"] == "client-lost"]
    assert len(lost) == 1 and lost[0]["by"] == "terminal:doomed"
    assert "control-free" in [e["event"] for e in journal(path)]


def test_a_screen_that_never_reads_loses_frames_never_the_scan(tmp_path):
    """Live runtime: a screen that attaches and then never reads gets frames until its
    socket is full, then none (its unsent bytes stay bounded); the scan and the other
    screen go on."""
    sock = tmp_path / "data" / "s" / "runtime.sock"
    with runtime(VALVE, sock, "--control", "faulty", virtual=False) as cell:
        good = cell.attach("good")
        stuck = socket.socket(socket.AF_UNIX)
        stuck.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stuck.connect(str(sock))
        codec = m.codec()
        stuck.sendall(frame(codec.dumps(m.Hello(
            m.PROTOCOL, m.schema_digest(), fingerprint(VALVE, None),
            Identity("stuck", "viewer"), False), m.ClientMessage)))
        # never reads again
        stats = wait_for(lambda: (s := good.query()) and s.frames_dropped > 20 and s,
                         "frames dropped for the stuck screen")
        from hmi.runtime.server import HIGH_WATER
        assert stats.backlog_bytes <= 2 * HIGH_WATER  # bounded: one frame over the mark
        scan = good.last.snapshot.scan
        wait_for(lambda: good.last.snapshot.scan > scan + 50, "the good screen's frames going on")
        assert good.command(Pause()).result.accepted  # and its commands answered
        assert stats.clients == 2
        stuck.close()
        good.leave()


def test_loss_of_the_runtime_is_shown_at_once_and_the_device_watchdog_makes_it_safe(
        tmp_path):
    """kill -9 of the runtime on a real plant (serve-plant with its watchdog): the screen
    knows at once (its connection closed), its commands are refused with why, and the
    device, hearing no request, sets its outputs safe by itself."""
    from hmi.plant.modbus.server_process import ServerProcess
    from tests.test_modbus import WAIT, read_coils
    plant = ServerProcess(VALVE, ("--watchdog", "300ms"))
    plant.start(WAIT)
    sock = tmp_path / "data" / "r" / "runtime.sock"
    try:
        cell = RuntimeProcess(VALVE, sock, "--plant", f"modbus://127.0.0.1:{plant.port}",
                              virtual=False)
        link = cell.attach("alice")
        wait_for(lambda: link.last.snapshot.output_map["O"], "the valve's opening order")
        wait_for(lambda: read_coils(plant.port) == [False, True], "O on at the device")
        def trips() -> int:
            return sum("watchdog: no request for 300ms" in line for line in plant.lines)
        before = trips()  # (it may have tripped before the runtime first connected)
        cell.process.send_signal(signal.SIGKILL)
        cell.process.wait()
        wait_for(lambda: link.lost is not None, "the screen to know")
        assert "connection closed" in link.lost
        answer = link.command(SetMode(True))
        assert not answer.result.accepted and "not done" in answer.result.message
        # (its own words first: each read of the coils is a request, which feeds the
        # watchdog, so polling them would keep it from ever tripping)
        wait_for(lambda: trips() > before, "the device's watchdog")
        assert read_coils(plant.port) == [False, False]
        link.leave()
    finally:
        plant.stop()


@pytest.mark.parametrize("how", ["request", "take"])
def test_control_is_requested_handed_over_or_taken_and_refusals_journalled(tmp_path, how):
    sock = tmp_path / "data" / "c" / "runtime.sock"
    path = tmp_path / "journal.jsonl"
    with runtime(VALVE, sock, "--journal", str(path)) as cell:
        alice = cell.attach("alice")
        bob = cell.attach("bob")
        assert alice.view().control.holder.identity.user == "alice"
        refused = bob.command(Pause()).result
        assert not refused.accepted and "not in control: alice" in refused.message
        if how == "request":
            assert bob.request_control().accepted
            wait_for(lambda: (c := alice.view().control).asked_by is not None
                     and c.asked_by.identity.user == "bob", "alice asked")
            assert alice.hand_over(bob.client).accepted
        else:
            assert bob.take_control().accepted
        wait_for(lambda: alice.view().control.holder.identity.user == "bob",
                 "alice to see bob in control")
        assert not alice.command(Pause()).result.accepted
        assert bob.command(Pause()).result.accepted
        assert bob.release_control().accepted
        nobody = bob.command(Pause()).result
        assert not nobody.accepted and "nobody is in control" in nobody.message
        alice.leave()
        bob.leave()
    entries = journal(path)
    events = [e["event"] for e in entries if e["type"] == "session"]
    expected = ["control-requested", "control-handed-over"] if how == "request" \
        else ["control-taken"]
    assert [e for e in events if e.startswith("control-")] == [
        "control-granted", *expected, "control-released"]
    actions = [(e["by"], e["accepted"]) for e in entries if e["type"] == "action"]
    assert actions == [("terminal:bob", False), ("terminal:alice", False),
                       ("terminal:bob", True), ("terminal:bob", False)]


def test_a_viewer_cannot_take_control(tmp_path):
    sock = tmp_path / "data" / "v" / "runtime.sock"
    with runtime(VALVE, sock) as cell:
        viewer = cell.attach("v", role="viewer", want_control=False)
        assert not viewer.take_control().accepted
        assert not viewer.request_control().accepted
        assert viewer.view().control.holder is None
        viewer.leave()


def test_the_runtime_stopped_by_the_screen_in_control_closes_every_screen(tmp_path):
    sock = tmp_path / "data" / "q" / "runtime.sock"
    path = tmp_path / "journal.jsonl"
    cell = RuntimeProcess(VALVE, sock, "--journal", str(path))
    alice = cell.attach("alice")
    bob = cell.attach("bob", role="viewer", want_control=False)
    bob.leave(stop_cell=True)  # a viewer cannot stop it
    wait_for(lambda: any(e["event"] == "client-left" for e in journal(path)), "bob left")
    assert cell.process.poll() is None
    carol = cell.attach("carol", role="viewer", want_control=False)
    alice.leave(stop_cell=True)
    assert cell.process.wait(120) == 0
    wait_for(lambda: carol.lost is not None, "carol told")
    assert "stopped by alice" in carol.lost
    assert journal(path)[-1]["event"] == "stop"

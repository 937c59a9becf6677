"""The cell's runtime in a process of its own, its screens over its socket (hmi/runtime,
hmi/link/client.py): attaching, frames, commands with their answers and the journal's `by`,
refusals in plain words, virtual time driven by the screen in control, and determinism with
screens attached. Real processes, real sockets; every wait is on state."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

import pytest

from hmi.engine.commands import Acknowledge, InjectFault, Pause, Resume, SetMode, StepScans
from hmi.explain.journal import read
from hmi.link.base import Identity
from hmi.link.client import AttachError, SocketLink
from hmi.project.injection import Injection
from hmi.project.kept import fingerprint, load_once
from hmi.wire import messages as m
from hmi.wire.framing import MAX_OUT, frame, read_message
from tests.conftest import PROJECTS
from tests.runtimes import ROOT, runtime, wait_for

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000


@pytest.fixture
def sock(tmp_path):
    return tmp_path / "data" / "cell" / "runtime.sock"


def journal(tmp_path) -> list[dict]:
    return read(tmp_path / "journal.jsonl").entries


def test_a_screen_attaches_sees_frames_and_commands_with_its_name_in_the_journal(tmp_path,
                                                                                  sock):
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl")) as cell:
        link = cell.attach("alice")
        assert link.facts.project == "cispi_valve" and link.facts.layout.outputs == ("C", "O")
        assert link.view().control.holder.identity.user == "alice"
        assert link.advance(2 * S) == 200
        assert link.last.snapshot.time_us == 2 * S  # the frame showing them came before the answer
        answer = link.command(SetMode(True))
        assert answer.result.accepted and link.view().cell.snapshot.mode in ("auto", "manual")
        link.advance(10_000)
        assert link.last.snapshot.mode == "manual"
        stats = link.query()
        assert stats is not None and stats.clients == 1 and stats.frames_sent >= 2
        link.leave()
    entries = journal(tmp_path)
    action = next(e for e in entries if e["type"] == "action")
    assert action["event"] == "enter manual mode" and action["by"] == "terminal:alice"
    assert action["role"] == "operator" and action["client"].startswith("c1/")
    events = [e["event"] for e in entries if e["type"] == "session"]
    assert events[:3] == ["start", "client-attached", "control-granted"]
    assert "client-left" in events and events[-1] == "stop"


def test_the_history_between_frames_is_kept_one_scan_pulses_included(sock):
    """Every edge of every scan reaches the screen's mirror, however few frames it got:
    the chronogram of a screen elsewhere is the runtime's."""
    with runtime(VALVE, sock, "--control", "faulty") as cell:
        link = cell.attach()
        for _ in range(6):
            link.advance(5 * S)  # one frame per 5 s of scans: hundreds of scans between
        mirror = link.history
        twin = load_twin_recorder(30 * S)
        for signal in twin.signals:
            assert mirror.trace(signal.name, 0, 31 * S) == twin.trace(signal.name, 0, 31 * S)
        assert dict(link.view().constraints) == twin.constraint_stats()


def load_twin_recorder(until_us: int):
    """The same run in this process, recorded by a recorder of its own."""
    from hmi.session.recorder import ScanRecorder
    from tests.conftest import make_session
    session = make_session(VALVE, control="faulty")
    recorder = ScanRecorder(session.engine.layout)
    session.scan_listeners.append(recorder.on_scan)
    while session.next_time <= until_us:
        session.scan_once()
    return recorder


def test_a_viewer_sees_but_its_commands_are_refused_and_journalled(tmp_path, sock):
    with runtime(VALVE, sock, "--journal", str(tmp_path / "journal.jsonl")) as cell:
        operator = cell.attach("alice")
        viewer = cell.attach("bob", role="viewer", want_control=False)
        operator.advance(S)
        wait_for(lambda: viewer.last.snapshot.time_us == S, "the viewer's frame of t = 1 s")
        answer = viewer.command(Pause())
        assert not answer.result.accepted
        assert "viewer" in answer.result.message
        assert not viewer.request_control().accepted
        assert operator.view().run.running  # nothing happened
        viewer.leave()
        operator.leave()
    refused = [e for e in journal(tmp_path) if e["type"] == "action"]
    assert refused == [dict(refused[0], event="pause", accepted=False, by="terminal:bob",
                            role="viewer")]


def test_a_screen_of_another_project_or_version_is_refused_in_plain_words(tmp_path, sock):
    with runtime(VALVE, sock) as cell:
        subsystem = PROJECTS / "cispi_subsystem"
        with pytest.raises(AttachError, match="other files"):
            SocketLink(load_once(VALVE), sock, fingerprint(subsystem, None),
                       Identity("alice"))
        raw = socket.socket(socket.AF_UNIX)
        raw.connect(str(sock))
        codec = m.codec()
        hello = m.Hello(m.PROTOCOL, "0" * 24, fingerprint(VALVE, None), Identity("x"), True)
        raw.sendall(frame(codec.dumps(hello, m.ClientMessage)))
        answer = codec.loads(read_message(raw, MAX_OUT), m.RuntimeMessage)
        assert isinstance(answer, m.Refused) and "different versions of plchmi" in answer.reason
        raw.close()
        cell.attach().leave()  # the runtime is fine


def test_a_second_runtime_for_the_same_project_is_refused(sock):
    with runtime(VALVE, sock):
        second = subprocess.run([sys.executable, "-m", "hmi.cli", "serve", str(VALVE),
                                 "--socket", str(sock), "--virtual"], cwd=ROOT,
                                capture_output=True, text=True, timeout=120)
        assert second.returncode == 1
        assert "a runtime already runs cispi_valve" in second.stderr
        assert "Traceback" not in second.stderr


def trace_of(tmp_path, name: str, viewers: int) -> bytes:
    """A seeded run's trace, driven over the socket, with `viewers` more screens attached."""
    trace = tmp_path / f"{name}.csv"
    sock = tmp_path / name / "runtime.sock"
    with runtime(VALVE, sock, "--control", "faulty", "--inject", "F5@3s",
                 "--trace", str(trace)) as cell:
        driver = cell.attach("driver")
        others = [cell.attach(f"viewer{k}", role="viewer", want_control=False)
                  for k in range(viewers)]
        for _ in range(20):
            driver.advance(S // 2)  # the viewers' frames come meanwhile, as they may
        driver.command(Acknowledge(None))
        driver.advance(2 * S)
        for other in others:
            other.leave()
        driver.leave()
    return trace.read_bytes()


def test_a_run_gives_the_same_trace_with_zero_or_three_screens_attached(tmp_path):
    alone = trace_of(tmp_path, "alone", 0)
    watched = trace_of(tmp_path, "watched", 3)
    assert alone == watched
    assert alone.count(b"\n") == 1 + 1201  # a header and 12 s of scans
    # and up to the acknowledgement (at 10 s), the headless run's own trace
    headless = tmp_path / "headless.csv"
    subprocess.run([sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--control",
                    "faulty", "--inject", "F5@3s", "--for", "10s", "--trace", str(headless)],
                   cwd=ROOT, check=True, capture_output=True, timeout=300)
    assert alone.startswith(headless.read_bytes())


def test_virtual_time_is_driven_by_the_screen_in_control_only(sock):
    with runtime(VALVE, sock) as cell:
        driver = cell.attach("driver")
        other = cell.attach("other", want_control=False)
        with pytest.raises(RuntimeError, match="not in control"):
            other.advance(S)
        driver.command(Pause())
        assert driver.advance(S) == 0  # paused: no scan
        driver.command(Resume())
        assert driver.advance(S) == 100
        assert driver.command(StepScans(10**9)).result.message.startswith("at most")
        driver.command(InjectFault(Injection("F5", 0)))
        other.leave()
        driver.leave()


def test_the_runtime_serves_frames_to_json_readers(sock):
    """The wire is plain JSON: any reader sees the frame's fields (here the first frame's
    scan and run state), nothing that needs plchmi's classes."""
    with runtime(VALVE, sock) as cell:
        raw = socket.socket(socket.AF_UNIX)
        raw.connect(str(sock))
        codec = m.codec()
        hello = m.Hello(m.PROTOCOL, m.schema_digest(), fingerprint(VALVE, None),
                        Identity("json", "viewer"), False)
        raw.sendall(frame(codec.dumps(hello, m.ClientMessage)))
        welcome = json.loads(read_message(raw, MAX_OUT))
        first = json.loads(read_message(raw, MAX_OUT))
        assert welcome[0] == "Welcome" and first[0] == "Frame"
        assert first[2][0][0] == 1  # the cell's snapshot's scan: the first, nothing ran since
        raw.close()
        cell.attach().leave()


def _policies(pid: int) -> list[tuple[int, int]]:
    """Each thread of `pid`: (its scheduling policy, its real-time priority)."""
    import contextlib
    import os
    from pathlib import Path
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # (a thread that ended meanwhile)
            found.append((os.sched_getscheduler(int(task.name)),
                          os.sched_getparam(int(task.name)).sched_priority))
    return found


def test_the_runtimes_other_threads_run_below_its_scan_at_real_time_priority(sock):
    """A real-time scan (where the kernel allows it) with every other thread of the runtime
    at SCHED_FIFO below it: a thread holding the interpreter lock is never descheduled by
    ordinary processes while the scan waits for the lock."""
    import os
    import time

    from hmi.runtime.runtime import HELPERS_PRIORITY
    from hmi.session.live import REALTIME_PRIORITY

    def settled(policies: list[tuple[int, int]]) -> bool:
        return not any(policy == os.SCHED_FIFO for policy, _ in policies) or all(
            p in ((os.SCHED_FIFO, HELPERS_PRIORITY), (os.SCHED_FIFO, REALTIME_PRIORITY))
            for p in policies)

    with runtime(VALVE, sock, virtual=False) as cell:
        alice = cell.attach("alice")
        # a thread that ends soon may be read at normal priority (a sign-in check gives its
        # priority back by design): read again until none is, or a guard against a hang
        # (a thread left at normal priority for good fails below)
        started = time.monotonic()
        policies = _policies(cell.process.pid)
        while not settled(policies) and time.monotonic() - started < 10.0:
            time.sleep(0.05)
            policies = _policies(cell.process.pid)
        alice.leave()
    if not any(policy == os.SCHED_FIFO for policy, _ in policies):
        pytest.skip("SCHED_FIFO is refused on this machine")
    assert policies.count((os.SCHED_FIFO, REALTIME_PRIORITY)) == 1, policies  # the scan
    assert all(p == (os.SCHED_FIFO, HELPERS_PRIORITY) for p in policies
               if p != (os.SCHED_FIFO, REALTIME_PRIORITY)), policies
    assert len(policies) >= 3, policies  # (the main thread, the screens' server, ...)

"""The OPC UA gateway over the real split: ``plchmi serve`` (the runtime) and ``plchmi
gateway`` (the OPC UA server, a process attached to it as a screen), an asyncua client and a
hostile one, real sockets. Every wait is on state (a value read, a journal entry, a process
ended), bounded only by a hang guard."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

asyncua = pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
from asyncua import Client  # noqa: E402

from hmi.access.users import add  # noqa: E402
from hmi.engine.commands import Pause  # noqa: E402
from hmi.explain.journal import read  # noqa: E402
from tests.conftest import PROJECTS  # noqa: E402
from tests.opcua_cells import free_port  # noqa: E402
from tests.runtimes import HANG_GUARD_S, ROOT, runtime, wait_for  # noqa: E402

VALVE = PROJECTS / "cispi_valve"
PASSWORD = "correct horse"


class Gateway:
    """``plchmi gateway`` as a process, waited for until it serves (its own words)."""

    def __init__(self, sock: Path, *options: str):
        self.port = free_port()
        self.url = f"opc.tcp://127.0.0.1:{self.port}"
        self.log = sock.parent / "gateway.test.log"
        with open(self.log, "wb") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "hmi.cli", "gateway", str(VALVE), "--socket",
                 str(sock), "--opcua", self.url, *options], cwd=ROOT,
                stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        wait_for(lambda: "serving cispi_valve over OPC UA" in self.output()
                 or self.process.poll() is not None, "the gateway serving")
        assert self.process.poll() is None, self.output()

    def output(self) -> str:
        return self.log.read_text()

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        self.process.wait(HANG_GUARD_S)


def journal(path: Path) -> list[dict]:
    return read(path).entries


async def _scan_count(url: str, user: str | None = None) -> tuple[Client, object]:
    c = Client(url, timeout=HANG_GUARD_S)
    if user is not None:
        c.set_user(user)
        c.set_password(PASSWORD)
    await c.connect()
    ns = await c.get_namespace_index("urn:plchmi:cispi_valve")
    cell = await c.nodes.objects.get_child(f"{ns}:cispi_valve")
    return c, (ns, cell)


async def _call(url: str, user: str, method: str, *args) -> list:
    c, (ns, cell) = await _scan_count(url, user)
    try:
        commands = await cell.get_child(f"{ns}:Commands")
        return await commands.call_method(f"{ns}:{method}", *args)
    finally:
        await c.disconnect()


async def _read_scans(url: str) -> tuple[int, int, list[str]]:
    """ScanCount twice (moving: the values are live) and the cell's children's names."""
    c, (ns, cell) = await _scan_count(url)
    try:
        count = await cell.get_child([f"{ns}:Status", f"{ns}:ScanCount"])
        started = time.monotonic()
        while True:  # (until the gateway published its first frame's values)
            value = await count.read_data_value(raise_on_bad_status=False)
            if value.StatusCode.is_good() or time.monotonic() - started > HANG_GUARD_S:
                break
            await asyncio.sleep(0.05)
        first = await count.read_value()
        later = first
        while later == first and time.monotonic() - started < HANG_GUARD_S:
            await asyncio.sleep(0.05)
            later = await count.read_value()
        names = [(await n.read_display_name()).Text for n in await cell.get_children()]
        return first, later, names
    finally:
        await c.disconnect()


def test_the_gateway_serves_the_runtimes_cell_and_its_commands_follow_control(tmp_path):
    """The gateway, a screen of the runtime, serves live values; an OPC UA user's command
    goes to the runtime while the gateway is in control (journalled with that user), and is
    refused, in words, once an HMI took control over; the runtime stopping ends the gateway
    by itself."""
    sock = tmp_path / "data" / "g" / "runtime.sock"
    path = tmp_path / "journal.jsonl"
    users = tmp_path / "users"
    add(users, "bob", "operator", PASSWORD)
    with runtime(VALVE, sock, "--journal", str(path), virtual=False) as cell:
        gateway = Gateway(sock, "--opcua-writable", "--opcua-users", str(users))
        try:
            first, later, names = asyncio.run(_read_scans(gateway.url))
            assert later > first and "Valve V1" in names and "Commands" in names
            accepted, message = asyncio.run(_call(gateway.url, "bob", "SetMode", True))
            assert accepted, message
            alice = cell.attach("alice", want_control=True)
            wait_for(lambda: alice.last.snapshot.mode == "manual", "manual mode seen by alice")
            assert not alice.command(Pause()).result.accepted  # the gateway is in control
            assert alice.take_control().accepted
            accepted, message = asyncio.run(_call(gateway.url, "bob", "SetMode", False))
            assert not accepted and "not in control" in message
            alice.leave()
        finally:
            cell.stop()
            gateway.process.wait(HANG_GUARD_S)  # ends by itself: the runtime stopped
    assert gateway.process.returncode == 0, gateway.output()
    assert "the runtime is gone" in gateway.output()
    entries = journal(path)
    actions = [(e["by"], e["accepted"]) for e in entries if e["type"] == "action"]
    assert actions == [("opcua:bob", True), ("terminal:alice", False),
                       ("opcua:bob", False)], actions
    events = [e["event"] for e in entries
              if e["type"] == "session" and e["event"].startswith("opcua-")]
    # (the runtime stopped first: the gateway left with it, its service stopped)
    assert events == ["opcua-serving", "opcua-stopped"], events


HEL_CLAIM = 2 ** 31 - 1  # bytes the hostile HEL says its message has


def _hostile_hel(port: int, stream_bytes: int) -> int:
    """A HEL whose header claims ~2 GiB, then data streamed into it: what the server must
    buffer. Returns the bytes it managed to send."""
    header = b"HELF" + HEL_CLAIM.to_bytes(4, "little")
    body = (0).to_bytes(4, "little") + (65536).to_bytes(4, "little") * 2 \
        + (0).to_bytes(4, "little") * 2
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_GUARD_S) as s:
        s.sendall(header + body)
        chunk = b"\0" * (1 << 20)
        with contextlib.suppress(OSError):
            while sent < stream_bytes:
                s.sendall(chunk)
                sent += len(chunk)
    return sent


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


STREAMED = 64 << 20  # what the hostile client would send into its HEL
# What a client can have sent before it sees the close, at any load: the gateway reads at
# most one chunk (64 kB) and one socket read (256 kB) before it closes; the rest stays in
# the kernel's socket buffers (loopback: 128 kB received, at most 4 MB to send, here),
# never in the gateway.
SENT_AT_MOST = 16 << 20


def test_a_hostile_hel_is_refused_before_the_gateway_buffers_it(tmp_path):
    """A HEL claiming 2 GiB, then 64 MiB streamed into it: the gateway closes the connection
    at the header (no chunk is larger than its receive buffer) instead of buffering what
    streams in, twice over; its memory stays as it was and it serves on; the runtime's
    memory does not move and its scans and screens go on (the figures of its scan times
    are `plchmi bench live`'s, not a test's)."""
    sock = tmp_path / "data" / "h" / "runtime.sock"
    with runtime(VALVE, sock, virtual=False) as cell:
        gateway = Gateway(sock)
        try:
            alice = cell.attach("alice")
            runtime_before = _rss_kb(cell.process.pid)
            gateway_before = _rss_kb(gateway.process.pid)
            for _ in range(2):
                sent = _hostile_hel(gateway.port, STREAMED)
                assert sent < SENT_AT_MOST, sent  # closed: the stream was not taken in
            wait_for(lambda: gateway.output().count("a message chunk of") >= 2,
                     "the gateway saying why it closed the connections")
            scan = alice.last.snapshot.scan
            wait_for(lambda: alice.last.snapshot.scan > scan + 100, "the scans going on")
            gateway_grew = _rss_kb(gateway.process.pid) - gateway_before
            runtime_grew = _rss_kb(cell.process.pid) - runtime_before
            assert gateway_grew < 16 * 1024, gateway_grew  # not the attack's 64 MiB
            assert runtime_grew < 16 * 1024, runtime_grew
            first, later, names = asyncio.run(_read_scans(gateway.url))  # it serves on
            assert later > first and "Valve V1" in names
            assert alice.command(Pause()).result.accepted  # the runtime answers
            print(f"sent {sent} B; gateway +{gateway_grew} kB, runtime +{runtime_grew} kB")
            alice.leave()
        finally:
            gateway.stop()


def test_the_gateway_needs_a_running_runtime(tmp_path):
    done = subprocess.run([sys.executable, "-m", "hmi.cli", "gateway", str(VALVE), "--socket",
                           str(tmp_path / "none" / "runtime.sock"), "--opcua",
                           f"opc.tcp://127.0.0.1:{free_port()}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=HANG_GUARD_S,
                          env={**os.environ})
    assert done.returncode == 1, done.stderr
    assert "no runtime runs cispi_valve" in done.stderr


async def test_the_screens_show_the_gateway_serving_then_its_loss(tmp_path):
    """The runtime's frames carry the gateway's state: an HMI attached to the runtime shows
    OPC UA and its clients in the status bar; the gateway killed, the runtime marks it
    failed (journalled) and the HMI says so in its status bar and a banner."""
    from ui_harness import region_text

    from hmi.link.base import Identity
    from hmi.link.client import SocketLink
    from hmi.project.kept import fingerprint, load_once
    from hmi.ui.app import PlcHmiApp
    from hmi.ui.headless import settle
    from tests.runtimes import RuntimeProcess

    sock = tmp_path / "data" / "s" / "runtime.sock"
    path = tmp_path / "journal.jsonl"
    cell = RuntimeProcess(VALVE, sock, "--journal", str(path))
    try:
        gateway = Gateway(sock)
        link = SocketLink(load_once(VALVE), sock, fingerprint(VALVE, None),
                          Identity("alice", "operator", "terminal", "alice"), True)
        assert link.first_frame.wait(HANG_GUARD_S)

        def opcua(state: str) -> bool:
            view = link.view()
            return view is not None and any(s.name == "opcua" and s.state == state
                                            for s in view.services)
        wait_for(lambda: opcua("serving"), "the gateway serving, in the frames")
        app = PlcHmiApp(link, live=False, show_measured=False)
        async with app.run_test(size=(120, 36)) as pilot:
            app.driver.advance(100_000)
            await settle(pilot)
            assert "OPC UA: no clients" in region_text(app, "#status")
            gateway.process.kill()
            gateway.process.wait(HANG_GUARD_S)
            wait_for(lambda: opcua("failed"), "the gateway's loss, in the frames")
            app.driver.advance(100_000)
            await settle(pilot)
            assert "OPC UA FAILED" in region_text(app, "#status")
            assert "OPC UA FAILED" in region_text(app, "#banners")
        link.leave()
    finally:
        cell.stop()
    events = [(e["event"], e["message"]) for e in journal(path)
              if e["type"] == "session" and e["event"].startswith("opcua-")]
    assert [e for e, _ in events] == ["opcua-serving", "opcua-failed"], events
    assert "its connection closed" in events[1][1]

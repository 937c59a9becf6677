"""The OPC UA server's doors under a flood of short connections: what a closed connection
leaves behind. An asyncua server in this process with plchmi's doors installed, real
sockets; every wait is on state, bounded only by a hang guard."""

from __future__ import annotations

import asyncio
import gc
import socket

import pytest

asyncua = pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")
from asyncua import Server  # noqa: E402

from hmi.opcua.doors import CellProcessor, install  # noqa: E402
from hmi.opcua.users import TrustList  # noqa: E402
from tests.opcua_cells import free_port  # noqa: E402

HANG_GUARD_S = 60.0
CONNECTIONS = 200
# A HEL whose header claims ~2 GiB: the server closes it at once (BoundedProtocol).
HOSTILE_HEL = b"HELF" + (2 ** 31 - 1).to_bytes(4, "little") + b"\0" * 20


def _connect_and_send(port: int) -> None:
    with socket.create_connection(("127.0.0.1", port), timeout=HANG_GUARD_S) as s:
        s.sendall(HOSTILE_HEL)
        s.recv(1)  # until the server closes it


async def _until(condition, what: str) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + HANG_GUARD_S
    while not condition():
        assert loop.time() < end, f"still waiting for {what}"
        await asyncio.sleep(0.01)


def _processors() -> int:
    gc.collect()
    return sum(1 for o in gc.get_objects() if isinstance(o, CellProcessor))


async def _flood(tmp_path) -> tuple[int, int]:
    async def gate(processor, params):
        return None, "no sign-in in this test"

    install(gate, lambda ticket: None, TrustList(tmp_path / "pki"))
    server = Server()
    await server.init()
    port = free_port()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}")
    await server.start()
    try:
        before = _processors()
        for _ in range(CONNECTIONS):
            await asyncio.to_thread(_connect_and_send, port)
        bserver = server.bserver
        assert bserver is not None
        await _until(lambda: not bserver.clients, "every connection closed")
        await _until(lambda: all(t.done() for t in list(bserver.closing_tasks)),
                     "every closed connection's closing task done")
        await asyncio.sleep(0)  # (the done callbacks run on the next turn of the loop)
        return len(bserver.closing_tasks), _processors() - before
    finally:
        await server.stop()


def test_a_closed_connection_leaves_nothing_behind(tmp_path):
    """200 connections, each closed by the server at its hostile HEL: none of them is still
    held once closed (asyncua kept each one's closing task, and with it its processor and
    buffers, until a sweep every 10 s: at thousands of connections a second, tens of
    megabytes in the gateway)."""
    kept_tasks, kept_processors = asyncio.run(_flood(tmp_path))
    assert kept_tasks == 0
    assert kept_processors == 0


async def _read_over_a_bare_channel(tmp_path, nodes: int) -> tuple[int, str, int]:
    """A Read of `nodes` node ids sent on an open secure channel without a session (any
    client may open one): (the request's bytes, what the server answered, the connections
    it still holds)."""
    from asyncua import Client, ua
    from asyncua.ua.ua_binary import struct_to_binary

    from hmi.opcua.doors import apply_limits

    async def gate(processor, params):
        return None, "no sign-in in this test"

    install(gate, lambda ticket: None, TrustList(tmp_path / "pki"))
    server = Server()
    await server.init()
    apply_limits(server, 100.0)
    port = free_port()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}")
    await server.start()
    try:
        client = Client(f"opc.tcp://127.0.0.1:{port}", timeout=HANG_GUARD_S)
        await client.connect_socket()
        await client.send_hello()
        await client.open_secure_channel()
        params = ua.ReadParameters()
        params.NodesToRead = [ua.ReadValueId(NodeId=ua.NodeId(100_000 + i, 0),
                                             AttributeId=ua.AttributeIds.Value)
                              for i in range(nodes)]
        try:
            await client.uaclient.read(params)
            answer = "results"
        except ua.UaStatusCodeError as exc:
            answer = type(exc).__name__
        bserver = server.bserver
        assert bserver is not None
        if answer == "BadRequestTooLarge":
            await _until(lambda: not bserver.clients, "the connection closed")
        held = len(bserver.clients)
        client.disconnect_socket()
        return len(struct_to_binary(params)), answer, held
    finally:
        await server.stop()


def test_a_request_larger_than_the_limit_is_refused_and_its_connection_closed(tmp_path):
    """asyncua takes requests of up to 100 MB, every chunk held until the last: any client
    that opens a channel (no sign-in needed) could have the gateway hold 100 MB per
    connection. A request over MAX_REQUEST_BYTES gets BadRequestTooLarge and its connection
    is closed; one under it is read and answered (here: no session, so access denied)."""
    from hmi.opcua.doors import MAX_REQUEST_BYTES

    size, answer, held = asyncio.run(_read_over_a_bare_channel(tmp_path, 80_000))
    assert size > MAX_REQUEST_BYTES
    assert (answer, held) == ("BadRequestTooLarge", 0)
    size, answer, held = asyncio.run(_read_over_a_bare_channel(tmp_path, 1_000))
    assert size < MAX_REQUEST_BYTES
    assert (answer, held) == ("BadUserAccessDenied", 1)

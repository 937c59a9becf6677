"""serve-plant's server keeps its connection slots from clients that hold them without using
them: one whose request trickles in, one that never takes its answers; and it stops without
a traceback with clients connected. In process, on real loopback sockets, with short
deadlines; every wait is bounded (and none is on a condition that may not come)."""

from __future__ import annotations

import asyncio
import socket
import struct

from hmi.plant.modbus.tcp_server import ModbusServer, Tables

SIZES = {"coil": 16, "di": 2000, "hr": 16, "ir": 16}
BOUND = 120.0  # seconds: far past every deadline below, on a loaded machine too


def request(tid: int) -> bytes:
    pdu = b"\x02\x00\x00\x07\xd0"  # read 2000 discrete inputs: a 255-byte answer
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu


async def started(**limits) -> tuple[ModbusServer, int, list[str]]:
    log: list[str] = []
    server = ModbusServer(Tables(SIZES), 1, log.append, **limits)
    return server, await server.start("127.0.0.1", 0), log


async def closed_by_server(reader: asyncio.StreamReader) -> bool:
    async with asyncio.timeout(BOUND):
        while True:
            try:
                if not await reader.read(65536):
                    return True
            except ConnectionError:
                return True


async def test_a_request_that_trickles_in_loses_its_slot():
    """A byte now and then: the request never completes in time, the slot is freed (it was
    held as long as each byte came within the idle timeout)."""
    server, port, log = await started(request_s=0.3, idle_s=60)
    try:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        frame = request(1)
        writer.write(frame[:1])  # begun
        await writer.drain()

        async def trickle():
            for byte in frame[1:]:
                await asyncio.sleep(0.2)
                writer.write(bytes([byte]))
                await writer.drain()
        task = asyncio.create_task(trickle())
        assert await closed_by_server(reader)
        task.cancel()
        writer.close()
        assert any("a request begun did not all come within 0.3 s" in line for line in log)
        assert server.counts.slow_closed == 1 and server.counts.requests == 0
    finally:
        await server.close()


async def test_a_client_that_never_reads_its_answers_loses_its_slot():
    server, port, log = await started(write_s=0.5)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # fills at once
    sock.setblocking(False)
    try:
        await asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port))
        # requests by the thousand at a time: the answers (255 bytes each) fill the
        # server's socket buffers (megabytes on loopback) within a few sends
        batch = b"".join(request(tid) for tid in range(4096))
        at = 0
        async with asyncio.timeout(BOUND):
            while not server.counts.slow_closed:
                try:
                    at = (at + sock.send(batch[at:])) % len(batch)
                except BlockingIOError:  # the server stopped reading: it waits to send
                    await asyncio.sleep(0.05)
                except ConnectionError:
                    break
                await asyncio.sleep(0)
        assert server.counts.slow_closed == 1
        assert any("took none of its answers for 0.5 s" in line for line in log)
        assert not server._open  # the slot is free
    finally:
        sock.close()
        await server.close()


async def test_stopping_with_clients_connected_says_so_without_a_traceback():
    """Ctrl-C with a client connected printed an asyncio traceback per open connection
    (Python 3.11 asks a cancelled handler task for its exception)."""
    loop = asyncio.get_running_loop()
    reported: list[dict] = []
    loop.set_exception_handler(lambda _, context: reported.append(context))
    server, port, log = await started()
    clients = [await asyncio.open_connection("127.0.0.1", port) for _ in range(3)]
    async with asyncio.timeout(BOUND):
        while len(server._open) < 3:
            await asyncio.sleep(0.01)
    await server.close()
    for _ in range(3):
        await asyncio.sleep(0)
    assert reported == []
    assert sum("connection closed: the server stops" in line for line in log) == 3
    for _, writer in clients:
        writer.close()

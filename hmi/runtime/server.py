"""The runtime's local endpoint: screens attach over a Unix socket (mode 0600).

One thread runs an event loop for every screen. A message is 4 bytes of length (big-endian)
then that many bytes of JSON (hmi.wire); a screen's message is at most MAX_IN bytes and must
arrive whole within MESSAGE_S once begun, its first must be a Hello within HELLO_S. Anything
else — too long, not JSON, not the type it claims, a field out of bounds — is malformed:
that screen is disconnected and journalled, the others and the scan never notice.

Frames go out at most every PUSH_S, right after a scan (the scan thread nudges the loop,
so the frame's work falls in the period's idle time), and only to a screen that took its
last one: a screen whose unsent bytes exceed HIGH_WATER gets none (its next frame carries
everything since the last it took), one whose unsent bytes exceed STUCK_BYTES (answers it
never reads) is disconnected. Every per-screen buffer is bounded.

A command is carried out in a worker thread (a step of many scans must not stop the frames
of the other screens); a screen's messages are carried out in the order it sent them, and the
frame that shows a command's effect goes before its answer.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from hmi.runtime.hub import Client, Hub
from hmi.runtime.place import socket_address
from hmi.wire import messages as m
from hmi.wire.codec import WireError
from hmi.wire.framing import HEADER, MAX_IN, frame

HELLO_S = 5.0
MESSAGE_S = 30.0
PUSH_S = 0.05
HIGH_WATER = 256 * 1024
STUCK_BYTES = 4 * 1024 * 1024
MAX_CLIENTS = 32


class Malformed(Exception):
    """A screen's message that is not a message: it is disconnected."""


@dataclass(eq=False)
class _Connection:
    writer: asyncio.StreamWriter
    client: Client | None = None

    def backlog(self) -> int:
        transport = self.writer.transport
        return transport.get_write_buffer_size() if not transport.is_closing() else 0

    def send(self, data: bytes) -> None:
        if not self.writer.transport.is_closing():
            self.writer.write(frame(data))


async def read_message(reader: asyncio.StreamReader, most: int) -> bytes:
    """One length-prefixed message (EOF: IncompleteReadError)."""
    header = await reader.readexactly(HEADER)
    size = int.from_bytes(header, "big")
    if not 0 < size <= most:
        raise Malformed(f"a message of {size} bytes (at most {most})")
    try:
        return await asyncio.wait_for(reader.readexactly(size), MESSAGE_S)
    except TimeoutError:
        raise Malformed(f"a message of {size} bytes not sent whole within "
                        f"{MESSAGE_S:g} s") from None


class SocketServer:
    def __init__(self, hub: Hub, path: Path, max_clients: int = MAX_CLIENTS):
        self.hub = hub
        self.path = path
        self.max_clients = max_clients
        self.codec = hub.codec
        self.connections: set[_Connection] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._failure: BaseException | None = None
        self._stopping: asyncio.Event | None = None
        self._why = ""
        self._due = 0.0  # monotonic time of the next frames (the scan's nudge)
        self._nudged = False
        hub.backlog = self.backlog

    def backlog(self) -> int:
        """The most bytes any screen has not taken yet."""
        return max((c.backlog() for c in list(self.connections)), default=0)

    # -- life cycle -----------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="plchmi-screens", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._failure is not None:
            raise self._failure
        self.hub.session.scan_listeners.append(self._on_scan)

    def stop(self, why: str, timeout: float = 5.0) -> None:
        """Tell every screen why (Closing), close their connections and the socket."""
        if self._on_scan in self.hub.session.scan_listeners:
            self.hub.session.scan_listeners.remove(self._on_scan)
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None:
            self._why = why
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stopping.set)
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:
            if not self._ready.is_set():
                self._failure = exc
                self._ready.set()

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()  # a socket left by a runtime that died (we hold the lock)
        old = os.umask(0o177)  # the socket is its owner's only (0600)
        try:
            with socket_address(self.path) as address:
                sock.bind(address)
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        sock.listen(64)
        server = await asyncio.start_unix_server(self._serve, sock=sock, limit=MAX_IN)
        self._ready.set()
        pusher = asyncio.create_task(self._push_forever())
        try:
            await self._stopping.wait()
        finally:
            pusher.cancel()
            closing = self.hub.encode(m.Closing(self._why or "the runtime stops"))
            for connection in list(self.connections):
                connection.send(closing)
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(connection.writer.drain(), 1.0)
                connection.writer.close()
            server.close()
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()

    # -- frames ---------------------------------------------------------------------------
    def _on_scan(self, snapshot: object) -> None:
        """In the scan thread, after each scan: wake the loop when frames are due, so that
        their work follows a scan instead of falling on the next one's start."""
        now = time.monotonic()
        if now >= self._due and not self._nudged and self._loop is not None:
            self._nudged = True
            self._due = now + PUSH_S
            with contextlib.suppress(RuntimeError):  # the loop is closing
                self._loop.call_soon_threadsafe(self._push)

    async def _push_forever(self) -> None:
        """Frames even without scans (paused, virtual time): ticks, run state, control."""
        while True:
            await asyncio.sleep(PUSH_S * 2)
            if time.monotonic() >= self._due:
                self._push()

    def _push(self) -> None:
        self._nudged = False
        for connection in list(self.connections):
            client = connection.client
            if client is None:
                continue
            backlog = connection.backlog()
            if backlog > STUCK_BYTES:
                self._drop(connection, "client-lost", "stopped reading (its unread answers "
                           f"passed {STUCK_BYTES // 1024} KiB): disconnected")
                continue
            if backlog > HIGH_WATER:
                client.dropped += 1  # it gets the next one it can take, with all since
                continue
            data = self.hub.frame(client)
            if data is not None:
                connection.send(data)

    def _drop(self, connection: _Connection, event: str, why: str) -> None:
        self.connections.discard(connection)
        if connection.client is not None:
            self.hub.detach(connection.client, event, why)
            connection.client = None
        connection.writer.transport.abort()

    # -- one screen -----------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        connection = _Connection(writer)
        transport = writer.transport
        transport.set_write_buffer_limits(high=HIGH_WATER)
        event, why = "client-lost", "its connection closed"
        try:
            if len(self.connections) >= self.max_clients:
                connection.send(self.hub.encode(m.Refused(
                    f"{self.max_clients} screens are attached already, the most this "
                    "runtime serves")))
                await writer.drain()
                return
            try:
                data = await asyncio.wait_for(read_message(reader, MAX_IN), HELLO_S)
            except TimeoutError:
                raise Malformed(f"no Hello within {HELLO_S:g} s") from None
            hello = self._decode(data)
            if not isinstance(hello, m.Hello):
                raise Malformed(f"a {type(hello).__name__} before its Hello")
            client, answer = await asyncio.to_thread(self.hub.attach, hello)
            connection.send(self.hub.encode(answer))
            if client is None:
                await writer.drain()
                return
            connection.client = client
            self.connections.add(connection)
            first = self.hub.frame(client, force=True)
            if first is not None:
                connection.send(first)
            while True:
                message = self._decode(await read_message(reader, MAX_IN))
                if isinstance(message, m.Bye):
                    event, why = "client-left", ("left, the cell stopping" if message.stop
                                                 else "left")
                    await asyncio.to_thread(self.hub.handle, client, message)
                    return
                reply = await asyncio.to_thread(self.hub.handle, client, message)
                if reply is not None and connection.client is not None:
                    shown = self.hub.frame(client)
                    if shown is not None:
                        connection.send(shown)
                    connection.send(self.hub.encode(reply))
        except (asyncio.IncompleteReadError, ConnectionError):
            pass  # the screen went away: its connection closed (lost)
        except asyncio.CancelledError:
            # the runtime stops with this screen still attached: its loop ends. Ended
            # here, not re-raised: asyncio (3.11) would log the cancelled task's callback
            # as an error in the runtime's log.
            pass
        except (Malformed, WireError, ValueError) as exc:
            event, why = "client-lost", f"sent a malformed message ({exc}): disconnected"
            with contextlib.suppress(Exception):
                connection.send(self.hub.encode(m.Refused(f"malformed message: {exc}")))
        finally:
            self.connections.discard(connection)
            stopping = self._stopping is not None and self._stopping.is_set()
            if stopping and event == "client-lost":
                event, why = "client-left", "disconnected: the runtime stops"
            if connection.client is not None:
                self.hub.detach(connection.client, event, why)
            with contextlib.suppress(Exception):
                writer.close()

    def _decode(self, data: bytes) -> m.ClientMessage:
        message: m.ClientMessage = self.codec.loads(data, m.ClientMessage)
        return message

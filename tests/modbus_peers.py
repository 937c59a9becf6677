"""Independent Modbus peers for the tests: none of them shares code with hmi.plant.

* :class:`TkDevice`: modbus-tk's TCP server (an implementation of its own, from PyPI) in
  this process, recording every request PDU it handles and every connection;
* :class:`ScriptedDevice`: a plain-socket server whose answers the test gives byte for byte
  (wrong ones on purpose), or that closes every connection at once;
* :func:`frame` / :func:`read_frames`: Modbus TCP frames packed and unpacked with struct, for
  plain-socket clients.

Every wait has a deadline and polls a state; none sleeps a fixed time to let things happen.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections.abc import Callable

import modbus_tk.defines as tk
from modbus_tk import hooks, modbus_tcp

WAIT = 120.0  # seconds: a deadline on a state, not a sleep (loaded 2-core machines)

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(test: Callable[[], bool], what: str, timeout: float = WAIT) -> None:
    deadline = time.monotonic() + timeout
    while not test():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def frame(tid: int, pdu: bytes, unit: int = 1, protocol: int = 0) -> bytes:
    return struct.pack(">HHHB", tid, protocol, len(pdu) + 1, unit) + pdu


def recv_exactly(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError(f"closed after {len(data)} of {n} bytes")
        data += chunk
    return data


def read_frame(sock: socket.socket) -> tuple[int, int, bytes]:
    """(transaction id, unit, PDU) of one frame; the header's protocol id must be 0."""
    tid, protocol, length, unit = struct.unpack(">HHHB", recv_exactly(sock, 7))
    assert protocol == 0 and 2 <= length <= 254, (tid, protocol, length)
    return tid, unit, recv_exactly(sock, length - 1)


def read_frames(sock: socket.socket) -> list[tuple[int, int, bytes]]:
    """Every frame until the other side closes."""
    out = []
    while True:
        try:
            out.append(read_frame(sock))
        except ConnectionError:
            return out


def closed_by_peer(sock: socket.socket, timeout: float = WAIT) -> bool:
    """Whether the other side closes the connection within `timeout` (all data read)."""
    sock.settimeout(timeout)
    try:
        while sock.recv(4096):
            pass
    except TimeoutError:
        return False
    except ConnectionResetError:
        return True
    return True


class TkDevice:
    """modbus-tk's server, unit 1, with coils, discrete inputs, holding and input registers
    from address 0; `requests` gets every request PDU handled, `connections` counts."""

    def __init__(self, coils: int = 16, inputs: int = 16, holding: int = 8,
                 input_registers: int = 8, unit: int = 1):
        self.port = free_port()
        self.server = modbus_tcp.TcpServer(port=self.port, address="127.0.0.1")
        self.slave = self.server.add_slave(unit)
        for name, kind, size in (("coil", tk.COILS, coils), ("di", tk.DISCRETE_INPUTS, inputs),
                                 ("hr", tk.HOLDING_REGISTERS, holding),
                                 ("ir", tk.ANALOG_INPUTS, input_registers)):
            if size:
                self.slave.add_block(name, kind, 0, size)
        self.requests: list[bytes] = []
        self.connections = 0
        self._lock = threading.Lock()

    def _on_request(self, args) -> None:
        slave, pdu = args
        if slave is self.slave:
            with self._lock:
                self.requests.append(bytes(pdu))

    def _on_connect(self, args) -> None:
        if args[0] is self.server:
            self.connections += 1

    def functions(self) -> list[int]:
        with self._lock:
            return [pdu[0] for pdu in self.requests]

    def writes(self) -> list[bytes]:
        with self._lock:
            return [pdu for pdu in self.requests if pdu[0] in (5, 6, 15, 16, 22, 23)]

    def get(self, table: str, address: int, count: int = 1) -> list[int]:
        return list(self.slave.get_values(table, address, count))

    def set(self, table: str, address: int, values: list[int]) -> None:
        self.slave.set_values(table, address, values)

    def __enter__(self) -> TkDevice:
        hooks.install_hook("modbus.Slave.handle_request", self._on_request)
        hooks.install_hook("modbus_tcp.TcpServer.on_connect", self._on_connect)
        self.server.start()

        def listening() -> bool:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
            except OSError:
                return False
            return True
        wait_until(listening, "modbus-tk to listen")
        wait_until(lambda: self.connections >= 1, "the probe connection to be seen")
        self.connections = 0
        return self

    def __exit__(self, *exc: object) -> None:
        hooks.uninstall_hook("modbus.Slave.handle_request", self._on_request)
        hooks.uninstall_hook("modbus_tcp.TcpServer.on_connect", self._on_connect)
        # modbus-tk's server loop sees its stop only when its select() returns, which waits
        # up to 1 s for a socket to be ready: a connection (no longer counted) wakes it.
        stopper = threading.Thread(target=self.server.stop, daemon=True)
        stopper.start()
        deadline = time.monotonic() + WAIT
        while stopper.is_alive() and time.monotonic() < deadline:
            with contextlib.suppress(OSError):
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
            stopper.join(0.02)
        assert not stopper.is_alive(), "modbus-tk's server did not stop"


class Closing(bytes):
    """An answer after which the device closes the connection."""


# answer(connection number from 1, request frame) -> the bytes to send back (a Closing to
# close the connection after them), or None to close it without answering.
Script = Callable[[int, bytes], bytes | None]


class ScriptedDevice:
    """A plain-socket device: each request frame it receives is answered by `script`; with
    no script, every connection is closed as soon as it is accepted."""

    def __init__(self, script: Script | None = None):
        self.script = script
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(64)
        self.listener.settimeout(0.2)
        self.port = self.listener.getsockname()[1]
        self.connections = 0
        self.requests: list[bytes] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._conns: list[socket.socket] = []

    def __enter__(self) -> ScriptedDevice:
        thread = threading.Thread(target=self._accept, daemon=True)
        thread.start()
        self._threads.append(thread)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        # Wake the accept() and the receives now, not at their next 0.2 s timeout (Linux).
        for sock in (self.listener, *self._conns):
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        for thread in list(self._threads):
            thread.join(5)
        self.listener.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            if self.script is None:
                conn.close()
                continue
            self._conns.append(conn)
            thread = threading.Thread(target=self._serve, args=(conn, self.connections),
                                      daemon=True)
            thread.start()
            self._threads.append(thread)

    def _serve(self, conn: socket.socket, number: int) -> None:
        assert self.script is not None
        conn.settimeout(0.2)
        with conn:
            while not self._stop.is_set():
                try:
                    head = recv_exactly(conn, 7)
                    length = struct.unpack(">H", head[4:6])[0]
                    request = head + recv_exactly(conn, length - 1)
                except TimeoutError:
                    continue
                except (ConnectionError, OSError):
                    return
                self.requests.append(request)
                answer = self.script(number, request)
                if answer is None:
                    return
                try:
                    conn.sendall(answer)
                except OSError:
                    return
                if isinstance(answer, Closing):
                    return


def answer_to(request: bytes, pdu: bytes, *, tid_delta: int = 0, unit: int | None = None,
              protocol: int = 0, length_delta: int = 0) -> bytes:
    """An answer frame carrying `pdu` for `request`, optionally wrong in its header."""
    tid, _, _, req_unit = struct.unpack(">HHHB", request[:7])
    return struct.pack(">HHHB", (tid + tid_delta) & 0xFFFF, protocol,
                       len(pdu) + 1 + length_delta,
                       req_unit if unit is None else unit) + pdu


def good_answer(request: bytes, bits: list[int] | None = None) -> bytes:
    """A correct answer to a read of bits or registers, or to a write (its echo)."""
    pdu = request[7:]
    fc = pdu[0]
    count = struct.unpack(">H", pdu[3:5])[0]
    if fc in (1, 2):
        values = (bits or []) + [0] * count
        data = bytearray((count + 7) // 8)
        for i in range(count):
            if values[i]:
                data[i // 8] |= 1 << (i % 8)
        return answer_to(request, bytes((fc, len(data))) + bytes(data))
    if fc in (3, 4):
        return answer_to(request, bytes((fc, 2 * count)) + bytes(2 * count))
    if fc in (15, 16):
        return answer_to(request, pdu[:5])
    return answer_to(request, pdu)  # 5, 6, 22: the echo

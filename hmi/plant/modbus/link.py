"""One Modbus TCP connection to a device, synchronous: a request goes out, its answer is
awaited, checked (modbus_frame.check_answer) and returned. The scan is synchronous, so this
is all the client needs: one request at a time, in order, never pipelined.

Our own, over a plain socket, rather than pymodbus's client: each failure must come out as
what it was, at once, and an answer that breaks the protocol must never reach the scan
(pymodbus 3.16's client took an FC 1 answer for an FC 2 request's inputs, accepted a byte
count larger than the data, and let an empty bit answer through to an IndexError in the
scan). The failures, each closing the socket so that a late or stray answer can never be
taken for the next request's:

* :class:`LinkClosed`: the device closed the connection (or reset it);
* :class:`NoAnswer`: no whole answer within the timeout;
* :class:`InvalidAnswer`: an answer came that breaks the protocol, with what was wrong;

and :class:`ExceptionAnswer`, a valid exception response, after which the connection is
kept (the device answered; it refused).
"""

from __future__ import annotations

import select
import socket
import time

from hmi.plant.modbus.frame import (
    HEADER_SIZE,
    MAX_ADU,
    Answer,
    FrameError,
    adu,
    check_answer,
    exception_name,
    parse_header,
)
from hmi.timefmt import format_duration


class LinkError(Exception):
    """The connection is unusable (and has been closed); the message says why."""


class ConnectFailed(LinkError):
    pass


class LinkClosed(LinkError):
    pass


class NoAnswer(LinkError):
    pass


class InvalidAnswer(LinkError):
    pass


class ExceptionAnswer(Exception):
    def __init__(self, code: int):
        super().__init__(f"{exception_name(code)} (exception {code})")
        self.code = code
        self.name = exception_name(code)


class ModbusLink:
    def __init__(self, host: str, port: int, unit: int, timeout_us: int):
        self.host, self.port, self.unit = host, port, unit
        self.timeout_s = timeout_us / 1e6
        self.limit = format_duration(timeout_us)
        self.sock: socket.socket | None = None
        self.transaction = 0

    @property
    def is_open(self) -> bool:
        return self.sock is not None

    def connect(self) -> None:
        """Open the connection; ConnectFailed with the reason in plain words."""
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:
            raise ConnectFailed(os_reason(exc)) from None
        self.sock = sock

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        self.sock = None

    def request(self, pdu: bytes, what: str) -> Answer:
        """Send one request PDU, return its checked answer (never an exception response:
        that raises ExceptionAnswer). `what` names the request in the errors."""
        sock = self.sock
        if sock is None:
            raise LinkClosed("not connected")
        self.transaction = (self.transaction + 1) & 0xFFFF
        try:
            self._nothing_pending(sock, what)
            sock.sendall(adu(self.transaction, self.unit, pdu))
            frame = self._receive(sock, what)
        except OSError as exc:
            self.close()
            raise LinkClosed(f"the connection was closed by the device during {what} "
                             f"({os_reason(exc)})") from None
        except LinkError:
            self.close()
            raise
        try:
            answer = check_answer(pdu, self.transaction, self.unit, frame)
        except FrameError as exc:
            self.close()
            raise InvalidAnswer(f"invalid answer to {what}: {exc}") from None
        if answer.exception is not None:
            raise ExceptionAnswer(answer.exception)
        return answer

    def _nothing_pending(self, sock: socket.socket, what: str) -> None:
        """Before a request: the device has sent nothing unasked, and not closed."""
        readable, _, _ = select.select([sock], [], [], 0)
        if not readable:
            return
        data = sock.recv(MAX_ADU)
        if not data:
            raise LinkClosed(f"the connection was closed by the device (before {what})")
        raise InvalidAnswer(f"invalid answer: {len(data)} bytes came unasked before {what}")

    def _receive(self, sock: socket.socket, what: str) -> bytes:
        """One whole answer frame, within the timeout; its header is checked as soon as it
        is in, so a frame that cannot be Modbus fails at once rather than at the timeout."""
        deadline = time.monotonic() + self.timeout_s
        data = b""
        need = HEADER_SIZE
        while len(data) < need:
            left = deadline - time.monotonic()
            if left <= 0:
                raise NoAnswer(self._no_answer(what, data, need))
            sock.settimeout(left)
            try:
                chunk = sock.recv(MAX_ADU)
            except TimeoutError:
                raise NoAnswer(self._no_answer(what, data, need)) from None
            if not chunk:
                where = f"after {len(data)} bytes of the answer" if data else \
                    "before answering"
                raise LinkClosed(f"the connection was closed by the device {where} "
                                 f"to {what}")
            data += chunk
            if need == HEADER_SIZE and len(data) >= HEADER_SIZE:
                try:
                    need = parse_header(data).frame_size
                except FrameError as exc:
                    raise InvalidAnswer(f"invalid answer to {what}: {exc}") from None
        if len(data) > need:
            raise InvalidAnswer(f"invalid answer to {what}: {len(data) - need} bytes "
                                "beyond the length its header gives")
        return data

    def _no_answer(self, what: str, data: bytes, need: int) -> str:
        if not data:
            return f"no answer to {what} within {self.limit}"
        return f"incomplete answer to {what}: {len(data)} of {need} bytes within {self.limit}"


def os_reason(exc: OSError) -> str:
    if isinstance(exc, TimeoutError | socket.timeout):
        return "no answer (connect timed out)"
    if isinstance(exc, socket.gaierror):
        return f"unknown host ({exc.strerror})"
    return exc.strerror or type(exc).__name__

"""A small Modbus TCP server over asyncio, as the Modbus Application Protocol v1.1b3 says.

`serve-plant` used pymodbus 3.16's server, which answers an unknown function code with
function byte 0x80 instead of FC | 0x80, a bad quantity with exception 1 (or 4, for FC 0x81)
instead of 3, takes any FC 5 value other than 0x0000 as ON, answers FC 24 with a FIFO it
makes up, and answers only the first of several requests pipelined on one connection. This
is the whole of what serve-plant needs, with none of that:

* a request is checked in the order of the specification's state diagrams: the function
  code (exception 1, Illegal Function), the structure and the quantity (exception 3,
  Illegal Data Value; FC 5's value too), the address range (exception 2, Illegal Data
  Address); then the device may still refuse it (exception 6 while `busy`; exception 4 if
  our own code fails). A request for another unit id gets exception 11 (Gateway Target
  Device Failed to Respond): the answer of a gateway for a device it does not have;
* requests pipelined on a connection are each answered, in order; a frame that cannot be
  framed (protocol id not 0, length field outside 2..254) closes the connection, with a
  log line, since nothing after it can be trusted to start a frame;
* at most `max_connections` connections are open at once (more are closed at once, with a
  log line a second at most), and a connection with no whole request for `idle_s` is closed;
  so is one whose request, once begun, has not all come within `request_s` (a client that
  trickles its bytes would otherwise keep its slot: 16 clients sending a byte a second held
  every one), and one that does not take its answers within `write_s` (a client that never
  reads held its slot forever, the server waiting to send).

The tables are plain Python lists; the owner is told before a read (to put fresh values
in) and after a write (to take the orders from them).
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from collections import Counter
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from hmi.plant.modbus.frame import (
    BIT_READS,
    COIL_OFF,
    COIL_ON,
    GATEWAY_TARGET_FAILED,
    HEADER_SIZE,
    ILLEGAL_DATA_ADDRESS,
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    MASK_WRITE_REGISTER,
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_READ_WRITE_WRITE,
    MAX_WRITE_COILS,
    MAX_WRITE_REGISTERS,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    READ_WRITE_REGISTERS,
    SERVER_DEVICE_FAILURE,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_COIL,
    WRITE_SINGLE_REGISTER,
    FrameError,
    adu,
    bit_bytes,
    exception_name,
    pack_bits,
    pack_registers,
    parse_header,
    unpack_bits,
    unpack_registers,
)

MAX_CONNECTIONS = 16
IDLE_S = 60.0
REQUEST_S = 5.0  # a request's bytes, from its first: a Modbus TCP request is at most 260
WRITE_S = 10.0  # an answer's bytes taken by the client
READ_TABLE = {READ_COILS: "coil", READ_DISCRETE_INPUTS: "di", READ_HOLDING_REGISTERS: "hr",
              READ_INPUT_REGISTERS: "ir"}


class Refused(Exception):
    """The request is answered with exception `code`."""

    def __init__(self, code: int, why: str = ""):
        super().__init__(why or exception_name(code))
        self.code = code


@dataclass(frozen=True)
class Request:
    """A request that passed the function code and quantity checks.

    `table`, `address`, `count`: what it reads (or, for a pure write, writes); `values`: what
    a write brings (bits, registers, or FC 22's (and_mask, or_mask)); FC 23's write part is
    `write_address` with `values`.
    """

    function: int
    table: str
    address: int
    count: int
    values: tuple[Any, ...] = ()  # bools for coils, ints for registers
    write_address: int = 0

    @property
    def reads(self) -> bool:
        return self.function in READ_TABLE or self.function == READ_WRITE_REGISTERS

    @property
    def writes(self) -> bool:
        return not self.reads or self.function == READ_WRITE_REGISTERS


def _quantity(count: int, limit: int) -> None:
    if not 1 <= count <= limit:
        raise Refused(ILLEGAL_DATA_VALUE, f"quantity {count}, expected 1 to {limit}")


def _length(pdu: bytes, expected: int) -> None:
    if len(pdu) != expected:
        raise Refused(ILLEGAL_DATA_VALUE, f"{len(pdu)} bytes, expected {expected}")


def decode_request(pdu: bytes) -> Request:
    """A request PDU, checked for function code (exception 1) and structure and quantity
    (exception 3); the address range is the tables' to check."""
    function = pdu[0]
    if function in READ_TABLE:
        _length(pdu, 5)
        address, count = struct.unpack_from(">HH", pdu, 1)
        _quantity(count, MAX_READ_BITS if function in BIT_READS else MAX_READ_REGISTERS)
        return Request(function, READ_TABLE[function], address, count)
    if function in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        _length(pdu, 5)
        address, value = struct.unpack_from(">HH", pdu, 1)
        if function == WRITE_SINGLE_REGISTER:
            return Request(function, "hr", address, 1, (value,))
        if value not in (COIL_ON, COIL_OFF):
            raise Refused(ILLEGAL_DATA_VALUE, f"coil value 0x{value:04X}, expected 0xFF00 "
                          "or 0x0000")
        return Request(function, "coil", address, 1, (value == COIL_ON,))
    if function in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        if len(pdu) < 6:
            raise Refused(ILLEGAL_DATA_VALUE, f"{len(pdu)} bytes, expected at least 6")
        address, count, size = struct.unpack_from(">HHB", pdu, 1)
        coils = function == WRITE_MULTIPLE_COILS
        _quantity(count, MAX_WRITE_COILS if coils else MAX_WRITE_REGISTERS)
        expected = bit_bytes(count) if coils else 2 * count
        if size != expected:
            raise Refused(ILLEGAL_DATA_VALUE, f"byte count {size}, expected {expected}")
        _length(pdu, 6 + size)
        data = pdu[6:]
        values = unpack_bits(data, count) if coils else unpack_registers(data)
        return Request(function, "coil" if coils else "hr", address, count, values)
    if function == MASK_WRITE_REGISTER:
        _length(pdu, 7)
        address, and_mask, or_mask = struct.unpack_from(">HHH", pdu, 1)
        return Request(function, "hr", address, 1, (and_mask, or_mask))
    if function == READ_WRITE_REGISTERS:
        if len(pdu) < 10:
            raise Refused(ILLEGAL_DATA_VALUE, f"{len(pdu)} bytes, expected at least 10")
        address, count, write_address, write_count, size = struct.unpack_from(">HHHHB", pdu, 1)
        _quantity(count, MAX_READ_REGISTERS)
        _quantity(write_count, MAX_READ_WRITE_WRITE)
        if size != 2 * write_count:
            raise Refused(ILLEGAL_DATA_VALUE, f"byte count {size}, expected {2 * write_count}")
        _length(pdu, 10 + size)
        return Request(function, "hr", address, count, unpack_registers(pdu[10:]),
                       write_address)
    raise Refused(ILLEGAL_FUNCTION, f"function code 0x{function:02X} is not served")


class Tables:
    """The four tables, from address 0 to their size; and what a request does to them.

    `on_read(table)` is called before a read is answered, `on_write(table)` after a write
    changed a table: the owner's hooks (serve-plant puts the sensors in, takes the orders).
    """

    def __init__(self, sizes: Mapping[str, int],
                 on_read: Callable[[str], None] = lambda table: None,
                 on_write: Callable[[str], None] = lambda table: None):
        self.sizes = dict(sizes)
        self.bits = {t: [False] * sizes[t] for t in ("coil", "di")}
        self.registers = {t: [0] * sizes[t] for t in ("hr", "ir")}
        self.on_read, self.on_write = on_read, on_write

    def check(self, request: Request) -> None:
        """Exception 2 if the request reaches outside its table."""
        spans = [(request.table, request.address, request.count)]
        if request.function == READ_WRITE_REGISTERS:
            spans.append(("hr", request.write_address, len(request.values)))
        for table, address, count in spans:
            size = self.sizes[table]
            if address + count > size:
                last = address + count - 1
                raise Refused(ILLEGAL_DATA_ADDRESS, f"{table} {address}-{last}: served "
                              f"{table} 0-{size - 1}" if size else f"no {table} served")

    def execute(self, request: Request) -> bytes:
        """Carry out a checked request; the answer PDU."""
        f, a, n = request.function, request.address, request.count
        if f in (WRITE_SINGLE_COIL, WRITE_MULTIPLE_COILS):
            self.bits["coil"][a:a + n] = request.values
        elif f in (WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS):
            self.registers["hr"][a:a + n] = request.values
        elif f == MASK_WRITE_REGISTER:
            and_mask, or_mask = request.values
            hr = self.registers["hr"]
            hr[a] = (hr[a] & and_mask) | (or_mask & ~and_mask & 0xFFFF)
        elif f == READ_WRITE_REGISTERS:  # the write is done before the read (§6.17)
            w = request.write_address
            self.registers["hr"][w:w + len(request.values)] = request.values
        if request.writes:
            self.on_write("coil" if f in (WRITE_SINGLE_COIL, WRITE_MULTIPLE_COILS) else "hr")
        if f in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, MASK_WRITE_REGISTER):
            return self._echo(request)
        if f in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
            return struct.pack(">BHH", f, a, n)
        self.on_read(request.table)
        if request.table in self.bits:
            data = pack_bits(self.bits[request.table][a:a + n])
        else:
            data = pack_registers(self.registers[request.table][a:a + n])
        return bytes((f, len(data))) + data

    @staticmethod
    def _echo(request: Request) -> bytes:
        f, a = request.function, request.address
        if f == WRITE_SINGLE_COIL:
            return struct.pack(">BHH", f, a, COIL_ON if request.values[0] else COIL_OFF)
        return struct.pack(f">BH{len(request.values)}H", f, a, *request.values)


def exception_pdu(function: int, code: int) -> bytes:
    return bytes((function | 0x80, code))


@dataclass
class ServerCounts:
    requests: int = 0
    reads: int = 0
    writes: int = 0
    exceptions: Counter[int] = field(default_factory=Counter)  # code -> answers sent
    connections: int = 0
    refused: int = 0  # connections over the limit
    idle_closed: int = 0
    slow_closed: int = 0  # a request too slow to come, or answers not taken
    bad_frames: int = 0  # connections closed on a frame that could not be framed

    def exceptions_text(self) -> str:
        total = sum(self.exceptions.values())
        if not total:
            return "0 exceptions"
        parts = ", ".join(f"{exception_name(code)} {n}"
                          for code, n in sorted(self.exceptions.items()))
        return f"{total} exceptions: {parts}"


# Called with each request that passed the checks, before it is carried out: may wait
# (a slow or mute device) or raise Refused (a busy one).
Gate = Callable[[Request], Awaitable[None]]


async def _open(request: Request) -> None:
    return None


class ModbusServer:
    def __init__(self, tables: Tables, unit: int, log: Callable[[str], None],
                 gate: Gate = _open, max_connections: int = MAX_CONNECTIONS,
                 idle_s: float = IDLE_S, request_s: float = REQUEST_S,
                 write_s: float = WRITE_S):
        self.tables, self.unit, self.log, self.gate = tables, unit, log, gate
        self.max_connections, self.idle_s = max_connections, idle_s
        self.request_s, self.write_s = request_s, write_s
        self.counts = ServerCounts()
        self._server: asyncio.Server | None = None
        self._open: set[asyncio.Task[None]] = set()
        self._refused_logged_at = -1.0
        self._refused_unlogged = 0

    # -- one request -------------------------------------------------------------------------
    def prepare(self, unit: int, pdu: bytes) -> Request | bytes:
        """The checked request, or the exception answer it gets."""
        if unit != self.unit:
            return exception_pdu(pdu[0], GATEWAY_TARGET_FAILED)
        try:
            request = decode_request(pdu)
            self.tables.check(request)
        except Refused as exc:
            return exception_pdu(pdu[0], exc.code)
        return request

    def execute(self, request: Request) -> bytes:
        try:
            answer = self.tables.execute(request)
        except Exception as exc:  # never let a bug here kill the server: say it, answer 4
            self.log(f"internal error: {type(exc).__name__}: {exc}")
            return exception_pdu(request.function, SERVER_DEVICE_FAILURE)
        if request.writes:
            self.counts.writes += 1
        else:
            self.counts.reads += 1
        return answer

    async def answer(self, unit: int, pdu: bytes) -> bytes:
        self.counts.requests += 1
        prepared = self.prepare(unit, pdu)
        if isinstance(prepared, Request):
            try:
                await self.gate(prepared)
                prepared = self.execute(prepared)
            except Refused as exc:
                prepared = exception_pdu(pdu[0], exc.code)
        if prepared[0] & 0x80:
            self.counts.exceptions[prepared[1]] += 1
        return prepared

    # -- connections -------------------------------------------------------------------------
    async def start(self, host: str, port: int) -> int:
        """Listen; the port bound (0 picks one). OSError if it cannot listen."""
        self._server = await asyncio.start_server(self._accept, host, port)
        bound: int = self._server.sockets[0].getsockname()[1]
        return bound

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._open):
            task.cancel()
        for task in list(self._open):
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        if self._server is not None:
            await self._server.wait_closed()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = _peer(writer)
        if len(self._open) >= self.max_connections:
            self.counts.refused += 1
            self._log_refusal(peer)
            writer.close()
            return
        task = asyncio.current_task()
        assert task is not None
        self._open.add(task)
        self.counts.connections += 1
        self.log(f"client connected from {peer} ({len(self._open)} open)")
        why = "client disconnected"
        try:
            why = await self._serve(reader, writer)
        except asyncio.CancelledError:
            # The server stops (close()). The task ends normally rather than cancelled:
            # Python 3.11's start_server callback asks a cancelled task for its exception
            # and prints a traceback per open connection at Ctrl-C.
            why = "connection closed: the server stops"
        except (ConnectionError, OSError) as exc:
            why = f"client connection lost ({type(exc).__name__})"
        finally:
            self._open.discard(task)
            writer.close()
            self.log(f"{why}: {peer} ({len(self._open)} open)")

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> str:
        """Answer each request in turn, in order, until the client goes or must be sent
        away; why the connection ends."""
        while True:
            begun = False
            try:
                async with asyncio.timeout(self.idle_s):
                    first = await reader.readexactly(1)
                begun = True
                async with asyncio.timeout(self.request_s):
                    head = first + await reader.readexactly(HEADER_SIZE - 1)
                    header = parse_header(head)
                    body = await reader.readexactly(header.length - 1)
            except TimeoutError:
                if begun:
                    self.counts.slow_closed += 1
                    return (f"connection closed: a request begun did not all come within "
                            f"{self.request_s:g} s")
                self.counts.idle_closed += 1
                return f"connection closed: no whole request for {self.idle_s:g} s"
            except asyncio.IncompleteReadError as exc:
                if exc.partial:
                    return f"client disconnected in the middle of a request ({len(exc.partial)}" \
                        " bytes of it came)"
                return "client disconnected"
            except FrameError as exc:
                self.counts.bad_frames += 1
                return f"connection closed: not a Modbus TCP frame ({exc})"
            answer = await self.answer(header.unit, body)
            writer.write(adu(header.transaction, header.unit, answer))
            try:
                async with asyncio.timeout(self.write_s):
                    await writer.drain()
            except TimeoutError:
                self.counts.slow_closed += 1
                writer.transport.abort()  # what is left unsent is dropped
                return (f"connection closed: the client took none of its answers for "
                        f"{self.write_s:g} s")

    def _log_refusal(self, peer: str) -> None:
        now = time.monotonic()
        self._refused_unlogged += 1
        if now - self._refused_logged_at < 1.0:
            return
        more = self._refused_unlogged - 1
        self.log(f"connection from {peer} refused: {self.max_connections} connections are "
                 f"open, the limit" + (f" ({more} more refused since the last line)"
                                       if more else ""))
        self._refused_logged_at = now
        self._refused_unlogged = 0


def _peer(writer: asyncio.StreamWriter) -> str:
    peer = writer.get_extra_info("peername")
    if isinstance(peer, tuple) and len(peer) >= 2:
        return f"{peer[0]}:{peer[1]}"
    return str(peer)

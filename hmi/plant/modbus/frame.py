"""Modbus TCP frames: what our client and `serve-plant` put on the wire, and the checks on
what they receive.

The rules are the Modbus Application Protocol v1.1b3 (function codes, quantities, exception
responses) and the Messaging on TCP/IP Implementation Guide v1.0b (the 7-byte MBAP header:
transaction id, protocol id 0, length of what follows, unit id). Pure functions over bytes,
no sockets: the client (modbus_link) and the server (modbus_tcp_server) do the I/O, and the
tests fuzz these directly.

An answer that breaks a rule is never "probably fine": :func:`check_answer` raises
:class:`FrameError` with what was wrong, in words an engineer can act on ("byte count 0,
expected 1"), and the client treats it as a communication fault.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

MBAP = struct.Struct(">HHHB")  # transaction id, protocol id, length (unit id + PDU), unit id
HEADER_SIZE = MBAP.size  # 7
MAX_PDU = 253  # v1.1b3 §4.1: 256 bytes of serial ADU less address and CRC
MAX_LENGTH = MAX_PDU + 1  # the largest length field: unit id + PDU
MAX_ADU = HEADER_SIZE - 1 + MAX_LENGTH  # 260

READ_COILS = 0x01
READ_DISCRETE_INPUTS = 0x02
READ_HOLDING_REGISTERS = 0x03
READ_INPUT_REGISTERS = 0x04
WRITE_SINGLE_COIL = 0x05
WRITE_SINGLE_REGISTER = 0x06
WRITE_MULTIPLE_COILS = 0x0F
WRITE_MULTIPLE_REGISTERS = 0x10
MASK_WRITE_REGISTER = 0x16
READ_WRITE_REGISTERS = 0x17

FUNCTION_NAMES = {
    READ_COILS: "read coils",
    READ_DISCRETE_INPUTS: "read discrete inputs",
    READ_HOLDING_REGISTERS: "read holding registers",
    READ_INPUT_REGISTERS: "read input registers",
    WRITE_SINGLE_COIL: "write single coil",
    WRITE_SINGLE_REGISTER: "write single register",
    WRITE_MULTIPLE_COILS: "write multiple coils",
    WRITE_MULTIPLE_REGISTERS: "write multiple registers",
    MASK_WRITE_REGISTER: "mask write register",
    READ_WRITE_REGISTERS: "read/write multiple registers",
}
BIT_READS = (READ_COILS, READ_DISCRETE_INPUTS)
REGISTER_READS = (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS)

# v1.1b3 §6: the most one request may carry.
MAX_READ_BITS = 2000  # 0x7D0
MAX_READ_REGISTERS = 125  # 0x7D
MAX_WRITE_COILS = 1968  # 0x7B0
MAX_WRITE_REGISTERS = 123  # 0x7B
MAX_READ_WRITE_WRITE = 121  # 0x79, the write part of FC 23
COIL_ON, COIL_OFF = 0xFF00, 0x0000  # the only two values of FC 5

# v1.1b3 §7: exception codes and their names.
ILLEGAL_FUNCTION = 1
ILLEGAL_DATA_ADDRESS = 2
ILLEGAL_DATA_VALUE = 3
SERVER_DEVICE_FAILURE = 4
SERVER_DEVICE_BUSY = 6
GATEWAY_TARGET_FAILED = 11
EXCEPTION_NAMES = {
    1: "Illegal Function",
    2: "Illegal Data Address",
    3: "Illegal Data Value",
    4: "Server Device Failure",
    5: "Acknowledge",
    6: "Server Device Busy",
    7: "Negative Acknowledge",
    8: "Memory Parity Error",
    10: "Gateway Path Unavailable",
    11: "Gateway Target Device Failed to Respond",
}


def exception_name(code: int) -> str:
    return EXCEPTION_NAMES.get(code, f"exception {code}")


def function_name(code: int) -> str:
    name = FUNCTION_NAMES.get(code)
    return f"0x{code:02X} ({name})" if name else f"0x{code:02X}"


class FrameError(ValueError):
    """A frame that breaks the protocol; the message says what was wrong."""


@dataclass(frozen=True)
class Header:
    transaction: int
    protocol: int
    length: int  # bytes after the length field: unit id + PDU
    unit: int

    @property
    def frame_size(self) -> int:
        return HEADER_SIZE - 1 + self.length


def adu(transaction: int, unit: int, pdu: bytes) -> bytes:
    """A whole Modbus TCP frame: the MBAP header, then the PDU."""
    return MBAP.pack(transaction, 0, len(pdu) + 1, unit) + pdu


def parse_header(data: bytes) -> Header:
    """The MBAP header at the start of `data`; a FrameError if it cannot frame a PDU."""
    if len(data) < HEADER_SIZE:
        raise FrameError(f"{len(data)} bytes, shorter than the 7-byte header")
    header = Header(*MBAP.unpack_from(data))
    if header.protocol != 0:
        raise FrameError(f"protocol id {header.protocol}, expected 0 (not Modbus)")
    if not 2 <= header.length <= MAX_LENGTH:
        raise FrameError(f"length field {header.length}, expected 2 to {MAX_LENGTH}")
    return header


# -- data --------------------------------------------------------------------------------
def pack_bits(values: Sequence[bool]) -> bytes:
    """Bits, first in the low bit of the first byte; the last byte padded with zeros."""
    out = bytearray((len(values) + 7) // 8)
    for i, value in enumerate(values):
        if value:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> tuple[bool, ...]:
    return tuple(bool(data[i // 8] >> (i % 8) & 1) for i in range(count))


def pack_registers(values: Sequence[int]) -> bytes:
    return struct.pack(f">{len(values)}H", *values)


def unpack_registers(data: bytes) -> tuple[int, ...]:
    return struct.unpack(f">{len(data) // 2}H", data)


def bit_bytes(count: int) -> int:
    return (count + 7) // 8


# -- requests (client side) ----------------------------------------------------------------
def read_request(function: int, address: int, count: int) -> bytes:
    return struct.pack(">BHH", function, address, count)


def write_coils_request(address: int, values: Sequence[bool]) -> bytes:
    data = pack_bits(values)
    return struct.pack(">BHHB", WRITE_MULTIPLE_COILS, address, len(values), len(data)) + data


def mask_write_request(address: int, and_mask: int, or_mask: int) -> bytes:
    return struct.pack(">BHHH", MASK_WRITE_REGISTER, address, and_mask, or_mask)


@dataclass(frozen=True)
class Answer:
    """A valid answer: the values read (bits or registers; empty for a write), or the code
    of an exception response."""

    function: int
    values: tuple[int, ...] = ()
    exception: int | None = None


def check_answer(request: bytes, transaction: int, unit: int, frame: bytes) -> Answer:
    """Check a whole answer `frame` against the `request` PDU we sent with `transaction` to
    `unit`; the values it carries, or a FrameError saying what is wrong.

    Everything is checked: the header (transaction id, protocol id, length field against
    the bytes that came, unit id), the function code (ours, or ours | 0x80 for an exception
    response of exactly one code byte), and the body against the request: a read's byte
    count against the quantity asked for, and the byte count against the bytes that came;
    a write's echo of address and quantity (or of the whole request, for FC 5, 6 and 22).
    """
    header = parse_header(frame)
    if header.transaction != transaction:
        raise FrameError(f"transaction id {header.transaction}, expected {transaction} "
                         "(the answer to another request)")
    if header.frame_size != len(frame):
        raise FrameError(f"length field {header.length} but {len(frame) - HEADER_SIZE + 1} "
                         "bytes came")
    if header.unit != unit:
        raise FrameError(f"unit id {header.unit}, expected {unit}")
    pdu = frame[HEADER_SIZE:]
    asked = request[0]
    function = pdu[0]
    if function == asked | 0x80:
        if len(pdu) != 2:
            raise FrameError(f"exception response of {len(pdu)} bytes, expected 2")
        if pdu[1] == 0:
            raise FrameError("exception response with code 0")
        return Answer(asked, exception=pdu[1])
    if function != asked:
        raise FrameError(f"function code {function_name(function)} in the answer to "
                         f"{function_name(asked)}")
    body = pdu[1:]
    if asked in BIT_READS or asked in REGISTER_READS or asked == READ_WRITE_REGISTERS:
        count = struct.unpack_from(">H", request, 3)[0]
        bits = asked in BIT_READS
        expected = bit_bytes(count) if bits else 2 * count
        if not body:
            raise FrameError("no byte count")
        if body[0] != expected:
            raise FrameError(f"byte count {body[0]}, expected {expected} for {count} "
                             f"{'bits' if bits else 'registers'}")
        if len(body) - 1 != expected:
            raise FrameError(f"byte count {expected} but {len(body) - 1} data bytes")
        data = body[1:]
        return Answer(asked, unpack_bits(data, count) if bits else unpack_registers(data))
    # Writes: the answer echoes the request (FC 5, 6, 22) or its address and quantity.
    echo = request[1:] if asked in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER,
                                    MASK_WRITE_REGISTER) else request[1:5]
    if body != echo:
        raise FrameError(f"the answer to {function_name(asked)} echoes {body.hex(' ') or '-'}"
                         f", expected {echo.hex(' ')}")
    return Answer(asked)

"""Property-based fuzzing of Modbus frames (hypothesis).

Random and mutated answers to our client, random requests to our server: neither side ever
crashes, and every frame is classified — a valid answer (with exactly the values asked for),
an exception response, or a refusal that says what was wrong. The reference frames here are
packed with struct in this file, independently of hmi.plant.modbus.frame.
"""

from __future__ import annotations

import socket
import struct
import threading

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hmi.plant.modbus.frame import (
    Answer,
    FrameError,
    adu,
    check_answer,
    mask_write_request,
    read_request,
    write_coils_request,
)
from hmi.plant.modbus.link import (
    ExceptionAnswer,
    InvalidAnswer,
    LinkClosed,
    LinkError,
    ModbusLink,
)
from hmi.plant.modbus.server_process import ServerProcess
from hmi.plant.modbus.tcp_server import ModbusServer, Tables
from tests.conftest import write_project
from tests.modbus_peers import WAIT, frame, read_frame, read_frames
from tests.test_modbus import REGISTER_VALVE

TID, UNIT = 0x0101, 1
MAX_COUNT = {1: 2000, 2: 2000, 3: 125, 4: 125}


@st.composite
def requests(draw) -> tuple[bytes, tuple]:
    """A request our client may send, and values a device may answer it with."""
    kind = draw(st.sampled_from([1, 2, 3, 4, 15, 22]))
    address = draw(st.integers(0, 65535))
    # The values as one draw of bytes (shrunk like any draw): a draw per value, as a
    # hypothesis Random gives (random() per bit, randrange() per register), was ~40 % of
    # these tests' CPU for up to 2000 bits.
    if kind in (1, 2):
        count = draw(st.one_of(st.integers(1, 17), st.integers(1, MAX_COUNT[kind])))
        size = (count + 7) // 8
        raw = draw(st.binary(min_size=size, max_size=size))
        values = tuple(bool(raw[i // 8] >> (i % 8) & 1) for i in range(count))
        return read_request(kind, address, count), values
    if kind in (3, 4):
        count = draw(st.integers(1, 125))
        raw = draw(st.binary(min_size=2 * count, max_size=2 * count))
        values = struct.unpack(f">{count}H", raw)
        return read_request(kind, address, count), values
    if kind == 15:
        coils = draw(st.lists(st.booleans(), min_size=1, max_size=80))
        return write_coils_request(address, coils), ()
    masks = draw(st.tuples(st.integers(0, 0xFFFF), st.integers(0, 0xFFFF)))
    return mask_write_request(address, *masks), ()


def reference_answer(request: bytes, values: tuple, tid: int = TID, unit: int = UNIT) -> bytes:
    """The answer a correct device gives, packed here with struct."""
    fc = request[0]
    if fc in (1, 2):
        data = bytearray((len(values) + 7) // 8)
        for i, v in enumerate(values):
            data[i // 8] |= int(v) << (i % 8)
        pdu = struct.pack(">BB", fc, len(data)) + bytes(data)
    elif fc in (3, 4):
        pdu = struct.pack(f">BB{len(values)}H", fc, 2 * len(values), *values)
    elif fc == 15:
        pdu = request[:5]
    else:
        pdu = request
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


@st.composite
def mutated(draw, answer: bytes) -> bytes:
    data = bytearray(answer)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "set", "insert", "delete", "truncate", "extend"]))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if op == "flip" and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and data:
            data[at] = draw(st.integers(0, 255))
        elif op == "insert":
            data.insert(at, draw(st.integers(0, 255)))
        elif op == "delete" and data:
            del data[at]
        elif op == "truncate":
            del data[at:]
        else:
            data += draw(st.binary(min_size=1, max_size=8))
    if len(data) >= 7 and draw(st.booleans()):
        # Keep the length field true to the bytes, so that the body's checks are reached.
        data[4:6] = struct.pack(">H", min(len(data) - 6, 0xFFFF))
    return bytes(data)


def classify(request: bytes, frame_bytes: bytes) -> Answer | FrameError:
    try:
        answer = check_answer(request, TID, UNIT, frame_bytes)
    except FrameError as exc:
        assert str(exc), "a refusal must say what was wrong"
        return exc
    # Accepted: then it is exactly what was asked for.
    header = struct.unpack(">HHHB", frame_bytes[:7])
    assert header[0] == TID and header[1] == 0 and header[3] == UNIT
    assert header[2] == len(frame_bytes) - 6
    if answer.exception is not None:
        assert frame_bytes[7:] == bytes((request[0] | 0x80, answer.exception))
        assert answer.exception != 0
    elif request[0] in MAX_COUNT:
        count = struct.unpack(">H", request[3:5])[0]
        assert len(answer.values) == count
        width = (count + 7) // 8 if request[0] in (1, 2) else 2 * count
        assert frame_bytes[7:9] == bytes((request[0], width)) and len(frame_bytes) == 9 + width
    else:
        assert answer.values == () and frame_bytes[7] == request[0]
    return answer


@given(requests())
@settings(max_examples=200)
def test_a_correct_answer_is_accepted_with_its_values(case):
    request, values = case
    answer = classify(request, reference_answer(request, values))
    assert isinstance(answer, Answer) and answer.exception is None
    assert answer.values == values


@given(requests(), st.data())
@settings(max_examples=400)
def test_a_mutated_answer_is_accepted_only_if_well_formed_else_refused(case, data):
    request, values = case
    good = reference_answer(request, values)
    classify(request, data.draw(mutated(good)))


@given(requests(), st.binary(max_size=300))
@settings(max_examples=300)
def test_random_bytes_are_refused_with_a_reason(case, junk):
    request, _ = case
    classify(request, junk)


@given(requests(), st.integers(1, 11), st.binary(max_size=3))
def test_an_exception_answer_is_classified_by_its_code(case, code, tail):
    request, _ = case
    exc_frame = adu(TID, UNIT, bytes((request[0] | 0x80, code)) + tail)
    result = classify(request, exc_frame)
    assert isinstance(result, Answer) == (tail == b"")


def _link_over_socketpair(answer: bytes) -> tuple[ModbusLink, threading.Thread]:
    ours, device = socket.socketpair()
    link = ModbusLink("device", 0, UNIT, 2_000_000)
    link.sock = ours

    def respond() -> None:
        with device:
            device.settimeout(WAIT)
            device.recv(300)  # the request
            device.sendall(answer)
    thread = threading.Thread(target=respond, daemon=True)
    thread.start()
    return link, thread


@given(requests(), st.data())
@settings(max_examples=200, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
def test_the_connection_classifies_whatever_comes_back(case, data):
    """Over a real socket pair: whatever the device sends and then closes, the request
    returns a valid answer or raises one of the four failures, never anything else."""
    request, values = case
    good = reference_answer(request, values, tid=1)
    answer = data.draw(st.one_of(st.just(good), mutated(good), st.binary(max_size=300)))
    link, thread = _link_over_socketpair(answer)
    try:
        result = link.request(request, "the request")
    except ExceptionAnswer as exc:
        assert link.is_open and 1 <= exc.code <= 255
    except (LinkClosed, InvalidAnswer) as exc:
        assert not link.is_open and str(exc)
    else:
        assert link.is_open and result.exception is None
        if answer == good:
            assert result.values == values
    finally:
        link.close()
        thread.join(WAIT)
    with pytest.raises(LinkError):
        link.request(request, "after close")


SIZES = {"coil": 16, "di": 16, "hr": 6, "ir": 3}


def make_server() -> tuple[ModbusServer, list[str]]:
    log: list[str] = []
    return ModbusServer(Tables(SIZES), UNIT, log.append), log


@st.composite
def request_pdus(draw) -> bytes:
    """Requests near the rules, to reach every check: a function code, then fields that
    are often right and sometimes not."""
    fc = draw(st.sampled_from([1, 2, 3, 4, 5, 6, 15, 16, 22, 23, 7, 24, 43, 0x81, 0]))
    fields = draw(st.lists(st.one_of(st.integers(0, 20), st.integers(0, 0xFFFF)),
                           max_size=5))
    body = b"".join(struct.pack(">H", f) for f in fields)
    tail = draw(st.binary(max_size=12))
    return bytes((fc,)) + body + tail


@given(st.one_of(request_pdus(), st.binary(min_size=1, max_size=253)),
       st.sampled_from([UNIT, UNIT, 0, 7, 255]))
@settings(max_examples=1000)
def test_the_server_answers_any_request_with_an_answer_or_an_exception(pdu, unit):
    server, log = make_server()
    prepared = server.prepare(unit, pdu)
    answer = prepared if isinstance(prepared, bytes) else server.execute(prepared)
    assert log == []  # no internal error
    assert 2 <= len(answer) <= 253
    if answer[0] == pdu[0] | 0x80 and len(answer) == 2 and answer[0] & 0x80:
        assert answer[1] in (1, 2, 3, 11)
        assert (answer[1] == 11) == (unit != UNIT)
        return
    # Served: our own client's checks accept it as the answer to that request.
    assert unit == UNIT and answer[0] == pdu[0]
    result = check_answer(pdu, TID, unit, adu(TID, unit, answer))
    assert result.exception is None


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    folder = write_project(tmp_path_factory.mktemp("fuzz"),
                           {"project.yaml": REGISTER_VALVE})
    srv = ServerProcess(folder)
    srv.start(WAIT)
    yield srv
    srv.stop()


@given(st.lists(st.one_of(request_pdus().map(lambda p: ("frame", p)),
                          st.binary(min_size=1, max_size=40).map(lambda b: ("raw", b))),
                min_size=1, max_size=8))
@settings(max_examples=60, deadline=None, suppress_health_check=[
    HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
def test_serve_plant_survives_random_streams(served, parts):
    """Frames and raw bytes sent at once on one connection, then the write side closed:
    each answer that comes is a whole frame answering one of ours, in order; then the server
    closes, and still serves the next connection."""
    leading: list[int] = []  # the frames before any raw bytes: framing is certain there
    stream = b""
    for tid, (kind, data) in enumerate(parts, 1):
        if kind == "frame":
            stream += frame(tid, data)
            if len(leading) == tid - 1:
                leading.append(tid)
        else:
            stream += data
    with socket.create_connection(("127.0.0.1", served.port), timeout=WAIT) as sock:
        sock.sendall(stream)
        sock.shutdown(socket.SHUT_WR)
        answers = read_frames(sock)  # each a whole frame, protocol id 0 (read_frame checks)
    tids = [tid for tid, _, _ in answers]
    assert tids[:len(leading)] == leading  # every one answered, in order
    if len(leading) == len(parts):
        assert tids == leading
    with socket.create_connection(("127.0.0.1", served.port), timeout=WAIT) as sock:
        sock.sendall(frame(7, b"\x02\x00\x00\x00\x01"))
        assert read_frame(sock)[0] == 7
    assert not any("internal error" in line for line in served.lines)

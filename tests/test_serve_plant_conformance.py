"""`plchmi serve-plant` (a real process) against clients that are not ours: pyModbusTCP's and
modbus-tk's (PyPI), plain sockets writing frames byte for byte, and Debian's mbpoll where it
is installed. What is checked is the Modbus Application Protocol v1.1b3: the address map,
every exception case, pipelining, the connection limits.
"""

from __future__ import annotations

import re
import shutil
import socket
import struct
import subprocess
import sys

import modbus_tk.defines as tk
import pytest
from modbus_tk import modbus_tcp
from modbus_tk.exceptions import ModbusError
from pyModbusTCP.client import ModbusClient

from hmi.plant.modbus.server_process import ServerProcess
from tests import test_modbus
from tests.conftest import ROOT, write_project
from tests.modbus_peers import (
    WAIT,
    closed_by_peer,
    frame,
    read_frame,
    read_frames,
    wait_until,
)
from tests.test_modbus import REGISTER_VALVE

server = test_modbus.server  # the fixture that starts (and stops) real server processes
# The register valve has inputs and outputs on all four tables (ir:2.3, di:0, hr:5.1,
# coil:3): served coil 0-15, di 0-15, hr 0-5, ir 0-2.


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    return write_project(tmp_path_factory.mktemp("conformance"),
                         {"project.yaml": REGISTER_VALVE})


@pytest.fixture
def serve(project, server):
    """A server of its own for the test (test_modbus's fixture stops it)."""
    return lambda *extra, host="127.0.0.1": server(project, *extra, host=host)


@pytest.fixture(scope="module")
def shared(project):
    """One server for the tests that only ask and leave the orders alone."""
    srv = ServerProcess(project)
    srv.start(WAIT)
    yield srv
    srv.stop()


def client(port: int) -> ModbusClient:
    c = ModbusClient(host="127.0.0.1", port=port, unit_id=1, timeout=WAIT, auto_open=True)
    assert c.open(), c.last_error_as_txt
    return c


def ask(port: int, pdu: bytes, unit: int = 1) -> bytes:
    """One request on its own connection, plain sockets; the answer PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=WAIT) as sock:
        sock.sendall(frame(0x1234, pdu, unit))
        tid, answered_unit, answer = read_frame(sock)
    assert tid == 0x1234 and answered_unit == unit
    return answer


def test_the_address_map_through_pymodbustcp_and_modbus_tk(serve):
    srv = serve()
    c = client(srv.port)
    # The valve starts closed: fsc (bit 3 of input register 2) on, fso (di 0) off.
    assert c.read_discrete_inputs(0, 16) == [False] * 16
    assert c.read_input_registers(0, 3) == [0, 0, 0b1000]
    assert c.read_coils(0, 16) == [False] * 16 and c.read_holding_registers(0, 6) == [0] * 6
    # O (coil 3) by Write Single Coil: the order arrives, the valve opens.
    assert c.write_single_coil(3, True)
    srv.wait_for("C=0 O=1", WAIT)
    wait_until(lambda: c.read_discrete_inputs(0, 1) == [True], "fso from the moving valve")
    assert c.read_input_registers(2, 1) == [0]
    # C (bit 1 of holding register 5) by modbus-tk's Mask Write Register; bit 15 kept.
    assert c.write_single_register(5, 0x8000)
    master = modbus_tcp.TcpMaster("127.0.0.1", srv.port, WAIT)
    try:
        assert master.execute(1, tk.WRITE_MULTIPLE_COILS, 3, output_value=[0]) == (3, 1)
        assert master.execute(1, tk.MASK_WRITE_REGISTER, 5, and_mask=0xFFFD,
                              or_mask=0x0002) == (5, 0xFFFD, 0x0002)
        srv.wait_for("C=1 O=0", WAIT)
        assert master.execute(1, tk.READ_HOLDING_REGISTERS, 5, 1) == (0x8002,)
    finally:
        master.close()
    wait_until(lambda: c.read_input_registers(2, 1) == [0b1000], "fsc again")
    # FC 16 and FC 23 too: C off by a multiple-register write, read back in the same request.
    assert c.write_multiple_registers(4, [7, 0x8000])
    srv.wait_for("C=0 O=0", WAIT)
    assert c.write_read_multiple_registers(0, [1], 4, 2) == [7, 0x8000]
    c.close()


# (request PDU, the exception code it must get); the answer's function byte is FC | 0x80.
EXCEPTIONS = {
    "FC 7, serial line only": (b"\x07", 1),
    "FC 8 diagnostics": (b"\x08\x00\x00\x00\x00", 1),
    "FC 24 read FIFO": (b"\x18\x00\x00", 1),
    "FC 43 device identification": (b"\x2b\x0e\x01\x00", 1),
    "FC 0": (b"\x00", 1),
    "FC 0x81": (b"\x81\x00\x00\x00\x01", 1),
    "FC 0x41 user-defined": (b"\x41\x00", 1),
    "FC 1 quantity 0": (b"\x01\x00\x00\x00\x00", 3),
    "FC 1 quantity 2001": (b"\x01\x00\x00\x07\xd1", 3),
    "FC 2 quantity 0": (b"\x02\x00\x00\x00\x00", 3),
    "FC 2 quantity 2001": (b"\x02\x00\x00\x07\xd1", 3),
    "FC 3 quantity 126": (b"\x03\x00\x00\x00\x7e", 3),
    "FC 4 quantity 126": (b"\x04\x00\x00\x00\x7e", 3),
    "FC 3 one byte too many": (b"\x03\x00\x00\x00\x01\x00", 3),
    "FC 3 one byte short": (b"\x03\x00\x00\x00", 3),
    "FC 5 value 0x1234": (b"\x05\x00\x03\x12\x34", 3),
    "FC 5 value 0x00FF": (b"\x05\x00\x03\x00\xff", 3),
    "FC 15 quantity 0": (b"\x0f\x00\x00\x00\x00\x00", 3),
    "FC 15 quantity 1969": (b"\x0f\x00\x00\x07\xb1\xf7" + bytes(247), 3),
    "FC 15 byte count 2 for 3 coils": (b"\x0f\x00\x00\x00\x03\x02\x00\x00", 3),
    "FC 15 data shorter than its byte count": (b"\x0f\x00\x00\x00\x03\x01", 3),
    "FC 16 quantity 124": (b"\x10\x00\x00\x00\x7c\xf8" + bytes(248)[:247], 3),
    "FC 16 byte count 3 for 1 register": (b"\x10\x00\x00\x00\x01\x03\x00\x00\x00", 3),
    "FC 22 one byte short": (b"\x16\x00\x05\xff\xff\x00", 3),
    "FC 23 write quantity 122": (b"\x17\x00\x00\x00\x01\x00\x00\x00\x7a\xf4", 3),
    "FC 1 coil 16": (b"\x01\x00\x10\x00\x01", 2),
    "FC 1 coils 15-16": (b"\x01\x00\x0f\x00\x02", 2),
    "FC 1 from 65535": (b"\x01\xff\xff\x00\x02", 2),
    "FC 2 inputs 10-16": (b"\x02\x00\x0a\x00\x07", 2),
    "FC 3 register 6": (b"\x03\x00\x06\x00\x01", 2),
    "FC 4 register 3": (b"\x04\x00\x03\x00\x01", 2),
    "FC 5 coil 16": (b"\x05\x00\x10\xff\x00", 2),
    "FC 6 register 6": (b"\x06\x00\x06\x00\x01", 2),
    "FC 15 coils 15-16": (b"\x0f\x00\x0f\x00\x02\x01\x00", 2),
    "FC 16 registers 5-6": (b"\x10\x00\x05\x00\x02\x04\x00\x00\x00\x00", 2),
    "FC 22 register 6": (b"\x16\x00\x06\xff\xff\x00\x00", 2),
    "FC 23 write to register 6": (b"\x17\x00\x00\x00\x01\x00\x06\x00\x01\x02\x00\x00", 2),
}


@pytest.mark.parametrize("case", EXCEPTIONS)
def test_every_exception_case_is_answered_as_the_specification_says(case, shared):
    pdu, code = EXCEPTIONS[case]
    assert len(pdu) <= 253
    assert ask(shared.port, pdu) == bytes((pdu[0] | 0x80, code))


def test_another_unit_gets_exception_11_and_nothing_changes(shared):
    assert ask(shared.port, b"\x05\x00\x03\xff\x00", unit=7) == b"\x85\x0b"
    assert ask(shared.port, b"\x01\x00\x03\x00\x01") == b"\x01\x01\x00"  # O still off


def test_exceptions_through_independent_clients(shared):
    """pyModbusTCP and modbus-tk parse the exception answers themselves."""
    c = client(shared.port)
    assert c.read_coils(16, 1) is None and c.last_except == 2
    assert c.custom_request(b"\x03\x00\x00\x00\x7e") is None and c.last_except == 3
    assert c.custom_request(b"\x18\x00\x00") is None and c.last_except == 1
    c.close()
    master = modbus_tcp.TcpMaster("127.0.0.1", shared.port, WAIT)
    try:
        with pytest.raises(ModbusError) as info:
            master.execute(1, tk.READ_INPUT_REGISTERS, 3, 1)
        assert info.value.get_exception_code() == 2
    finally:
        master.close()


def test_the_summary_counts_the_exceptions_sent(serve):
    srv = serve()
    cases = list(EXCEPTIONS.values())[:17]
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        for tid, (pdu, code) in enumerate(cases, 1):
            sock.sendall(frame(tid, pdu))
            assert read_frame(sock) == (tid, 1, bytes((pdu[0] | 0x80, code)))
    srv.stop()
    summary = srv.lines[-1]
    ones = sum(1 for _, code in cases if code == 1)
    assert f"17 requests (0 reads, 0 writes, 17 exceptions: Illegal Function {ones}, " \
        f"Illegal Data Value {17 - ones})" in summary, summary


def test_pipelined_requests_are_each_answered_in_order(serve):
    """50 requests sent at once on one connection, a write of O among them: 50 answers, in
    order, and the write carried out (pymodbus 3.16's server answered 1 of 2, 0 of 50)."""
    srv = serve()
    requests = [(tid, b"\x02\x00\x00\x00\x02") for tid in range(1, 51)]
    requests[24] = (25, b"\x0f\x00\x03\x00\x01\x01\x01")  # O on, in the middle
    requests[40] = (41, b"\x18\x00\x00")  # an exception among them
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        sock.sendall(b"".join(frame(tid, pdu) for tid, pdu in requests))
        sock.shutdown(socket.SHUT_WR)  # all sent: the server may close once it answered
        answers = read_frames(sock)
    assert [tid for tid, _, _ in answers] == list(range(1, 51))
    assert answers[24][2] == b"\x0f\x00\x03\x00\x01"
    assert answers[40][2] == b"\x98\x01"
    assert all(a[2][:2] == b"\x02\x01" for i, a in enumerate(answers) if i not in (24, 40))
    srv.wait_for("C=0 O=1", WAIT)
    srv.stop()
    assert "50 requests (48 reads, 1 writes, 1 exceptions" in srv.lines[-1], srv.lines[-1]


def test_a_frame_that_is_not_modbus_closes_the_connection_with_a_log_line(serve):
    srv = serve()
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        sock.sendall(frame(1, b"\x02\x00\x00\x00\x02") + frame(2, b"\x02\x00\x00\x00\x02",
                                                                protocol=5)
                     + frame(3, b"\x02\x00\x00\x00\x02"))
        answers = read_frames(sock)  # until the server closes
    assert [tid for tid, _, _ in answers] == [1]
    srv.wait_for("connection closed: not a Modbus TCP frame (protocol id 5, expected 0 "
                 "(not Modbus))", WAIT)
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        sock.sendall(struct.pack(">HHHB", 1, 0, 1, 1))  # length 1: no function code
        assert read_frames(sock) == []
    srv.wait_for("length field 1, expected 2 to 254", WAIT)


def test_an_idle_connection_is_closed(serve):
    srv = serve("--idle-timeout", "300ms")
    assert "a connection with no request for 0.3 s is closed" in "\n".join(srv.lines)
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        sock.sendall(frame(1, b"\x02\x00\x00\x00\x02"))
        assert read_frame(sock)[0] == 1  # served, then nothing more is asked
        assert closed_by_peer(sock)
    srv.wait_for("connection closed: no whole request for 0.3 s", WAIT)
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as sock:
        sock.sendall(frame(1, b"\x02\x00"))  # half a request, and no more
        assert closed_by_peer(sock)


def test_connections_are_capped(serve):
    srv = serve("--max-connections", "2")
    assert "at most 2 connections at once" in "\n".join(srv.lines)
    first = socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT)
    second = socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT)
    for n, sock in enumerate((first, second), 1):
        sock.sendall(frame(n, b"\x02\x00\x00\x00\x02"))
        assert read_frame(sock)[0] == n
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as third:
        assert closed_by_peer(third)
    srv.wait_for("refused: 2 connections are open, the limit", WAIT)
    first.close()
    srv.wait_for(lambda line: "client disconnected" in line and "(1 open)" in line, WAIT)
    with socket.create_connection(("127.0.0.1", srv.port), timeout=WAIT) as again:
        again.sendall(frame(9, b"\x02\x00\x00\x00\x02"))
        assert read_frame(again)[0] == 9
    second.close()
    srv.stop()
    assert "from 3 connections (1 refused over the limit)" in srv.lines[-1], srv.lines[-1]


def test_listening_beyond_this_machine_warns(serve):
    srv = serve(host="0.0.0.0")
    warning = next(line for line in srv.lines if "warning" in line)
    assert f"listening on 0.0.0.0: the simulated plant can be read and driven by anyone who " \
        f"can reach port {srv.port}" in warning
    assert ask(srv.port, b"\x02\x00\x00\x00\x01") == b"\x02\x01\x00"
    local = serve()
    assert not any("warning" in line for line in local.lines)


MBPOLL = shutil.which("mbpoll")


@pytest.mark.skipif(MBPOLL is None, reason="Debian's mbpoll is not installed "
                    "(apt-get install mbpoll)")
def test_mbpoll_reads_and_writes_serve_plant(serve):
    srv = serve()

    def mbpoll(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([MBPOLL, "-m", "tcp", "-a", "1", "-p", str(srv.port), "-0",
                               "-1", "-q", *args], capture_output=True, text=True,
                              timeout=WAIT)

    def values(out: str) -> list[int]:
        return [int(v) for v in re.findall(r"^\[\d+\]:\s+(-?\d+)$", out, re.M)]
    ir = mbpoll("-t", "3", "-r", "2", "-c", "1", "127.0.0.1")  # input register 2
    assert ir.returncode == 0 and values(ir.stdout) == [0b1000], ir
    di = mbpoll("-t", "1", "-r", "0", "-c", "2", "127.0.0.1")
    assert di.returncode == 0 and values(di.stdout) == [0, 0], di
    write = mbpoll("-t", "0", "-r", "3", "127.0.0.1", "1")  # O on
    assert write.returncode == 0, write
    srv.wait_for("C=0 O=1", WAIT)
    coils = mbpoll("-t", "0", "-r", "0", "-c", "4", "127.0.0.1")
    assert values(coils.stdout) == [0, 0, 0, 1], coils
    bad = mbpoll("-t", "0", "-r", "100", "-c", "2", "127.0.0.1")
    assert bad.returncode != 0 and "Illegal data address" in bad.stderr, bad


def test_a_port_in_use_is_a_clear_error(project):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run([sys.executable, "-m", "hmi.cli", "serve-plant", str(project),
                               "--port", str(port)], capture_output=True, text=True,
                              cwd=ROOT, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == f"plchmi: error: cannot listen on 127.0.0.1:{port}: " \
        "Address already in use"

"""Our Modbus client (ModbusPlant) against servers that are not ours: modbus-tk's and
pyModbusTCP's (PyPI), and plain-socket devices that answer wrong on purpose or close every
connection. The engine scans in virtual time; the plant's back-off runs on the same virtual
clock, so no test waits for a back-off to pass. Sockets are real throughout.
"""

from __future__ import annotations

import json
import re
import struct
import subprocess
import sys

import pytest
from pyModbusTCP.server import ModbusServer

from hmi.engine.scan import Engine
from hmi.plant.base import PlantError
from hmi.plant.modbus.client import BACKOFF_MAX_S, ModbusPlant, ModbusSettings
from hmi.project.loader import load_project
from tests.conftest import PROJECTS, ROOT, write_project
from tests.modbus_peers import (
    Closing,
    ScriptedDevice,
    TkDevice,
    answer_to,
    free_port,
    good_answer,
    wait_until,
)

VALVE = PROJECTS / "cispi_valve"

MAP_PROJECT = """
    name: map_check
    scan_period: 10ms
    inputs:
      a: {description: a, address: "di:0"}
      b: {description: b, address: "di:5"}
      c: {description: c, address: "coil:8"}
      d: {description: d, address: "ir:2.3"}
      e: {description: e, address: "hr:4.0"}
    outputs:
      X: {description: x, address: "coil:0"}
      Y: {description: y, address: "coil:1"}
      Z: {description: z, address: "coil:3"}
      U: {description: u, address: "hr:5.1"}
      V: {description: v, address: "hr:5.2"}
    control:
      equations:
        X: "a"
        Y: "b"
        Z: "c"
        U: "d"
        V: "e"
    plant:
      kind: modbus
"""


class VirtualClock:
    """Seconds, moved by the test: the plant's back-off and its journal windows run on it."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def plant_for(path, port: int, clock=None, read_only: bool = False,
              timeout_us: int = 1_000_000) -> ModbusPlant:
    project = load_project(path)
    kwargs = {"clock": clock} if clock is not None else {}
    return ModbusPlant(project, ModbusSettings(port=port, timeout_us=timeout_us),
                       read_only=read_only, **kwargs)


def pdus(requests: list[bytes]) -> list[tuple]:
    """(function, address, quantity-or-value) of each request PDU."""
    return [struct.unpack(">BHH", p[:5]) for p in requests]


def test_the_address_map_against_modbus_tk(tmp_path):
    write_project(tmp_path, {"project.yaml": MAP_PROJECT})
    with TkDevice() as dev:
        dev.set("di", 0, [1, 0, 0, 0, 0, 0])
        dev.set("coil", 0, [0, 0, 1, 0, 0, 0, 0, 0, 1])  # coil 2 is someone else's
        dev.set("ir", 2, [0b1000])
        dev.set("hr", 4, [1, 0x8000])  # bit 15 of register 5 is someone else's
        plant = plant_for(tmp_path, dev.port)
        assert plant.connect()
        assert dict(plant.read(0)) == {"a": True, "b": False, "c": True, "d": True,
                                       "e": True}
        # One request per table, the gap di 1-4 bridged: FC 1, 2, 3, 4 in table order.
        assert pdus(dev.requests) == [(1, 8, 1), (2, 0, 6), (3, 4, 1), (4, 2, 1)]
        dev.requests.clear()
        plant.write(0, {"X": True, "Y": False, "Z": True, "U": True, "V": False})
        # Coils 0-1 and coil 3 (the gap at 2 is never bridged), a mask write for hr 5.
        assert [p[0] for p in dev.requests] == [15, 15, 22]
        assert dev.requests[2] == struct.pack(">BHHH", 22, 5, 0xFFF9, 0x0002)
        assert dev.get("coil", 0, 4) == [1, 0, 1, 1]
        assert dev.get("hr", 5) == [0x8002]
        # Steady outputs cost nothing; one changed bit costs its request only.
        dev.requests.clear()
        plant.write(10_000, {"X": True, "Y": False, "Z": True, "U": True, "V": False})
        assert dev.requests == []
        plant.write(20_000, {"X": True, "Y": False, "Z": True, "U": False, "V": True})
        assert [p[0] for p in dev.requests] == [22]
        assert dev.get("hr", 5) == [0x8004]
        plant.close()
    assert plant.stats["writes"] == 4 and plant.stats["invalid"] == 0


def test_exception_responses_from_independent_servers_keep_the_connection(tmp_path):
    # modbus-tk serves discrete inputs 0-3 only: di 0-5 is Illegal Data Address.
    write_project(tmp_path, {"project.yaml": MAP_PROJECT})
    with TkDevice(inputs=4) as dev:
        plant = plant_for(tmp_path, dev.port)
        assert plant.connect()
        with pytest.raises(PlantError) as info:
            plant.read(0)
        assert not info.value.lost and plant.connected
        assert "answered Illegal Data Address (exception 2) to read discrete inputs 0-5" \
            in str(info.value)
        assert plant.stats["exceptions"] == 1 and plant.stats["losses"] == 0
        plant.close()
    # pyModbusTCP's server has no Mask Write Register: Illegal Function, by name.
    port = free_port()
    server = ModbusServer("127.0.0.1", port, no_block=True)
    server.start()
    try:
        plant = plant_for(tmp_path, port)
        wait_until(plant.connect, "pyModbusTCP to listen")
        plant.read(0)
        with pytest.raises(PlantError) as info:
            plant.write(0, {"X": True, "Y": False, "Z": True, "U": True, "V": False})
        assert "Illegal Function (exception 1) to write holding register 5 bits 1,2" \
            in str(info.value)
        assert not info.value.lost and plant.connected
        assert server.data_bank.get_coils(0, 4) == [True, False, False, True]
        plant.close()
    finally:
        server.stop()


def _fc2(request: bytes, pdu: bytes, **wrong) -> bytes:
    return answer_to(request, pdu, **wrong)


# (what the device sends back to "read discrete inputs 0-1", what the client must say)
INVALID = {
    "byte count 0": (lambda r: _fc2(r, b"\x02\x00"), "byte count 0, expected 1 for 2 bits"),
    "FC 3 answer": (lambda r: _fc2(r, b"\x03\x02\x00\x00"),
                    "function code 0x03 (read holding registers) in the answer to 0x02"),
    "FC 1 answer": (lambda r: _fc2(r, b"\x01\x01\x03"),
                    "function code 0x01 (read coils) in the answer to 0x02"),
    "byte count 5, 1 byte": (lambda r: _fc2(r, b"\x02\x05\x03"), "byte count 5, expected 1"),
    "short data": (lambda r: _fc2(r, b"\x02\x01"), "byte count 1 but 0 data bytes"),
    "long data": (lambda r: _fc2(r, b"\x02\x01\x03\x00"), "byte count 1 but 2 data bytes"),
    "transaction id": (lambda r: _fc2(r, b"\x02\x01\x03", tid_delta=1),
                       "(the answer to another request)"),
    "unit id": (lambda r: _fc2(r, b"\x02\x01\x03", unit=7), "unit id 7, expected 1"),
    "protocol id": (lambda r: _fc2(r, b"\x02\x01\x03", protocol=1),
                    "protocol id 1, expected 0"),
    "length 0": (lambda r: _fc2(r, b"", length_delta=-1), "length field 0, expected 2 to 254"),
    "length 300": (lambda r: _fc2(r, b"\x02\x01\x03", length_delta=296),
                   "length field 300"),
    "long exception": (lambda r: _fc2(r, b"\x82\x02\x00"),
                       "exception response of 3 bytes, expected 2"),
    "exception code 0": (lambda r: _fc2(r, b"\x82\x00"), "exception response with code 0"),
    "two answers": (lambda r: _fc2(r, b"\x02\x01\x03") * 2, "beyond the length"),
}


@pytest.mark.parametrize("case", INVALID)
def test_an_invalid_answer_is_a_communication_fault_with_its_reason(case, tmp_path):
    answer, reason = INVALID[case]
    with ScriptedDevice(lambda number, request: answer(request)) as dev:
        plant = plant_for(VALVE, dev.port)
        assert plant.connect()
        with pytest.raises(PlantError) as info:
            plant.read(0)
        message = str(info.value)
        assert info.value.lost and not plant.connected
        assert "invalid answer to read discrete inputs 0-1: " in message, message
        assert reason in message, message
        assert plant.stats["invalid"] == 1 and plant.stats["timeouts"] == 0
        assert "invalid answer" in plant.link.drain()[-1]["message"]
        plant.close()


def test_an_invalid_write_echo_is_a_communication_fault():
    def script(number: int, request: bytes) -> bytes:
        if request[7] == 15:  # write coils 0-1, echoed as a write of 3 coils
            return answer_to(request, request[7:10] + b"\x00\x03")
        return good_answer(request)
    with ScriptedDevice(script) as dev:
        plant = plant_for(VALVE, dev.port)
        assert plant.connect()
        plant.read(0)
        with pytest.raises(PlantError) as info:
            plant.write(0, {"C": False, "O": True})
        assert "invalid answer to write coils 0-1: the answer to 0x0F (write multiple coils)"\
            " echoes 00 00 00 03, expected 00 00 00 02" in str(info.value)
        plant.close()


def test_the_scan_takes_an_invalid_answer_as_a_plant_fault_never_an_internal_error():
    """The reported case: FC 2 answered with byte count 0 used to raise IndexError inside
    the scan (internal error, no plant journal entry, scans slowed to 65/s)."""
    with ScriptedDevice(lambda n, r: answer_to(r, b"\x02\x00")) as dev:
        plant = plant_for(VALVE, dev.port, clock=VirtualClock())
        engine = Engine(plant.project, plant)
        assert plant.connect()
        snaps = [engine.step(k * 10_000) for k in range(1, 51)]
    assert all(s.error is None for s in snaps)
    assert [r.source for r in engine.latched] == ["plant"]
    assert "invalid answer to read discrete inputs 0-1: byte count 0" in engine.latched[0].detail
    assert all(s.outputs == (False, False) for s in snaps)
    events = [e["event"] for e in plant.link.drain()]
    assert events == ["connected", "lost"], events


def test_no_answer_and_an_incomplete_answer_say_so():
    with ScriptedDevice(lambda n, r: b"") as dev:  # mute: the request is never answered
        plant = plant_for(VALVE, dev.port, timeout_us=200_000)
        assert plant.connect()
        with pytest.raises(PlantError, match=r"no answer to read discrete inputs 0-1 within "
                           r"200ms"):
            plant.read(0)
        assert plant.stats["timeouts"] == 1 and plant.stats["invalid"] == 0
    # Part of an answer, then the device closes: said as such, at once.
    with ScriptedDevice(lambda n, r: Closing(answer_to(r, b"\x02\x01\x03")[:8])) as dev:
        plant = plant_for(VALVE, dev.port)
        assert plant.connect()
        with pytest.raises(PlantError, match="closed by the device after 8 bytes of the "
                           "answer to read discrete inputs 0-1"):
            plant.read(0)
    # Part of an answer, then nothing: the timeout, saying how much came.
    with ScriptedDevice(lambda n, r: answer_to(r, b"\x02\x01\x03")[:8]) as dev:
        plant = plant_for(VALVE, dev.port, timeout_us=200_000)
        assert plant.connect()
        with pytest.raises(PlantError, match="incomplete answer to read discrete inputs 0-1: "
                           "8 of 10 bytes within 200ms"):
            plant.read(0)


def run_virtual(plant: ModbusPlant, clock: VirtualClock, seconds: float,
                step_s: float = 0.01, engine: Engine | None = None) -> Engine:
    """Scan every `step_s` of virtual time for `seconds`; the clock moves with the scans."""
    engine = engine or Engine(plant.project, plant)
    start = engine.now
    steps = round(seconds / step_s)
    for k in range(1, steps + 1):
        now = start + round(k * step_s * 1e6)
        clock.t = now / 1e6
        engine.step(now)
    return engine


def test_a_device_that_closes_every_connection_gets_a_backed_off_handful():
    """5 s of scans at 100/s against a device that accepts and closes every connection:
    attempts at 0, 0.1, 0.3, 0.7, 1.5 and 3.1 s (doubling from 0.1 s), not one per scan;
    and the journal has the first loss and, at the end, the outage's summary."""
    clock = VirtualClock()
    with ScriptedDevice() as dev:
        plant = plant_for(VALVE, dev.port, clock=clock)
        assert plant.connect()
        engine = run_virtual(plant, clock, 5.0)
        wait_until(lambda: dev.connections == plant.stats["connects"], "the accepts")
        plant.close()
    assert plant.stats["connects"] == plant.stats["losses"] == 6 == dev.connections
    assert engine.scan == 500 and [r.source for r in engine.latched] == ["plant"]
    assert "closed by the device" in engine.latched[0].detail
    entries = plant.link.drain()
    assert [e["event"] for e in entries] == ["connected", "lost", "connect-retries"]
    assert entries[2]["losses"] == 6 and "6 connections lost" in entries[2]["message"]


def test_a_long_outage_is_counted_once_a_minute_at_the_capped_backoff():
    clock = VirtualClock()
    with ScriptedDevice() as dev:
        plant = plant_for(VALVE, dev.port, clock=clock)
        assert plant.connect()
        run_virtual(plant, clock, 150.0, step_s=0.1)
        plant.close()
    # 5 attempts while the back-off doubles (0.1 to 1.6 s), then one per 2 s (the cap).
    assert BACKOFF_MAX_S == 2.0
    assert 5 + (150 - 3.1) // 2 - 1 <= plant.stats["connects"] <= 5 + (150 - 3.1) // 2 + 1
    entries = plant.link.drain()
    events = [e["event"] for e in entries]
    assert events == ["connected", "lost", "link-problems", "link-problems",
                      "connect-retries"], events
    assert entries[-1]["losses"] == plant.stats["losses"]
    assert 0 < sum(e["losses"] for e in entries[2:4]) < plant.stats["losses"]


def test_the_backoff_is_reset_by_a_working_scan_not_by_a_connection():
    """Connections 1-3 are closed at their first request; 4 works for a while, then is
    closed; 5 and after answer the read but are closed at the write. Only 4's working scans
    reset the back-off: neither a connection nor a read that works does."""
    served = {"requests": 0}

    def script(number: int, request: bytes) -> bytes | None:
        if number <= 3:
            return None
        if number == 4:
            served["requests"] += 1
            return good_answer(request) if served["requests"] <= 20 else None
        return good_answer(request) if request[7] == 2 else None

    clock = VirtualClock()
    with ScriptedDevice(script) as dev:
        plant = plant_for(VALVE, dev.port, clock=clock)
        engine = Engine(plant.project, plant)
        waits: list[float] = []  # from each loss to the next connection
        lost_at = None
        assert plant.connect()
        for k in range(1, 400):
            clock.t = k / 100
            connects, losses = plant.stats["connects"], plant.stats["losses"]
            engine.step(k * 10_000)
            if plant.stats["connects"] > connects and lost_at is not None:
                waits.append(round(clock.t - lost_at, 2))
            if plant.stats["losses"] > losses:
                lost_at = clock.t
        plant.close()
    # (to the scan: a wait can end one 10 ms scan later than the back-off)
    assert waits[:7] == pytest.approx([0.1, 0.2, 0.4, 0.1, 0.2, 0.4, 0.8], abs=0.011), waits
    events = [e["event"] for e in plant.link.drain()]
    assert events == ["connected", "lost", "reconnected", "lost", "connect-retries"], events


def test_read_only_mode_sends_no_write_even_at_stop():
    with TkDevice() as dev:
        dev.set("coil", 0, [0, 1])  # the PLC being observed holds O on
        clock = VirtualClock()
        plant = plant_for(VALVE, dev.port, clock=clock, read_only=True)
        assert plant.connect()
        engine = run_virtual(plant, clock, 1.0)
        assert engine.last is not None and engine.last.outputs == (False, True)
        safe = dict(zip(engine.layout.outputs, engine.safe_vector, strict=True))
        assert plant.stop(engine.now, safe) is False
        seen = dev.functions()
    assert dev.writes() == [] and set(seen) == {1, 2}
    assert len(seen) == 2 * 100 and plant.stats["writes"] == 0
    assert dev.get("coil", 0, 2) == [0, 1]


def test_the_stop_write_is_sent_and_counted():
    with TkDevice() as dev:
        dev.set("di", 0, [1, 0])  # closed: the valve's law opens it
        clock = VirtualClock()
        plant = plant_for(VALVE, dev.port, clock=clock)
        assert plant.connect()
        engine = run_virtual(plant, clock, 1.05)  # X0 waits 1 s, then O
        assert dev.get("coil", 0, 2) == [0, 1]
        before = len(dev.writes())
        safe = dict(zip(engine.layout.outputs, engine.safe_vector, strict=True))
        assert plant.stop(engine.now, safe) is True
        writes = dev.writes()
    # One Write Multiple Coils of coils 0-1, both off: the safe vector.
    assert len(writes) == before + 1 and writes[-1] == bytes.fromhex("0f 0000 0002 01 00")
    assert dev.get("coil", 0, 2) == [0, 0]
    assert plant.stats["writes"] == len(writes) and plant.stats["stop_writes"] == 1


def test_the_run_report_counts_every_write_the_device_saw(tmp_path):
    """`plchmi run` against modbus-tk: the report's writes, the stop's included, are the
    requests the device handled (the reported 2025 reported vs 2026 seen)."""
    with TkDevice() as dev:
        dev.set("di", 0, [1, 0])
        proc = subprocess.run(
            [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "1s",
             "--plant", f"modbus://127.0.0.1:{dev.port}", "--journal",
             str(tmp_path / "j.jsonl")],
            capture_output=True, text=True, cwd=ROOT, timeout=120)
        seen = dev.functions()
    assert proc.returncode == 0, proc.stderr
    match = re.search(r"requests (\d+) \(reads (\d+), writes (\d+), of which 1 at stop\)",
                      proc.stdout)
    assert match, proc.stdout
    requests, reads, writes = map(int, match.groups())
    assert writes == sum(1 for f in seen if f == 15) >= 2
    assert reads == sum(1 for f in seen if f == 2) and requests == len(seen)
    assert "Stopped: stopped: safe outputs written" in proc.stdout


def test_a_run_against_a_device_dropping_every_connection_journals_a_handful(tmp_path):
    """The reported storm, end to end: `plchmi run` for 1 s against a device that accepts
    and closes every connection (before the back-off: a connection a scan, about 100 here
    and 200 journal lines)."""
    journal = tmp_path / "j.jsonl"
    with ScriptedDevice() as dev:
        proc = subprocess.run(
            [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "1s",
             "--plant", f"modbus://127.0.0.1:{dev.port}", "--journal", str(journal)],
            capture_output=True, text=True, cwd=ROOT, timeout=120)
        connections = dev.connections
    assert proc.returncode == 0, proc.stderr
    assert 2 <= connections <= 5, connections  # 0, 0.1, 0.3, 0.7 s: never more
    entries = [json.loads(line) for line in journal.read_text().splitlines()]
    events = [(e["type"], e["event"]) for e in entries
              if not e["event"].startswith("scan-overrun")]
    assert events == [("session", "start"), ("plant", "connected"), ("plant", "lost"),
                      ("alarm", "raised"), ("plant", "connect-retries"),
                      ("session", "stop")], events
    assert "closed by the device" in entries[2]["message"]
    assert f"connections made {connections}" in proc.stdout

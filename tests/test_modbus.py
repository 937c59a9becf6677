"""Against a real Modbus TCP server: `plchmi serve-plant` in another process, on 127.0.0.1.

Never a mock of the transport. The servers listen on ports the system picks (`--port 0`);
every wait has a deadline generous enough for a loaded 2-core machine, and polls a condition
rather than sleeping a fixed time.
"""

from __future__ import annotations

import csv
import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from hmi.engine.commands import FaultReset, Pause, Resume, SetMode, StepScans
from hmi.engine.scan import Engine
from hmi.engine.snapshot import Snapshot
from hmi.plant.modbus.client import ModbusPlant, ModbusSettings, wait_connected
from hmi.plant.modbus.server_process import ServerProcess
from hmi.project.loader import load_project
from hmi.session.live import LiveRunner, WallClock
from hmi.session.session import Session
from hmi.session.view import CellView
from tests.conftest import PROJECTS, ROOT, make_session, write_project

VALVE = PROJECTS / "cispi_valve"
S = 1_000_000
WAIT = 120.0  # seconds: a deadline on a state, not a sleep (loaded 2-core machines)
SAFE_S = 600  # a run that ends on its state: its fail-safe, never what it waits for


def quick_valve(folder: Path) -> Path:
    """A copy of the valve, at `folder`, whose filling sequence holds 1 s open instead of
    the project's 3 s: a setting of the process, not of what the tests here check (the
    valve, its 2 s travel, its 1 s rest closed, the diagnosers, the filter and the addresses
    are the project's). The hold, as the rest, stays 500 ms longer than the diagnoser's
    500 ms dwell at that end: a close order within the dwell is read as fso breaking on
    arrival (B3A) once the first read after it comes after the valve left the switch, as an
    opening within the closed dwell is read as B1A. A hold of 500 ms, as this copy had, put
    the close order in the scan the dwell ends: a run against serve-plant at a load of
    about 20 (244 scan overruns) read fso broken before the dwell ended and diagnosed B3A.

    On a real server the tests wait in real time: a whole cycle takes 6 s instead of 8 s.
    The diagnoser's windows are the project's: built for the valve's declared tolerances (a
    travel of 1.6 s to 2.4 s, arrival seen within [1.4 s, 2.45 s)), they also hold a PLC
    that reads its switches late through Modbus on a loaded machine (at a load of 17 on 2
    cores: Modbus I/O up to 84 ms a scan)."""
    shutil.copytree(VALVE, folder)
    law = folder / "control.yaml"
    text = law.read_text(encoding="utf-8")
    for old, new in (("X2.t >= 3s, description: Filled for 3 s",
                      "X2.t >= 1s, description: Filled for 1 s"),):
        assert text.count(old) == 1, f"the valve's law no longer says {old!r}"
        text = text.replace(old, new)
    law.write_text(text, encoding="utf-8")
    return folder


@pytest.fixture
def server():
    servers: list[ServerProcess] = []

    def start(project=VALVE, *extra: str, port: int = 0,
              host: str = "127.0.0.1") -> ServerProcess:
        srv = ServerProcess(project, extra, port=port, host=host)
        servers.append(srv)
        srv.start(WAIT)
        return srv
    yield start
    for srv in servers:
        srv.stop()


class Live:
    """An engine on a Modbus plant, scanning in real time in its own thread."""

    def __init__(self, project_path, port: int, read_only: bool = False,
                 timeout_us: int = 1_000_000):
        self.project = load_project(project_path)
        self.plant = ModbusPlant(self.project, ModbusSettings(port=port, timeout_us=timeout_us),
                                 read_only=read_only)
        assert wait_connected(self.plant, WAIT, lambda line: None), self.plant.message
        self.engine = Engine(self.project, self.plant)
        self.session = Session(self.engine, clock=WallClock())
        self.cells: list[CellView] = []  # what the session handed out, scan by scan
        self.snaps: list[Snapshot] = []  # the engine's part of each
        self.session.scan_listeners.append(self._keep)
        self.runner = LiveRunner(self.session)

    def __enter__(self) -> Live:
        self.runner.start()
        return self

    def _keep(self, cell: CellView) -> None:
        self.cells.append(cell)
        self.snaps.append(cell.snapshot)

    def cell(self, snap: Snapshot) -> CellView:
        """The session's view of the scan `snap` is the engine's part of."""
        return next(c for c in self.cells if c.snapshot is snap)

    def __exit__(self, *exc: object) -> None:
        self.runner.stop(5)
        engine = self.engine
        self.plant.stop(engine.now, dict(zip(engine.layout.outputs, engine.safe_vector,
                                             strict=True)))

    def wait(self, test: Callable[[Snapshot], bool], what: str, timeout: float = WAIT,
             since: int = 0) -> Snapshot:
        deadline = time.monotonic() + timeout
        seen = since
        while time.monotonic() < deadline:
            snaps = self.snaps[seen:]
            for snap in snaps:
                if test(snap):
                    return snap
            seen += len(snaps)
            assert self.runner.alive, "the scan thread died"
            time.sleep(0.01)
        last = self.snaps[-1] if self.snaps else None
        raise AssertionError(f"timed out waiting for {what}; last scan: "
                             f"{last and (last.inputs, last.outputs, last.plant, last.latched)}")


def read_coils(port: int, count: int = 2) -> list[bool]:
    client = ModbusTcpClient("127.0.0.1", port=port, timeout=WAIT, retries=1)
    assert client.connect()
    try:
        response = client.read_coils(0, count=count, device_id=1)
        assert not response.isError(), response
        return list(response.bits[:count])
    finally:
        client.close()


def states(rows: list[dict]) -> list[tuple]:
    """The sequence of distinct (fsc, fso, C, O, steps) a trace went through."""
    out: list[tuple] = []
    for r in rows:
        state = (r["fsc"], r["fso"], r["C"], r["O"], r["steps"])
        if not out or out[-1] != state:
            out.append(state)
    return out


DIAGNOSIS = re.compile(r"V1 -> (\w+) \{([^}]*)\}")


def alarm_events(path) -> list[tuple[str, str]]:
    """(alarm key, event) of each alarm entry journalled so far (a line being written is
    left for the next look)."""
    if not path.exists():
        return []
    events = []
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:
            continue
        if entry.get("type") == "alarm":
            events.append((entry["key"], entry["event"]))
    return events


def _reap(run: subprocess.Popen[str]) -> None:
    """Kill and reap a run whose end the test did not see (a wait that failed): no stray
    process keeps its port or its journal open for the next test."""
    if run.poll() is None:
        run.kill()
        run.communicate()


def test_a_fault_injected_in_serve_plant_is_diagnosed_as_in_the_simulation(server, tmp_path):
    """F13 (the valve jams on its next movement) injected in the plant process, seen only
    through Modbus: the same diagnoser transitions, alarms and final decision as the direct
    run of 8 s.

    The run through Modbus ends on its state, not after a time: it is stopped (SIGTERM, as
    a service manager stops it) once it has journalled every alarm event the simulation's
    8 s journalled (the last one, recovery needed, at 3.49 s; the jammed valve then rests
    with both orders withdrawn). Its `--for` and the wait are fail-safes only, far longer
    than the few seconds it takes (at a load of 30 on the 2 cores, 120 s of both, the
    simulation running beside it, were not enough). The simulation runs first: the real run
    then competes with no run of this test for the cores."""
    sim_journal = tmp_path / "sim.jsonl"
    sim = subprocess.run(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "8s", "--inject",
         "F13@0s", "--journal", str(sim_journal)], capture_output=True, text=True,
        cwd=ROOT, timeout=SAFE_S)
    assert sim.returncode == 0, sim.stderr
    expected = alarm_events(sim_journal)
    assert ("recovery_needed:V1_close", "raised") in expected, expected
    srv = server(VALVE, "--inject", "F13@0s")
    journal = tmp_path / "real.jsonl"
    run = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", f"{SAFE_S}s",
         "--plant", f"modbus://127.0.0.1:{srv.port}", "--journal", str(journal)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        deadline = time.monotonic() + SAFE_S
        while len(alarm_events(journal)) < len(expected) and run.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=WAIT)
    finally:
        _reap(run)
    assert run.returncode == 0, err
    assert alarm_events(journal) == expected, f"stdout:\n{out}\nstderr:\n{err}"
    seen = DIAGNOSIS.findall(out)
    assert seen == DIAGNOSIS.findall(sim.stdout) == [("A3", "F3, F13")], out
    final = [line for line in out.splitlines() if line.strip().startswith("final: V1")]
    assert final and "F3 (sensor fso stuck at 0) or F13" in final[0]


def test_a_headless_run_against_serve_plant_behaves_like_the_simulation(server, tmp_path):
    """A whole cycle of the valve and the start of the next, through Modbus, goes through
    the simulation's states in the same order; stopped while opening, it leaves the
    outputs safe.

    The run ends on the plant's state, not after a wall-clock time: it is stopped (SIGTERM,
    as a service manager stops it) once the server has seen the valve leave its closed end
    a second time; the open order then stays on for the 2 s of travel. A run of a fixed
    10 s, as this test was, ended before or after that movement depending on the load (each
    transition waits for a scan: at a load of 14 the cycle came late and the last state was
    missing); its states are compared as a prefix of the simulation's, which runs longer.
    The valve holds 1 s open (quick_valve): the second opening comes at 6.9 s."""
    valve = quick_valve(tmp_path / "valve")
    srv = server(valve)
    trace = tmp_path / "modbus.csv"
    run = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "run", str(valve), "--for", "120s",
         "--plant", f"modbus://127.0.0.1:{srv.port}", "--trace", str(trace)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    # The same project on the simulated plant, in virtual time, while the real run waits on
    # its valve (real time, a core idle).
    sim_trace = tmp_path / "sim.csv"
    sim = subprocess.Popen([sys.executable, "-m", "hmi.cli", "run", str(valve), "--for", "12s",
                            "--trace", str(sim_trace)], cwd=ROOT,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        def opening(line: str) -> bool:  # the valve off its closed end, the open order on
            return "fsc=0 fso=0" in line and line.endswith("C=0 O=1")
        try:
            first = srv.wait_for(opening, 120)
            srv.wait_for(opening, 120, start=srv.lines.index(first) + 1)
        except RuntimeError as exc:  # what the run saw, to say why
            run.send_signal(signal.SIGTERM)
            out, err = run.communicate(timeout=120)
            raise AssertionError(f"{exc}\nthe run:\n{out}\n{err}") from None
        run.send_signal(signal.SIGTERM)
        out, err = run.communicate(timeout=120)
    finally:
        _reap(run)
        sim.wait(120)
    assert run.returncode == 0, err
    assert sim.returncode == 0
    assert "of real time" in out and "Damage events: none" in out
    assert "connections lost 0" in out and "exception responses 0" in out
    # The run ended while the valve was opening: a stopping PLC leaves its outputs safe.
    assert "Stopped: stopped: safe outputs written" in out
    assert read_coils(srv.port) == [False, False]
    srv.stop()
    summary = srv.lines[-1]
    assert "cycles 1" in summary and "damage events: none" in summary, summary

    # The simulation went through the same states, in order.
    with trace.open() as f1, sim_trace.open() as f2:
        real, sim = list(csv.DictReader(f1)), list(csv.DictReader(f2))
    assert real[-1]["O"] == "1"  # stopped while opening
    # a whole cycle (open, hold, close, wait) and the second opening, as in the simulation
    assert len(states(real)) >= 8
    assert states(real) == states(sim)[:len(states(real))]


def test_server_killed_and_restarted_mid_run(server, tmp_path):
    # A copy of the valve whose safe state holds the close order, so that the safe vector
    # is visible on the restarted server (whose coils start at 0).
    folder = quick_valve(tmp_path / "valve")
    text = (folder / "project.yaml").read_text()
    (folder / "project.yaml").write_text(text.replace(
        "    safe: 0\n    address: coil:0", "    safe: 1\n    address: coil:0"))
    srv = server(folder)
    port = srv.port
    with Live(folder, port) as live:
        live.wait(lambda s: s.output_map == {"C": False, "O": True}, "the valve opening")
        srv.kill()
        lost = live.wait(lambda s: not s.plant.connected, "the loss to be seen")
        assert lost.latched[0].source == "plant" and "lost" in lost.latched[0].detail
        assert "PlantStatus" not in lost.plant.message
        # From then on: the safe vector, and steps held (the law does not run blind).
        frozen = live.wait(lambda s: "cannot connect" in s.plant.message, "retries")
        assert frozen.is_safe_latched and frozen.outputs == (True, False)
        assert frozen.latched == lost.latched  # one reason per outage, not one per retry
        assert frozen.fov == (True, False) and frozen.active_steps == ("X1",)
        # The alarm the operator sees (its explanation), with the reason.
        seen = live.cell(frozen)
        alarm = next(e for e in seen.explanations if e.kind == "plant")
        assert "plant connection lost" in alarm.what and alarm.latched
        assert "connection was closed" in alarm.why
        assert any(a.key == alarm.key for a in seen.alarms)

        mark = len(srv.lines)
        srv.port = port
        srv.start(WAIT)
        back = live.wait(lambda s: s.plant.connected, "the reconnection", since=len(live.snaps))
        # The first thing the restarted device receives is the safe vector, C on.
        srv.wait_for("C=1 O=0", WAIT, start=mark)
        assert read_coils(port) == [True, False]
        # Still latched: automatic operation waits for the operator.
        settle = live.wait(lambda s: s.time_us >= back.time_us + 500_000, "half a second")
        assert all(s.is_safe_latched and s.outputs == (True, False)
                   for s in live.snaps if back.scan <= s.scan <= settle.scan)
        result = live.session.command(FaultReset())
        assert result.accepted and "plant connection lost" in result.message
        resumed = live.wait(lambda s: not s.latched and s.output_map["O"], "the law to resume",
                            since=len(live.snaps))
        assert resumed.plant.connected
        srv.wait_for("C=0 O=1", WAIT, start=mark)


def test_pausing_a_real_plant_holds_it_safe(server, tmp_path):
    valve = quick_valve(tmp_path / "valve")
    srv = server(valve)
    with Live(valve, srv.port) as live:
        live.wait(lambda s: s.output_map["O"], "the valve opening")
        result = live.session.command(Pause())
        assert "outputs written safe while paused" in result.message
        assert read_coils(srv.port) == [False, False]
        paused_at = live.engine.scan
        opened = srv.lines.index(srv.wait_for("C=0 O=1", WAIT))
        parked = srv.lines.index(srv.wait_for("C=0 O=0", WAIT, start=opened + 1))
        mark = parked + 1
        assert not live.session.command(StepScans(1)).accepted
        deadline = time.monotonic() + 0.3
        while time.monotonic() < deadline:  # no scan drives it while paused
            assert read_coils(srv.port) == [False, False]
        assert live.engine.scan == paused_at
        assert live.session.command(Resume()).accepted
        live.wait(lambda s: s.output_map["O"], "the valve opening again", since=len(live.snaps))
        srv.wait_for("C=0 O=1", WAIT, start=mark)


REGISTER_VALVE = """
    name: register_valve
    scan_period: 10ms
    inputs:
      fsc: {description: closed end switch, address: "ir:2.3"}
      fso: {description: open end switch, address: "di:0"}
    outputs:
      C: {description: close order, address: "hr:5.1"}
      O: {description: open order, address: "coil:3"}
    control:
      grafcet:
        steps:
          0: {initial: true}
          1: {actions: [O]}
          2: {actions: [C]}
        transitions:
          - {from: 0, to: 1, when: fsc}
          - {from: 1, to: 2, when: fso}
          - {from: 2, to: 1, when: fsc}
    plant:
      kind: modbus
      model: valve
      params: {travel: 300ms}
"""


def test_register_bits_and_scattered_addresses_end_to_end(server, tmp_path):
    write_project(tmp_path, {"project.yaml": REGISTER_VALVE})
    srv = server(tmp_path)
    other = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=WAIT)
    assert other.connect()
    assert not other.write_register(5, 0x8000, device_id=1).isError()  # not ours: bit 15
    with Live(tmp_path, srv.port) as live:
        closing = live.wait(lambda s: s.active_steps == ("X2",) and s.output_map["C"],
                            "closing")
        # The server decoded C from bit 1 of holding register 5 (a Mask Write Register)...
        srv.wait_for("C=1 O=0", WAIT)
        # ...and the valve closed: fsc came back through bit 3 of input register 2.
        live.wait(lambda s: s.active_steps == ("X1",), "open again",
                  since=closing.scan)  # snaps[k] is scan k + 1
        assert live.plant.status.details["exceptions"] == 0
    # Stopped: the safe vector was written; the register's other bit was left alone.
    assert other.read_holding_registers(5, count=1, device_id=1).registers[0] == 0x8000
    assert other.read_coils(3, count=1, device_id=1).bits[0] is False
    other.close()


def test_exception_responses_are_reported_by_name(server, tmp_path):
    srv = server()
    folder = tmp_path / "far"
    shutil.copytree(VALVE, folder)
    text = (folder / "project.yaml").read_text()
    (folder / "project.yaml").write_text(text.replace("address: di:1", "address: di:100"))
    with Live(folder, srv.port) as live:
        snap = live.wait(lambda s: s.latched, "the exception")
        assert snap.plant.connected  # an exception response is an answer: the link is fine
        assert "Illegal Data Address (exception 2)" in snap.plant.message
        assert "Illegal Data Address" in snap.latched[0].detail
        assert "to read discrete inputs 100" in snap.latched[0].detail
        assert snap.outputs == (False, False)
        assert snap.plant.details["exceptions"] >= 1
        alarm = next(e for e in live.cell(snap).explanations if e.kind == "plant")
        assert "the plant answered Illegal Data Address" in alarm.what
        live.wait(lambda s: s.scan >= snap.scan + 20, "more scans")  # still scanning


def test_a_busy_device_is_reported_and_operation_resumes_after_reset(server):
    srv = server(VALVE, "--inject", "busy@0s+2s")
    with Live(VALVE, srv.port) as live:
        busy = live.wait(lambda s: "Server Device Busy" in s.plant.message, "busy answers")
        assert busy.latched and "Server Device Busy (exception 6)" in busy.latched[0].detail
        live.wait(lambda s: s.plant.message.startswith("connected"), "the end of busy")
        assert live.session.command(FaultReset()).accepted
        live.wait(lambda s: not s.latched and s.output_map["O"], "the valve opening",
                  since=len(live.snaps))


def test_a_device_that_stops_answering_times_out_and_is_reconnected(server):
    # mute from 1 s to 2 s of the server's clock (which starts before the run's): requests
    # time out after 200 ms, so the mute is seen several times over before it ends
    srv = server(VALVE, "--inject", "mute@1s+1s")
    with Live(VALVE, srv.port, timeout_us=200_000) as live:
        lost = live.wait(lambda s: not s.plant.connected, "the timeout")
        assert "within 200ms" in lost.plant.message
        assert lost.plant.details["timeouts"] >= 1
        assert lost.outputs == (False, False) and lost.latched[0].source == "plant"
        live.wait(lambda s: s.plant.connected and s.plant.message.startswith("connected")
                  and s.time_us > 2 * S, "answers again", since=len(live.snaps))


def test_read_only_mode_observes_and_writes_nothing(server):
    srv = server()
    # The "real PLC" (here a plain client) opens the valve.
    other = ModbusTcpClient("127.0.0.1", port=srv.port, timeout=WAIT)
    assert other.connect()
    assert not other.write_coils(0, [False, True], device_id=1).isError()
    other.close()
    with Live(VALVE, srv.port, read_only=True) as live:
        snap = live.wait(lambda s: s.value("fso"), "the valve open")
        # Detection only: the PLC holds O on the open valve; CSs2 (O and fso) is reported,
        # and what the device has is shown as it is, not corrected.
        report = snap.filter_report
        assert "CSs2" in report.violated_names and report.policy == "monitor"
        assert snap.outputs == (False, True) and not snap.filter_report.changes
        assert live.engine.policy == "monitor"
        assert not live.session.command(SetMode(True)).accepted
        live.wait(lambda s: s.scan >= snap.scan + 30, "more scans")
        seen = list(live.snaps)
    assert all(s.outputs == (False, True) and s.fov == (False, True) for s in seen)
    assert all(s.active_steps == ("X0",) for s in seen)  # the control law never ran
    assert live.plant.status.details["writes"] == 0 and live.plant.status.details["reads"] > 30
    assert read_coils(srv.port) == [False, True]
    srv.stop()
    assert " 1 writes," in srv.lines[-1], srv.lines[-1]  # the other client's, and only it


def test_a_slow_server_makes_overruns_that_are_counted(server):
    srv = server(VALVE, "--delay", "25ms")
    with Live(VALVE, srv.port) as live:
        live.wait(lambda s: live.runner.overruns >= 3 and s.plant.details["slow_scans"] >= 3,
                  "overruns")
        snap = live.snaps[-1]
        assert snap.plant.connected and not snap.latched


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_absent_server_is_retried_then_the_run_gives_up():
    port = _free_port()
    started = time.monotonic()
    # 800 ms: attempts at 0, 0.1, 0.3 and 0.7 s (the back-off doubles from 0.1 s)
    proc = subprocess.run(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "5s",
         "--plant", f"modbus://127.0.0.1:{port}", "--connect-timeout", "800ms"],
        capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 1
    assert f"no connection to the plant within 800ms: cannot connect to 127.0.0.1:{port} " \
        "unit 1: Connection refused" in proc.stderr
    assert proc.stderr.count("attempt ") >= 3  # retried, with backoff
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    assert time.monotonic() - started < 60


def test_a_run_waits_for_a_late_server(server):
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "hmi.cli", "run", str(VALVE), "--for", "300ms",
         "--plant", f"modbus://127.0.0.1:{port}", "--connect-timeout", "60s"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stderr is not None and proc.stdout is not None
    attempts: list[str] = []

    def read_stderr() -> None:
        for line in proc.stderr:
            attempts.append(line)
    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    deadline = time.monotonic() + WAIT
    while not any("attempt 2" in line for line in attempts) and time.monotonic() < deadline:
        time.sleep(0.05)
    srv = server(VALVE, port=port)
    out = proc.stdout.read()
    proc.wait(120)
    reader.join(5)
    assert proc.returncode == 0, "".join(attempts)
    assert "Connection refused" in "".join(attempts)
    assert "scans in" in out
    srv.stop()
    assert "1 connections" in srv.lines[-1]


def test_bench_prints_both_round_trips():
    proc = subprocess.run([sys.executable, "-m", "hmi.cli", "bench", "modbus", "--quick"],
                          capture_output=True, text=True, cwd=ROOT, timeout=180)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("== bench modbus:") and "could not" not in proc.stdout
    assert any("plchmi scan, outputs changing" in line and " ms" in line for line in lines)
    assert any("bare pymodbus" in line and " ms" in line for line in lines)


def test_the_sim_run_is_unchanged_by_the_clock_option():
    # The engine is deterministic; a Session without a clock keeps virtual time.
    session = make_session(VALVE)
    assert session.clock is None
    session.run_for(1 * S)
    assert session.engine.now == 1 * S


def test_serve_plant_prints_its_map(server):
    srv = server()
    assert srv.lines[0].startswith("Serving cispi_valve's simulated plant")
    assert any(line.split()[:3] == ["di:0", "fsc", "sensor"] for line in srv.lines)
    assert any(line.split()[:3] == ["coil:1", "O", "order"] for line in srv.lines)


def test_quitting_the_hmi_on_a_real_plant_leaves_its_outputs_safe(server, tmp_path,
                                                                   monkeypatch):
    """`plchmi ui` on serve-plant: q asks, y stops the cell (its runtime) and quits, and the
    plant is left with the safe vector written (the valve was being opened when the
    operator quit): the command returns once the runtime has stopped."""
    from ui_harness import screen_text, wait_live

    from hmi.cli import main
    from hmi.ui.app import PlcHmiApp
    from hmi.ui.dialogs import ConfirmDialog
    from hmi.ui.headless import press, wait_for_screen

    valve = quick_valve(tmp_path / "valve")
    srv = server(valve)
    monkeypatch.setenv("PLCHMI_DATA", str(tmp_path))
    seen: dict[str, object] = {}

    async def operator(pilot) -> None:
        app = pilot.app
        await wait_live(pilot, lambda: app.link.last is not None and
                        app.link.last.snapshot.output_map["O"], "the valve opening")
        seen["coils_before"] = read_coils(srv.port)
        await press(pilot, "q")
        await wait_for_screen(pilot, ConfirmDialog)
        seen["dialog"] = screen_text(app)
        await press(pilot, "y")

    run = PlcHmiApp.run
    monkeypatch.setattr(PlcHmiApp, "run", lambda self: run(self, headless=True,
                                                           size=(100, 30),
                                                           auto_pilot=operator))
    assert main(["ui", str(valve), "--plant", f"modbus://127.0.0.1:{srv.port}",
                 "--journal", str(tmp_path / "journal.jsonl")]) == 0
    assert seen["coils_before"] == [False, True]  # O on while the valve opened
    assert "safe value (C=0, O=0)" in str(seen["dialog"])
    assert read_coils(srv.port) == [False, False]

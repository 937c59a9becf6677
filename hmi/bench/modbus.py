"""`plchmi bench modbus`: what one scan's Modbus I/O costs, next to bare pymodbus.

Both are measured in the same run, against the same `plchmi serve-plant` in another process,
over loopback, alternating in blocks of 100 so that machine load affects both alike:

* our plant: `ModbusPlant.read` + `ModbusPlant.write` of a scan, with outputs changing every
  scan (a read of the inputs and a write of the coils), and with outputs steady (the write is
  skipped: only the read goes out);
* bare pymodbus: `read_discrete_inputs` + `write_coils` on a plain `ModbusTcpClient`.
"""

from __future__ import annotations

import argparse
import tempfile
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from hmi.bench import percentile
from hmi.plant.modbus.client import ModbusPlant, ModbusSettings
from hmi.plant.modbus.server_process import ServerProcess
from hmi.project.loader import load_project

# The CISPI valve's I/O map: two end switches on discrete inputs, two orders on coils.
PROJECT = """
name: bench_valve
scan_period: 10ms
inputs:
  fsc: {description: closed end switch, address: "di:0"}
  fso: {description: open end switch, address: "di:1"}
outputs:
  C: {description: close order, address: "coil:0"}
  O: {description: open order, address: "coil:1"}
control:
  equations:
    C: "False"
    O: "False"
plant:
  kind: modbus
  model: valve
  timeout: 2s
"""
BLOCK = 100
SECTION = "modbus"
HELP = "one scan's Modbus I/O over loopback (plchmi's plant vs bare pymodbus), p50/p99/max"


def run(args: argparse.Namespace) -> None:
    """Print the figures; if they cannot be measured, say why (a bench never fails)."""
    scans = 300 if getattr(args, "quick", False) else 2000
    try:
        measure(scans, _out)
    except Exception as exc:
        _out(f"  could not measure: {type(exc).__name__}: {exc}")


def _out(line: str) -> None:
    print(line, flush=True)


def measure(scans: int, out: Callable[[str], None]) -> None:
    with tempfile.TemporaryDirectory(prefix="plchmi-bench-") as folder:
        (Path(folder) / "project.yaml").write_text(textwrap.dedent(PROJECT))
        project = load_project(folder)
        with ServerProcess(folder) as server:
            settings = ModbusSettings(port=server.port, timeout_us=2_000_000)
            plant = ModbusPlant(project, settings, period_us=10_000)
            bare = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2, retries=0)
            if not plant.connect() or not bare.connect():
                raise RuntimeError(f"cannot connect to the server: {plant.message}")
            try:
                figures = _measure(plant, bare, scans)
            finally:
                plant.close()
                bare.close()
    out(f"loopback TCP, plchmi serve-plant in another process, {scans} samples each "
        "(p50 / p99 / max)")
    for label, samples in figures:
        p50, p99, worst = percentile(samples, 50), percentile(samples, 99), max(samples)
        out(f"  {label:<62} {p50 / 1000:6.3f} / {p99 / 1000:6.3f} / {worst / 1000:6.3f} ms")


def _measure(plant: ModbusPlant, bare: ModbusTcpClient, scans: int
             ) -> list[tuple[str, list[float]]]:
    changing: list[float] = []
    steady: list[float] = []
    raw: list[float] = []
    now = 0
    flip = False
    for i in range(-1, scans // BLOCK + (1 if scans % BLOCK else 0)):
        n = BLOCK if i >= 0 else 20  # block -1 warms up all three
        n = min(n, scans - len(raw)) if i >= 0 else n
        for _ in range(n):
            flip = not flip
            now += 10_000
            t = time.perf_counter()
            plant.read(now)
            plant.write(now, {"C": False, "O": flip})
            dt = (time.perf_counter() - t) * 1e6
            if i >= 0:
                changing.append(dt)
        for _ in range(n):
            now += 10_000
            t = time.perf_counter()
            plant.read(now)
            plant.write(now, {"C": False, "O": flip})
            dt = (time.perf_counter() - t) * 1e6
            if i >= 0:
                steady.append(dt)
        for _ in range(n):
            flip = not flip
            t = time.perf_counter()
            r = bare.read_discrete_inputs(0, count=2, device_id=1)
            w = bare.write_coils(0, [False, flip], device_id=1)
            dt = (time.perf_counter() - t) * 1e6
            if r.isError() or w.isError():
                raise RuntimeError(f"bare pymodbus request failed: {r} {w}")
            if i >= 0:
                raw.append(dt)
    return [
        ("plchmi scan, outputs changing (read di 0-1 + write coils 0-1)", changing),
        ("plchmi scan, outputs steady (read di 0-1; write skipped)", steady),
        ("bare pymodbus read_discrete_inputs + write_coils", raw),
    ]

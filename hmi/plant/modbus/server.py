"""`plchmi serve-plant`: a project's simulated plant, in real time, as a Modbus TCP server.

The simulated devices are the same :class:`SimPlant` a headless run uses; here their clock is
the wall clock (integer microseconds since the server started) and their I/O is the project's
address map: sensors are served where their inputs are mapped (discrete inputs, input
register bits...), orders are taken from where the outputs are mapped (coils, holding
register bits). With an HMI on the other end this behaves like a real cell, and any Modbus
client (mbpoll) can look at it.

The physics is advanced on every request, just before it is answered, through pymodbus's
`SimDevice(action=...)` hook: a read always sees the sensors at the moment it arrives, and a
write changes the orders at the moment it arrives. A 10 ms tick also advances it, to print
every change of the served I/O and every plant event as it happens.

Communication faults are injected like device faults (`--inject busy@5s+2s`): `busy` answers
every request with exception 6 (Server Device Busy), `mute` stops answering (the connection
stays open, requests time out). `--delay 30ms` answers every request late (a slow server).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from hmi.errors import UsageError
from hmi.plant.injection import Injection
from hmi.plant.modbus.address_map import BIT_TABLES, AddressMap
from hmi.plant.sim.plant import SimPlant
from hmi.project.model import Project
from hmi.timefmt import format_duration, seconds

logging.getLogger("pymodbus").addHandler(logging.NullHandler())
logging.getLogger("pymodbus").propagate = False

COMM_FAULTS = {
    "busy": "answer every request with exception 6, Server Device Busy",
    "mute": "stop answering (requests time out, the connection stays open)",
}
# Function code -> the table it addresses.
FC_TABLE = {1: "coil", 5: "coil", 15: "coil", 2: "di", 3: "hr", 6: "hr", 16: "hr", 22: "hr",
            23: "hr", 4: "ir"}
TICK_S = 0.01


@dataclass(frozen=True)
class CommFault:
    code: str  # busy, mute
    at_us: int
    until_us: int | None

    def active(self, now_us: int) -> bool:
        return self.at_us <= now_us and (self.until_us is None or now_us < self.until_us)


def split_injections(injections: list[Injection]) -> tuple[list[Injection], list[CommFault]]:
    """Device faults for the simulated plant, communication faults for the server."""
    device, comm = [], []
    for inj in injections:
        if inj.code in COMM_FAULTS and inj.device is None:
            until = inj.at_us + inj.duration_us if inj.duration_us is not None else None
            comm.append(CommFault(inj.code, inj.at_us, until))
        else:
            device.append(inj)
    return device, comm


class PlantServer:
    """The simulated plant behind pymodbus's TCP server (see the module docstring)."""

    def __init__(self, project: Project, unit: int, injections: list[Injection] = (),
                 delay_us: int = 0, out: Callable[[str], None] = print):
        self.project = project
        self.unit = unit
        self.delay_us = delay_us
        self.out = out
        self.plant = SimPlant(project)
        device_faults, self.comm_faults = split_injections(list(injections))
        for inj in device_faults:
            self.plant.resolve(inj)
        for inj in device_faults:
            self.plant.inject(inj)
        self.injections = list(injections)
        self.map = AddressMap.for_project(project)
        driven = {name for name in self.plant.input_names if name not in self.plant.free_inputs}
        self.sensors = tuple(p for p in self.map.inputs if p.name in driven)
        self.orders = dict.fromkeys(self.plant.output_names, False)
        self.counts = {"requests": 0, "reads": 0, "writes": 0, "exceptions": 0, "clients": 0}
        self._t0 = time.monotonic_ns()
        self._shown: tuple | None = None
        self._events_shown = 0
        self._comm_shown: set[tuple[str, bool]] = set()
        self.server: ModbusTcpServer | None = None

    def now_us(self) -> int:
        return (time.monotonic_ns() - self._t0) // 1000

    # -- the datastore hook ----------------------------------------------------------------
    def device(self) -> SimDevice:
        sizes = self.map.table_sizes()
        blocks = []
        for table in ("coil", "di", "hr", "ir"):
            if table in BIT_TABLES:
                count = max(16, -(-sizes[table] // 16) * 16)
                blocks.append([SimData(0, count=count, values=False, datatype=DataType.BITS)])
            else:
                count = max(1, sizes[table])
                blocks.append([SimData(0, count=count, values=0,
                                       datatype=DataType.REGISTERS)])
        return SimDevice(self.unit, simdata=tuple(blocks), action=self._action)

    async def _action(self, fc: int, start: int, address: int, count: int,
                      registers: list[int], set_values: list | None) -> ExcCodes | None:
        self.counts["requests"] += 1
        try:
            now = self.now_us()
            for fault in self.comm_faults:
                if fault.active(now):
                    if fault.code == "busy":
                        self.counts["exceptions"] += 1
                        return ExcCodes.DEVICE_BUSY
                    # mute: answer only once the window is over (the client gave up long ago)
                    wait_us = (fault.until_us - now) if fault.until_us is not None else 1 << 40
                    await asyncio.sleep(min(wait_us, 1 << 30) / 1e6)
                    now = self.now_us()
            if self.delay_us:
                await asyncio.sleep(self.delay_us / 1e6)
                now = self.now_us()
            table = FC_TABLE.get(fc)
            if table is None:
                self.counts["exceptions"] += 1
                return ExcCodes.ILLEGAL_FUNCTION
            if set_values is None:
                self.counts["reads"] += 1
                self._refresh(now, table, start, registers)
            else:
                self.counts["writes"] += 1
                self._take_orders(now, table, address, set_values)
            return None
        except Exception as exc:  # never let a bug here kill the server: say it, answer 4
            self.out(f"{seconds(self.now_us())} s  internal error: {type(exc).__name__}: {exc}")
            self.counts["exceptions"] += 1
            return ExcCodes.DEVICE_FAILURE

    def _refresh(self, now: int, table: str, start: int, registers: list[int]) -> None:
        """Write the sensors' values at `now` into the block about to be read."""
        values = self.plant.read(now)
        for p in self.sensors:
            if p.address.table != table:
                continue
            if table in BIT_TABLES:
                word, bit = p.address.index // 16 - start, p.address.index % 16
            else:
                word, bit = p.address.index - start, p.address.bit or 0
            if values[p.name]:
                registers[word] |= 1 << bit
            else:
                registers[word] &= ~(1 << bit)

    def _take_orders(self, now: int, table: str, address: int, set_values: list) -> None:
        changed = False
        for p in self.map.outputs:
            if p.address.table != table:
                continue
            offset = p.address.index - address
            if not 0 <= offset < len(set_values):
                continue
            if table in BIT_TABLES:
                value = bool(set_values[offset])
            else:
                value = bool((int(set_values[offset]) >> (p.address.bit or 0)) & 1)
            if self.orders[p.name] != value:
                self.orders[p.name] = value
                changed = True
        if changed:
            self.plant.write(now, self.orders)
            self._show(now)  # at once: a short pulse must not fall between two ticks

    # -- what the console shows ------------------------------------------------------------
    def banner(self, host: str, port: int) -> list[str]:
        devices = ", ".join(f"{d.name} ({d.MODEL})" for d in self.plant.devices) or "none"
        lines = [f"Serving {self.project.name}'s simulated plant [{devices}] as Modbus TCP "
                 f"unit {self.unit} on {host}:{port}"]
        sensor_names = {p.name for p in self.sensors}
        for p in self.map.points:
            role = ("sensor" if p.name in sensor_names else "input, not simulated") \
                if p.kind == "input" else "order"
            var = self.project.variable(p.name)
            text = var.description if var is not None else ""
            lines.append(f"  {p.address!s:<9} {p.name:<10} {role:<21} {text}")
        sizes = self.map.table_sizes()
        served = []
        for table in ("coil", "di", "hr", "ir"):
            n = max(16, -(-sizes[table] // 16) * 16) if table in BIT_TABLES \
                else max(1, sizes[table])
            served.append(f"{table} 0-{n - 1}")
        lines.append("  served: " + ", ".join(served) + "; other addresses answer exception 2")
        if self.injections:
            lines.append("Faults scheduled: " + ", ".join(str(i) for i in self.injections))
        if self.delay_us:
            lines.append(f"Every answer delayed by {format_duration(self.delay_us)}")
        lines.append("Ctrl-C stops the server.")
        return lines

    def _show(self, now: int) -> None:
        """Print the served I/O at `now` if it changed since the last line printed."""
        values = self.plant.read(now)
        shown = tuple(values[p.name] for p in self.map.inputs) + tuple(self.orders.values())
        if shown != self._shown:
            self._shown = shown
            io = " ".join(f"{p.name}={int(values[p.name])}" for p in self.map.inputs)
            orders = " ".join(f"{n}={int(v)}" for n, v in self.orders.items())
            self.out(f"{seconds(now):>10} s  {io}  |  {orders}")

    def tick(self) -> None:
        """Advance the physics to now and print what changed."""
        now = self.now_us()
        self._show(now)
        events = self.plant.events()
        for event in events[self._events_shown:]:
            damage = " (damage)" if event.damage else ""
            self.out(f"{seconds(event.time_us):>10} s  {event.device} {event.kind}{damage}: "
                     f"{event.detail}")
        self._events_shown = len(events)
        for fault in self.comm_faults:
            for edge, on in (("starts", True), ("ends", False)):
                at = fault.at_us if on else fault.until_us
                if at is not None and now >= at and (fault.code, on) not in self._comm_shown:
                    self._comm_shown.add((fault.code, on))
                    self.out(f"{seconds(at):>10} s  communication fault {fault.code} {edge}")

    def on_connect(self, connected: bool) -> None:
        if connected:
            self.counts["clients"] += 1
        self.out(f"{seconds(self.now_us()):>10} s  client "
                 f"{'connected' if connected else 'disconnected'}")

    def summary(self) -> str:
        counters = self.plant.counters()
        damage = self.plant.damage()
        c = self.counts
        return (f"Stopped after {seconds(self.now_us())} s: {c['requests']} requests "
                f"({c['reads']} reads, {c['writes']} writes, {c['exceptions']} exceptions) "
                f"from {c['clients']} connections; plant: "
                + (", ".join(f"{k} {v}" for k, v in counters) or "-")
                + f"; damage events: {len(damage) or 'none'}")

    # -- running ---------------------------------------------------------------------------
    async def serve(self, host: str, port: int) -> int:
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        self.server = ModbusTcpServer([self.device()], address=(host, port),
                                      trace_connect=self.on_connect)
        try:
            await self.server.serve_forever(background=True)
        except RuntimeError:
            raise UsageError(f"cannot listen on {host}:{port} (is the port already in use?)"
                             ) from None
        sockets = getattr(self.server.transport, "sockets", None) or ()
        bound = sockets[0].getsockname()[1] if sockets else port
        self._t0 = time.monotonic_ns()
        for line in self.banner(host, bound):
            self.out(line)
        try:
            while not stop.is_set():
                self.tick()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), TICK_S)
        finally:
            await self.server.shutdown()
        self.tick()
        self.out(self.summary())
        return 0


def run_server(project: Project, host: str, port: int, unit: int,
               injections: list[Injection], delay_us: int = 0) -> int:
    def out(line: str) -> None:
        print(line, flush=True)
    server = PlantServer(project, unit, injections, delay_us, out)
    return asyncio.run(server.serve(host, port))

"""`plchmi serve-plant`: a project's simulated plant, in real time, as a Modbus TCP server.

The simulated devices are the same :class:`SimPlant` a headless run uses; here their clock is
the wall clock (integer microseconds since the server started) and their I/O is the project's
address map: sensors are served where their inputs are mapped (discrete inputs, input
register bits...), orders are taken from where the outputs are mapped (coils, holding
register bits). With an HMI on the other end this behaves like a real cell, and any Modbus
client (mbpoll) can look at it. The protocol itself is modbus_tcp_server's.

The physics is advanced on every request, just before it is answered: a read always sees
the sensors at the moment it arrives, and a write changes the orders at the moment it
arrives. A 10 ms tick also advances it, to print every change of the served I/O and every
plant event as it happens.

Communication faults are injected like device faults (`--inject busy@5s+2s`): `busy` answers
every request with exception 6 (Server Device Busy), `mute` stops answering (the connection
stays open, requests time out). `--delay 30ms` answers every request late (a slow server).

`--watchdog 500ms` is the communication watchdog of a fieldbus coupler: if no request comes
for that long (the controller died, its link broke), the device sets every order to the
project's safe value by itself and says so, and keeps them there until a controller writes
them again.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from hmi.errors import UsageError
from hmi.plant.modbus.address_map import BIT_TABLES, AddressMap
from hmi.plant.modbus.frame import SERVER_DEVICE_BUSY
from hmi.plant.modbus.tcp_server import (
    IDLE_S,
    MAX_CONNECTIONS,
    ModbusServer,
    Refused,
    Request,
    Tables,
)
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.model import Project
from hmi.timefmt import format_duration, seconds

COMM_FAULTS = {
    "busy": "answer every request with exception 6, Server Device Busy",
    "mute": "stop answering (requests time out, the connection stays open)",
}
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
    """The simulated plant behind our Modbus TCP server (see the module docstring)."""

    def __init__(self, project: Project, unit: int, injections: Sequence[Injection] = (),
                 delay_us: int = 0, out: Callable[[str], None] = print,
                 max_connections: int = MAX_CONNECTIONS, idle_s: float = IDLE_S,
                 warn: Callable[[str], None] | None = None, watchdog_us: int | None = None):
        self.project = project
        self.watchdog_us = watchdog_us
        self._last_request_us = 0
        self.watchdog_trips = 0
        self._tripped = False
        self.unit = unit
        self.delay_us = delay_us
        self.out = out
        self.warn = warn or out
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
        self._t0 = time.monotonic_ns()
        self._shown: tuple[object, ...] | None = None
        self._events_shown = 0
        self._comm_shown: set[tuple[str, bool]] = set()
        self.tables = Tables(self.served_sizes(), self._refresh, self._take_orders)
        self.modbus = ModbusServer(self.tables, unit, self._log, self._gate, max_connections,
                                   idle_s)

    def now_us(self) -> int:
        return (time.monotonic_ns() - self._t0) // 1000

    def served_sizes(self) -> dict[str, int]:
        """Each bit table from 0 to its highest used address rounded up to 16 (at least 16),
        each register table from 0 to its highest used register (at least 1)."""
        sizes = self.map.table_sizes()
        return {table: max(16, -(-n // 16) * 16) if table in BIT_TABLES else max(1, n)
                for table, n in sizes.items()}

    def _log(self, text: str) -> None:
        self.out(f"{seconds(self.now_us()):>10} s  {text}")

    # -- the hooks of the Modbus server ------------------------------------------------------
    async def _gate(self, request: Request) -> None:
        """Communication faults and delay, before a request is carried out."""
        now = self.now_us()
        self._last_request_us = now  # (the watchdog is fed by every request)
        self._tripped = False
        for fault in self.comm_faults:
            if fault.active(now):
                if fault.code == "busy":
                    raise Refused(SERVER_DEVICE_BUSY)
                # mute: answer only once the window is over (the client gave up long ago)
                wait_us = (fault.until_us - now) if fault.until_us is not None else 1 << 40
                await asyncio.sleep(min(wait_us, 1 << 30) / 1e6)
                now = self.now_us()
        if self.delay_us:
            await asyncio.sleep(self.delay_us / 1e6)

    def _refresh(self, table: str) -> None:
        """Put the sensors' values at this moment into `table`, about to be read."""
        values = self.plant.read(self.now_us())
        for p in self.sensors:
            if p.address.table != table:
                continue
            if table in BIT_TABLES:
                self.tables.bits[table][p.address.index] = values[p.name]
            else:
                registers = self.tables.registers[table]
                mask = 1 << (p.address.bit or 0)
                word = registers[p.address.index]
                registers[p.address.index] = word | mask if values[p.name] else word & ~mask

    def _take_orders(self, table: str) -> None:
        """A write changed `table`: the orders mapped there, at this moment."""
        changed = False
        for p in self.map.outputs:
            if p.address.table != table:
                continue
            if table in BIT_TABLES:
                value = self.tables.bits[table][p.address.index]
            else:
                value = bool(self.tables.registers[table][p.address.index]
                             >> (p.address.bit or 0) & 1)
            if self.orders[p.name] != value:
                self.orders[p.name] = value
                changed = True
        if changed:
            now = self.now_us()
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
        served = ", ".join(f"{table} 0-{n - 1}" for table, n in self.served_sizes().items())
        lines.append(f"  served: {served}; other addresses answer exception 2")
        m = self.modbus
        lines.append(f"  at most {m.max_connections} connections at once; a connection with "
                     f"no request for {m.idle_s:g} s is closed")
        if self.injections:
            lines.append("Faults scheduled: " + ", ".join(str(i) for i in self.injections))
        if self.delay_us:
            lines.append(f"Every answer delayed by {format_duration(self.delay_us)}")
        if self.watchdog_us is not None:
            lines.append(f"Watchdog: no request for {format_duration(self.watchdog_us)} sets "
                         "every order to its safe value")
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

    def watch(self, now: int) -> None:
        """The communication watchdog (module docstring): no request for its time, every
        order goes to its safe value."""
        if self.watchdog_us is None or self._tripped or \
                now - self._last_request_us < self.watchdog_us:
            return
        self._tripped = True
        self.watchdog_trips += 1
        safe = {v.name: v.safe for v in self.project.outputs}
        tables = set()
        for p in self.map.outputs:
            value = safe.get(p.name, False)
            table = p.address.table
            tables.add(table)
            if table in BIT_TABLES:
                self.tables.bits[table][p.address.index] = value
            else:
                registers = self.tables.registers[table]
                mask = 1 << (p.address.bit or 0)
                word = registers[p.address.index]
                registers[p.address.index] = word | mask if value else word & ~mask
        self.out(f"{seconds(now):>10} s  watchdog: no request for "
                 f"{format_duration(self.watchdog_us)}: every order set to its safe value")
        for table in sorted(tables):
            self._take_orders(table)

    def tick(self) -> None:
        """Advance the physics to now and print what changed."""
        now = self.now_us()
        self.watch(now)
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

    def summary(self) -> str:
        counters = self.plant.counters()
        damage = self.plant.damage()
        c = self.modbus.counts
        closed = [f"{n} {what}" for n, what in (
            (c.refused, "refused over the limit"), (c.idle_closed, "closed when idle"),
            (c.slow_closed, "closed as too slow"),
            (c.bad_frames, "closed on a frame that is not Modbus TCP")) if n]
        return (f"Stopped after {seconds(self.now_us())} s: {c.requests} requests "
                f"({c.reads} reads, {c.writes} writes, {c.exceptions_text()}) "
                f"from {c.connections} connections"
                + (f" ({', '.join(closed)})" if closed else "") + "; plant: "
                + (", ".join(f"{k} {v}" for k, v in counters) or "-")
                + f"; damage events: {len(damage) or 'none'}")

    # -- running ---------------------------------------------------------------------------
    async def serve(self, host: str, port: int) -> int:
        loop = asyncio.get_running_loop()
        stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        try:
            bound = await self.modbus.start(host, port)
        except OSError as exc:  # asyncio's message repeats the address: the errno's words
            reason = os.strerror(exc.errno) if exc.errno else str(exc)
            raise UsageError(f"cannot listen on {host}:{port}: {reason}") from None
        self._t0 = time.monotonic_ns()
        self._last_request_us = 0
        if not is_loopback(host):
            self.warn(f"plchmi: warning: listening on {host}: the simulated plant can be read "
                      f"and driven by anyone who can reach port {bound} (Modbus has no "
                      "authentication); use --host 127.0.0.1 to keep it on this machine")
        for line in self.banner(host, bound):
            self.out(line)
        try:
            while not stop.is_set():
                self.tick()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), TICK_S)
        finally:
            await self.modbus.close()
        self.tick()
        self.out(self.summary())
        return 0


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a name: it may well resolve to a public address


def run_server(project: Project, host: str, port: int, unit: int,
               injections: list[Injection], delay_us: int = 0,
               max_connections: int = MAX_CONNECTIONS, idle_s: float = IDLE_S,
               watchdog_us: int | None = None) -> int:
    def out(line: str) -> None:
        print(line, flush=True)

    def warn(line: str) -> None:
        print(line, file=sys.stderr, flush=True)
    server = PlantServer(project, unit, injections, delay_us, out, max_connections, idle_s,
                         warn, watchdog_us)
    return asyncio.run(server.serve(host, port))

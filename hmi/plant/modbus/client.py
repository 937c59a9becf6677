"""A real plant over Modbus TCP: the engine's inputs read from a device, its outputs written.

The engine's scan is synchronous, so is the connection (modbus_link): a scan's requests go
out one at a time, in order, and their checked answers are the scan's input image.

Faults never escape as anything but :class:`PlantError`, whose message is stable for a given
cause (the engine's latch keeps one reason per distinct message), and :attr:`status` says
what is going on in plain words:

* not connected (at start, or after a loss): every read raises; nothing is ever written
  while disconnected;
* connection closed, no answer within the timeout, or an answer that breaks the protocol
  (wrong transaction id, unit, function code, byte count, length...: see
  modbus_frame.check_answer): the socket is closed (a late answer could otherwise be taken
  for the next request's), the plant is disconnected, the read raises with what was wrong;
* an exception response (Illegal Data Address, Server Device Busy...): the read or write
  raises with the exception's name; the connection is kept.

Reconnection backs off exponentially (0.1 s, doubling, at most 2 s between attempts) and the
back-off is reset only by a scan whose requests all got valid answers, never by a mere
connection: a device that accepts connections and then drops them, or answers nonsense, gets
a few connections a second at first and one every 2 s after, not one per scan.

Outputs are written when they change, in full after every (re)connection (so the first
thing a reconnected device receives is the whole vector the engine holds: the safe vector,
since the engine latches safe on the loss), and in full at least every `write_refresh`, so
that a device whose outputs were changed behind our back is corrected within that time.
In read-only mode nothing is written, ever: :meth:`ModbusPlant.write` returns at once, and
the outputs' addresses are read back instead.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any
from urllib.parse import urlsplit

from hmi.errors import UsageError
from hmi.plant.base import Plant, PlantError, PlantState, PlantStatus
from hmi.plant.modbus.address_map import AddressMap
from hmi.plant.modbus.frame import (
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    mask_write_request,
    read_request,
    write_coils_request,
)
from hmi.plant.modbus.link import (
    ConnectFailed,
    ExceptionAnswer,
    InvalidAnswer,
    LinkError,
    ModbusLink,
    NoAnswer,
)
from hmi.plant.modbus.link_log import LinkLog
from hmi.project.model import PlantSpec, Project

READ_FUNCTION = {"coil": READ_COILS, "di": READ_DISCRETE_INPUTS,
                 "hr": READ_HOLDING_REGISTERS, "ir": READ_INPUT_REGISTERS}
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0
URL_HINT = "modbus://HOST:PORT[/UNIT], e.g. modbus://127.0.0.1:5020/1"


@dataclass(frozen=True)
class ModbusSettings:
    host: str = "127.0.0.1"
    port: int = 502
    unit: int = 1
    timeout_us: int = 1_000_000
    read_gap: int = 8
    write_refresh_us: int = 1_000_000

    @classmethod
    def from_spec(cls, spec: PlantSpec) -> ModbusSettings:
        return cls(spec.host, spec.port, spec.unit, spec.timeout_us, spec.read_gap,
                   spec.write_refresh_us)

    @property
    def where(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port} unit {self.unit}"


def parse_plant_url(text: str, base: ModbusSettings) -> ModbusSettings:
    """`modbus://HOST:PORT[/UNIT]` over the project's settings; a UsageError if malformed."""
    bad = f"--plant {text!r}: expected {URL_HINT}"
    try:
        url = urlsplit(text)
    except ValueError as exc:  # "Invalid IPv6 URL": a '[' without its ']'
        raise UsageError(f"{bad} ({exc}; an IPv6 address is written in brackets, "
                         "modbus://[::1]:5020)") from None
    try:
        port = url.port
    except ValueError:
        raise UsageError(bad + " (the port must be a number from 1 to 65535)") from None
    if url.scheme != "modbus" or not url.hostname or url.query or url.fragment \
            or url.username or url.password:
        raise UsageError(bad)
    if port is None or port == 0:
        raise UsageError(bad + " (the port is missing)")
    unit = base.unit
    path = url.path.strip("/")
    if path:
        if not (path.isascii() and path.isdigit()) or len(path) > 3 or int(path) > 255:
            raise UsageError(bad + f" (unit {path!r} is not a number from 0 to 255)")
        unit = int(path)
    return replace(base, host=url.hostname, port=port, unit=unit)


class ModbusPlant(Plant):
    """The Plant contract over Modbus TCP (see the module docstring for fault handling)."""

    kind = "modbus"
    is_real = True

    def __init__(self, project: Project, settings: ModbusSettings, read_only: bool = False,
                 period_us: int | None = None, clock: Callable[[], float] = time.monotonic):
        self.project = project
        self.clock = clock  # for the back-off (seconds); the tests give a virtual one
        self.settings = settings
        self.read_only = read_only
        self.period_us = period_us or project.scan_period_us
        self.input_names = tuple(v.name for v in project.inputs)
        self.output_names = tuple(v.name for v in project.outputs)
        self.map = AddressMap.for_project(project, settings.read_gap, read_back=read_only)
        # Each read request is the same every scan: its PDU is built once.
        self._reads = tuple((rng, read_request(READ_FUNCTION[rng.table], rng.start, rng.count),
                             f"read {rng}") for rng in self.map.reads)
        self._conn: ModbusLink | None = None
        self.connected = False
        self.ever_connected = False
        self.message = "not connected yet"
        self._down_reason = f"not connected to {settings.where}"
        self._outage = False  # since a problem, until a scan's I/O all works again
        self._backoff_s = BACKOFF_FIRST_S
        self._next_attempt = 0.0  # clock() of the next connection attempt
        self.attempts = 0
        self._written: dict[object, tuple[int, ...]] = {}  # plan entry -> values last written
        self._last_full_us: int | None = None
        self.stats = dict.fromkeys(
            ("requests", "reads", "writes", "stop_writes", "exceptions", "timeouts", "invalid",
             "losses", "connects", "slow_scans"), 0)
        self.last_exception = ""
        self.io_us: deque[float] = deque(maxlen=10_000)  # wall time of each scan's I/O
        self._scan_io = 0.0
        self._scan_ok = False
        self.link: LinkLog = LinkLog(settings.where, clock)  # connection events for the journal

    # -- connection ----------------------------------------------------------------------
    def connect(self) -> bool:
        """One connection attempt now; on failure the next is scheduled after the back-off.

        A connection does not reset the back-off: only a scan whose requests all worked does.
        """
        self.attempts += 1
        s = self.settings
        conn = ModbusLink(s.host, s.port, s.unit, s.timeout_us)
        try:
            conn.connect()
        except ConnectFailed as exc:
            failed = f"cannot connect to {s.where}: {exc}"
            if not self.ever_connected:
                # After a loss, the loss stays the reason the engine is given (one latch
                # reason per outage); the failed attempts show in the status message.
                self._down_reason = failed
            self._outage = True
            self._schedule_retry(failed)
            self.link.connect_failed(self.attempts, failed)
            return False
        self._conn = conn
        self.connected = True
        self.ever_connected = True
        self.stats["connects"] += 1
        self._written.clear()  # the first write after a connection is a full one
        self.message = f"connected to {s.where}"
        self.link.connected(self.attempts)
        return True

    @property
    def retry_in_s(self) -> float:
        return max(0.0, self._next_attempt - self.clock())

    def _schedule_retry(self, why: str) -> None:
        self._next_attempt = self.clock() + self._backoff_s
        self.message = f"{why}; next try in {self._backoff_s:g} s"
        self._backoff_s = min(self._backoff_s * 2, BACKOFF_MAX_S)

    def _lost(self, reason: str) -> PlantError:
        """Drop the connection (a late answer must not pass for the next one's)."""
        if self._conn is not None:
            self._conn.close()
        self._conn = None
        self.connected = False
        self.stats["losses"] += 1
        if not self._outage:  # the outage's first problem is the reason, until it is over
            self._down_reason = f"{self.settings.where}: {reason}"
        self._outage = True
        self._schedule_retry(f"connection to {self.settings.where} lost: {reason}")
        self.link.lost(reason)
        return PlantError(self._down_reason)

    def _ensure_connected(self) -> ModbusLink:
        if not self.connected and self.clock() >= self._next_attempt:
            self.connect()
        if not self.connected or self._conn is None:
            raise PlantError(self._down_reason)
        return self._conn

    def _request(self, conn: ModbusLink, pdu: bytes, what: str) -> tuple[int, ...]:
        """One request; its values, or a PlantError saying what went wrong."""
        self.stats["requests"] += 1
        try:
            return conn.request(pdu, what).values
        except NoAnswer as exc:
            self.stats["timeouts"] += 1
            raise self._lost(str(exc)) from None
        except InvalidAnswer as exc:
            self.stats["invalid"] += 1
            raise self._lost(str(exc)) from None
        except LinkError as exc:
            raise self._lost(str(exc)) from None
        except ExceptionAnswer as exc:
            self.stats["exceptions"] += 1
            self.last_exception = exc.name
            detail = f"{self.settings.where} answered {exc} to {what}"
            self.message = detail
            self.link.exception(exc.name, detail)
            raise PlantError(detail, lost=False) from None

    # -- the engine's side ---------------------------------------------------------------
    def read(self, now_us: int) -> Mapping[str, bool]:
        started = time.perf_counter()
        self._scan_ok = False
        conn = self._ensure_connected()
        values: dict[str, bool] = {}
        try:
            for rng, pdu, what in self._reads:
                # check_answer made sure there are exactly rng.count values
                self.map.decode(rng, self._request(conn, pdu, what), values)
                self.stats["reads"] += 1
            self._scan_ok = True
        finally:
            self._scan_io = time.perf_counter() - started
            if self.read_only:  # no write follows: the scan's I/O ends here
                self._end_scan(self._scan_io)
        self.message = f"connected to {self.settings.where}"
        return values

    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None:
        if self.read_only:
            return  # read-only mode: never a single write request
        started = time.perf_counter()
        try:
            self._write(now_us, outputs)
        except PlantError:
            self._scan_ok = False
            raise
        finally:
            self._end_scan(self._scan_io + time.perf_counter() - started)
            self._scan_io = 0.0

    def _write(self, now_us: int, outputs: Mapping[str, bool], at_stop: bool = False) -> None:
        if not self.connected or self._conn is None:
            raise PlantError(self._down_reason)  # never connect in order to write
        conn = self._conn
        refresh = self.settings.write_refresh_us
        full = self._last_full_us is None or not self._written or \
            now_us - self._last_full_us >= refresh
        for run in self.map.coil_runs:
            values = tuple(bool(outputs[n]) for n in run.names)
            if full or self._written.get(run) != values:
                self._request(conn, write_coils_request(run.start, values), f"write {run}")
                self._written[run] = values
                self._count_write(at_stop)
        for reg in self.map.register_bits:
            values = tuple(bool(outputs[n]) for n, _ in reg.bits)
            if full or self._written.get(reg) != values:
                and_mask, or_mask = reg.masks(outputs)
                self._request(conn, mask_write_request(reg.index, and_mask, or_mask),
                              f"write {reg}")
                self._written[reg] = values
                self._count_write(at_stop)
        if full:
            self._last_full_us = now_us

    def _count_write(self, at_stop: bool) -> None:
        self.stats["writes"] += 1
        if at_stop:  # the safe vector written when the run ends: counted, and said apart
            self.stats["stop_writes"] += 1

    def _end_scan(self, io_s: float) -> None:
        if io_s * 1e6 > self.period_us:
            self.stats["slow_scans"] += 1
        if not (self._scan_ok and self.connected):
            return
        # Every request of the scan got a valid answer: the link works.
        self.io_us.append(io_s * 1e6)  # a round trip figure: scans that did all their I/O
        self._backoff_s = BACKOFF_FIRST_S
        self._outage = False
        self.link.link_ok()

    @property
    def status(self) -> PlantStatus:
        s = self.settings
        description = f"modbus {s.where}" + (" (read-only)" if self.read_only else "")
        details: dict[str, Any] = dict(self.stats)
        details["host"], details["port"], details["unit"] = s.host, s.port, s.unit
        details["read_only"] = self.read_only
        if self.io_us:
            details["last_io_ms"] = round(self.io_us[-1] / 1000, 3)
            details["max_io_ms"] = round(max(self.io_us) / 1000, 3)
        if self.last_exception:
            details["last_exception"] = self.last_exception
        if not self.connected:
            details["retry_in_s"] = round(self.retry_in_s, 2)
        return PlantStatus("modbus", description, self.connected, self.message, details)

    def io_percentiles(self) -> tuple[float, float] | None:
        """(p50, p99) of a scan's Modbus I/O in microseconds, over the recent scans."""
        if not self.io_us:
            return None
        ordered = sorted(self.io_us)
        return (ordered[len(ordered) // 2],
                ordered[min(len(ordered) - 1, int(len(ordered) * 0.99))])

    def state(self) -> PlantState:
        """No physical state: a real plant is only known through its I/O."""
        return ()

    def stop(self, now_us: int, safe: Mapping[str, bool]) -> bool:
        """Leave the device as a stopping PLC does: write the safe vector in full, then close.

        Returns whether the safe vector was written (not in read-only mode, nor when the
        device cannot be reached: then it is up to the device's own communication watchdog).
        """
        written = False
        if self.connected and not self.read_only:
            self._written.clear()
            try:
                self._write(now_us, safe, at_stop=True)
                written = True
            except PlantError:
                pass
        self.close()
        self.message = "stopped: safe outputs written, connection closed" if written else \
            "stopped: connection closed"
        return written

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._conn = None
        self.connected = False
        self.link.close()  # the summaries of what was still going on


def wait_connected(plant: ModbusPlant, timeout_s: float | None,
                   report: Callable[[str], None]) -> bool:
    """Try to connect until it works or `timeout_s` has passed (None: keep trying).

    For the runners, before the first scan: the engine does not start until the plant is
    connected, so nothing is written to a device before it answers.
    """
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while True:
        if plant.connect():
            report(plant.message)
            return True
        wait = plant.retry_in_s
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            wait = min(wait, left)
        report(f"attempt {plant.attempts}: {plant.message}")
        time.sleep(wait)

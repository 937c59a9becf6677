"""What every simulated device offers the simulated plant.

A device has sensor ports (read by the PLC) and actuator ports (written by it), parameters
with defaults, and a list of faults it can suffer. Time is integer microseconds and always
given by the caller: a device never looks at a clock, so a run is exactly repeatable.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from hmi.plant.base import PlantEvent
from hmi.project.device_models import DeviceModel, FaultSpec, ParamSpec


@dataclass
class PendingFault:
    code: str
    at_us: int
    duration_us: int | None = None  # for faults that last a while (interruptions)
    options: dict[str, Any] = field(default_factory=dict)


class SimDevice(ABC):
    """Base of simulated devices; subclasses implement the physics in :meth:`_advance_to`.

    A model names the catalogue entry it implements, ``class Valve(SimDevice, model=VALVE)``
    (hmi.project.device_models): its name, ports, parameters and faults are that entry's, the
    very data the loader checked the project against, so the two cannot drift apart.
    """

    SPEC: ClassVar[DeviceModel]
    MODEL: ClassVar[str]
    DESCRIPTION: ClassVar[str] = ""
    SENSORS: ClassVar[tuple[str, ...]]
    ACTUATORS: ClassVar[tuple[str, ...]]
    PARAMS: ClassVar[Mapping[str, ParamSpec]] = {}
    FAULTS: ClassVar[Mapping[str, FaultSpec]] = {}
    # A model that knows how to undo its faults' effects (see _repaired); the others refuse a
    # repair rather than leave a half-faulty device behind.
    REPAIRABLE: ClassVar[bool] = False

    def __init_subclass__(cls, model: DeviceModel | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if model is not None:
            cls.SPEC = model
            cls.MODEL = model.name
            cls.DESCRIPTION = model.description
            cls.SENSORS = model.sensors
            cls.ACTUATORS = model.actuators
            cls.PARAMS = model.params
            cls.FAULTS = model.faults

    def __init__(self, name: str, params: Mapping[str, Any]):
        self.name = name
        self.params = {key: spec.default for key, spec in self.PARAMS.items()}
        self.params.update(params)
        self.t = 0
        self.orders = dict.fromkeys(self.ACTUATORS, False)
        self.events: list[PlantEvent] = []
        self.pending: list[PendingFault] = []
        self.active_faults: dict[str, int] = {}  # code -> time it became active
        # state_items / counter_items: the last key and the items built for it
        self._state_cache: tuple[Hashable, tuple[tuple[str, Any], ...]] | None = None
        self._counter_cache: tuple[Hashable, tuple[tuple[str, int], ...]] | None = None

    # -- the plant's side --------------------------------------------------------------------
    def inject(self, code: str, at_us: int, duration_us: int | None = None,
               **options: Any) -> None:
        if code not in self.FAULTS:
            raise KeyError(code)
        self.pending.append(PendingFault(code, at_us, duration_us, options))
        self.pending.sort(key=lambda p: p.at_us)

    def write(self, t: int, orders: Mapping[str, bool]) -> None:
        """The PLC writes its actuator ports at time t (after the device reached t)."""
        self.advance(t)
        changed = {port: bool(value) for port, value in orders.items()
                   if self.orders.get(port) != bool(value)}
        if changed:
            self.orders.update(changed)
            self._orders_changed(t, changed)

    def advance(self, t: int) -> None:
        """Bring the physics to time t, activating injected faults exactly on time."""
        if t < self.t:
            return
        while self.pending and self.pending[0].at_us <= t:
            fault = self.pending.pop(0)
            self._advance_to(max(fault.at_us, self.t))
            self.active_faults[fault.code] = fault.at_us
            self._fault_activated(fault)
        self._advance_to(t)

    @abstractmethod
    def sensors(self) -> dict[str, bool]:
        """Sensor port values at the current time (after advance)."""

    def read_sensors(self) -> Mapping[str, bool]:
        """The sensors right after :meth:`advance`, for the plant's read (not to be kept
        nor changed: a model may give the same mapping again)."""
        return self.sensors()

    def sense(self, t: int) -> Mapping[str, bool]:
        """:meth:`advance` to t then :meth:`read_sensors`: the plant's read of a device with
        sensor ports, once per scan (a model may do both at once)."""
        self.advance(t)
        return self.read_sensors()

    @abstractmethod
    def _advance_to(self, t: int) -> None:
        """Integrate the physics from self.t to t (t >= self.t) and set self.t = t."""

    def link(self, devices: Mapping[str, SimDevice]) -> None:  # noqa: B027
        """Hook: resolve "device" parameters to the plant's other devices (all built by then).

        Physical links between devices (a pump pushing through valves into tanks) are not
        ports: the PLC neither reads nor writes them, so the plant wires them here.
        """

    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:  # noqa: B027
        """Hook: react to new orders (record dangerous combinations...)."""

    def _fault_activated(self, fault: PendingFault) -> None:  # noqa: B027
        """Hook: a fault became active at fault.at_us."""

    def repair(self, t: int) -> tuple[str, ...]:
        """The technician's repair at time t, for training: every active and scheduled fault
        is removed and the device works normally again from where it physically is. Returns
        the codes removed."""
        if not self.REPAIRABLE:
            raise NotImplementedError(f"repair is not modelled for {self.MODEL} devices")
        self.advance(t)
        codes = tuple(self.active_faults) + tuple(p.code for p in self.pending)
        self.active_faults.clear()
        self.pending.clear()
        self._repaired()
        return codes

    def _repaired(self) -> None:  # noqa: B027
        """Hook: undo the faults' effects (a jam, an armed fault, a glitch in progress)."""

    @abstractmethod
    def state(self) -> dict[str, Any]:
        """Scalar values describing the physical state, for traces and the UI."""

    def counters(self) -> dict[str, int]:
        """Work achieved (cycles, parts...), used to judge whether the cell kept going."""
        return {}

    # A snapshot holds the plant's state and counters at every scan, and they change at few:
    # a model that says what its state() and counters() are computed from (a few fields, in
    # a tuple) has them rebuilt only when that changes. None: rebuilt at every call.
    def state_key(self) -> Hashable | None:
        """The values state() is computed from (None: no cache)."""
        return None

    def counters_key(self) -> Hashable | None:
        """The values counters() is computed from (None: no cache)."""
        return None

    def state_items(self, prefixed: bool) -> tuple[tuple[str, Any], ...]:
        """state() as (name, value) pairs, names prefixed with the device's when asked; the
        same tuple while state_key() is unchanged."""
        self._state_cache = cache = _refreshed(self._state_cache, self.state_key(), self.name,
                                               self.state, prefixed)
        return cache[1]

    def counter_items(self, prefixed: bool) -> tuple[tuple[str, int], ...]:
        """counters() as state_items() gives state()."""
        self._counter_cache = cache = _refreshed(self._counter_cache, self.counters_key(),
                                                 self.name, self.counters, prefixed)
        return cache[1]

    def record(self, t: int, kind: str, damage: bool, detail: str) -> None:
        self.events.append(PlantEvent(t, self.name, kind, damage, detail))


def _items(name: str, values: Mapping[str, Any], prefixed: bool) -> tuple[tuple[str, Any], ...]:
    if prefixed:
        return tuple((f"{name}.{key}", value) for key, value in values.items())
    return tuple(values.items())


def _refreshed(cache: tuple[Hashable, tuple[tuple[str, Any], ...]] | None, key: Hashable | None,
               name: str, values: Callable[[], Mapping[str, Any]], prefixed: bool
               ) -> tuple[Hashable, tuple[tuple[str, Any], ...]]:
    """`cache` while the device says its values are unchanged (the same `key`), else the items
    of `values()` anew: a snapshot then finds the very tuple it had."""
    if key is not None and cache is not None and cache[0] == key:
        return cache
    return key, _items(name, values(), prefixed)

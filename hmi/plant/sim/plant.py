"""A simulated plant: the project's devices, bound to its variables by their ports.

Inputs that no device drives (a push button, a selector) read as 0 unless the operator sets
them (:meth:`SimPlant.set_input`), which is how training and commissioning sessions press
buttons on a simulated cell.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from hmi.errors import UsageError
from hmi.plant.base import Plant, PlantEvent, PlantState, PlantStatus
from hmi.plant.sim.device import SimDevice
from hmi.plant.sim.models import MODELS
from hmi.project.injection import Injection, parse_injection
from hmi.project.model import Project

__all__ = ["Injection", "SimPlant", "parse_injection"]  # Injection: hmi.project.injection


class _Replaceable:
    """SimPlant.read, which a caller may replace on one plant (``plant.read = f``, and
    monkeypatch's undo: a test's lost link), the replacement noted in the plant's
    ``_read_replaced`` (None: its own read). Why not a look at the plant's ``__dict__`` at
    every scan (SimPlant.read_into must read through a replaced read): reading an object's
    ``__dict__`` makes CPython 3.11 keep its attributes in a dictionary for good, and every
    read and write of them then goes the slow way (some 2,800 instructions a scan, the
    engine's frame reading ``status`` too)."""

    def __init__(self, method: Callable[[SimPlant, int], Mapping[str, bool]]):
        self.method = method

    def __get__(self, plant: SimPlant | None, owner: type | None = None) -> Any:
        if plant is None:  # (on the class: the function, as a method's)
            return self.method
        replaced = plant._read_replaced
        return self.method.__get__(plant) if replaced is None else replaced

    def __set__(self, plant: SimPlant, value: Callable[[int], Mapping[str, bool]]) -> None:
        own = (getattr(value, "__func__", None) is self.method
               and getattr(value, "__self__", None) is plant)  # (its own again: an undo)
        plant._read_replaced = None if own else value

    def __delete__(self, plant: SimPlant) -> None:
        plant._read_replaced = None


class SimPlant(Plant):
    """The project's simulated devices: faults can be injected and repaired, and the inputs
    no device drives set by the operator."""

    kind = "sim"
    can_inject = True
    can_repair = True
    can_set_inputs = True
    # (each plant's own, set when it is built: a plain attribute the engine reads at every
    # scan, not a property; None on the class, not a PlantStatus: CPython 3.11 reads an
    # instance attribute the slow way when the class holds an object of a class of ours
    # under the same name, some 100 instructions a scan)
    status: PlantStatus = None  # type: ignore[assignment]

    def __init__(self, project: Project):
        self._read_replaced: Callable[[int], Mapping[str, bool]] | None = None  # (read)
        self.project = project
        self.input_names = tuple(v.name for v in project.inputs)
        self.output_names = tuple(v.name for v in project.outputs)
        self.devices: list[SimDevice] = []
        self._sensor_bind: list[tuple[SimDevice, tuple[tuple[str, str], ...]]] = []
        self._actuator_bind: list[tuple[SimDevice, tuple[tuple[str, str], ...]]] = []
        driven: set[str] = set()
        for spec in project.plant.devices:
            device = MODELS[spec.model](spec.name, spec.params)
            self.devices.append(device)
            sensors = tuple((port, var) for port, var in spec.ports.items()
                            if port in device.SENSORS)
            actuators = tuple((port, var) for port, var in spec.ports.items()
                              if port in device.ACTUATORS)
            self._sensor_bind.append((device, sensors))
            self._actuator_bind.append((device, actuators))
            driven.update(var for _, var in sensors)
        by_name = {d.name: d for d in self.devices}
        for device in self.devices:  # pipes and shafts between devices (device.link)
            device.link(by_name)
        self.free_inputs: dict[str, bool] = {name: False for name in self.input_names
                                             if name not in driven}
        self._values = dict.fromkeys(self.input_names, False)
        # read_into's plan for the engine's bindings (see _read_plan)
        self._plan: tuple[Any, ...] | None = None
        self._read_at: int | None = None  # the time every device was last brought to
        # the last write_vector's names and values (None: the next one writes, forget_writes)
        self._written_names: tuple[str, ...] | None = None
        self._written_values: tuple[bool, ...] | None = None
        # Several devices: their items last time, and the plant's tuple made of them.
        self._state_parts: tuple[list[PlantState], PlantState] | None = None
        self._counter_parts: tuple[list[tuple[tuple[str, int], ...]],
                                   tuple[tuple[str, int], ...]] | None = None
        self._taken = [0] * len(self.devices)
        self._one = self.devices[0] if len(self.devices) == 1 else None
        # read_into's plan when every device has sensors in slots that follow each other, no
        # input is free and read is the plant's own: (bindings, (device, ports, first, end,
        # last) per device); else None (see _read_plan)
        self._simple: tuple[Any, ...] | None = None
        # whether write_vector may answer for take_events (its own, not replaced; the plan)
        self._says_events = False
        models = ", ".join(f"{d.name} ({d.MODEL})" for d in self.devices) or "no devices"
        # (a plain attribute, not a property: the engine reads it at every scan)
        self.status = PlantStatus("sim", f"simulated: {models}")

    # -- engine side -------------------------------------------------------------------------
    def _read(self, now_us: int) -> Mapping[str, bool]:
        values = self._values
        for device, binding in self._sensor_bind:
            device.advance(now_us)
            sensed = device.sensors()
            for port, var in binding:
                values[var] = sensed[port]
        values.update(self.free_inputs)
        return values

    # (a read set on one plant, a test's lost link, noted in _read_replaced: _Replaceable)
    read = _Replaceable(_read)

    def read_into(self, now_us: int, image: list[Any],
                  bindings: tuple[tuple[str, int], ...]) -> None:
        """:meth:`read` straight into the engine's image (the same values, no mapping).
        A plant that reads otherwise (a test's flaky plant, a subclass or a patched read)
        is read through its read.

        Each device's sensors go in as one vector: the values in its ports' slot order,
        kept while the device gives the very same mapping again (a gliding cell's), and
        stored as a slice when its slots follow each other. This is the plant's part of
        every scan: the plan (:meth:`_read_plan`) leaves it only the devices to read."""
        simple = self._simple
        if simple is not None and simple[0] is bindings and self._read_replaced is None:
            # (each device's slots follow each other, every input is driven: most plants;
            # _read_device written out, this is every scan's read)
            for device, ports, first, end, last in simple[1]:
                sensed = device.sense(now_us)
                if sensed is not last[0]:
                    last[0], last[1] = sensed, _vector(sensed, ports)
                image[first:end] = last[1]
            self._read_at = now_us
            return
        plan = self._plan
        if plan is None or plan[0] is not bindings:
            plan = self._plan = self._read_plan(bindings)
            self._simple = None if plan[2] is None else (bindings, plan[2])
            if self._simple is not None:
                self.read_into(now_us, image, bindings)
                return
        if plan[1] or self._read_replaced is not None:
            super().read_into(now_us, image, bindings)
            return
        for device, ports, slots, first, end, last in plan[3]:
            if ports:
                _read_device(device.sense(now_us), image, ports, slots, first, end, last)
            else:
                device.advance(now_us)
        free = self.free_inputs
        for name, index in plan[4]:
            image[index] = bool(free[name])
        self._read_at = now_us

    def _read_plan(self, bindings: tuple[tuple[str, int], ...]) -> tuple[Any, ...]:
        """read_into's plan for the engine's bindings: whether the plant is read through its
        own read (a subclass's); per device (in the plant's order: one may drive another)
        (device, its sensor ports in slot order, their slots, the first and end slot when
        they follow each other (else None), [the mapping last read, the vector made of it]),
        as (device, ports, first, end, last) when every device has sensors in slots that
        follow each other, no input is free and the plant's read is its own, else None; the
        full ones; the free inputs' (name, slot) pairs.

        It also decides whether write_vector may say that no event is waiting: when
        take_events is the plant's own, as the plant is now (a take_events replaced on the
        instance or in a subclass is asked at every scan; one replaced after the plant's
        first read is asked at the scans with news)."""
        slot = dict(bindings)
        readers = []
        for device, binding in self._sensor_bind:
            pairs = sorted((slot[var], port) for port, var in binding)
            slots = tuple(index for index, _ in pairs)
            contiguous = bool(slots) and slots == tuple(range(slots[0], slots[0] + len(slots)))
            readers.append((device, tuple(port for _, port in pairs), slots,
                            slots[0] if contiguous else None,
                            slots[0] + len(slots) if contiguous else None, [None, ()]))
        free = tuple((name, slot[name]) for name in self.free_inputs)
        own = type(self).read is SimPlant.read
        simple = own and not free and all(reader[3] is not None for reader in readers)
        # (the bound method's function, not a look at the plant's __dict__: _Replaceable)
        taken = self.take_events
        self._says_events = (type(self).take_events is _TAKE_EVENTS
                             and getattr(taken, "__func__", None) is _TAKE_EVENTS
                             and getattr(taken, "__self__", None) is self)
        return (bindings, not own,
                tuple((d, ports, first, end, last)
                      for d, ports, _, first, end, last in readers) if simple else None,
                tuple(readers), free)

    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None:
        self._written_values = None
        for device, binding in self._actuator_bind:
            device.write(now_us, {port: outputs[var] for port, var in binding})

    def forget_writes(self) -> None:
        """The devices' orders were set from outside (a restored closed-loop state): the next
        write_vector writes whatever it is given."""
        self._written_values = None

    def write_vector(self, now_us: int, names: tuple[str, ...],
                     values: tuple[bool, ...]) -> bool:
        """Skips the write when it changes nothing: the same vector as the last write, and
        every device already brought to `now_us` by this scan's read (then each device's
        write would only find its orders unchanged). Whoever sets the devices' orders
        otherwise calls :meth:`forget_writes`.

        True when no device has recorded an event since the last :meth:`take_events` (it
        would give nothing), which the plan (:meth:`_read_plan`) lets it say."""
        if values != self._written_values or now_us != self._read_at \
                or names is not self._written_names:
            self.write(now_us, dict(zip(names, values, strict=True)))
            self._written_names, self._written_values = names, tuple(values)
        one = self._one
        if one is not None:
            return len(one.events) == self._taken[0] and self._says_events
        if self._says_events:
            for device, seen in zip(self.devices, self._taken):  # noqa: B905 - same length
                if len(device.events) > seen:
                    return False
            return True
        return False

    def close(self) -> None:
        pass

    # -- simulation side ---------------------------------------------------------------------
    def set_input(self, name: str, value: bool) -> None:
        if name not in self.free_inputs:
            raise KeyError(name)
        self.free_inputs[name] = bool(value)

    def faults(self) -> list[tuple[str, str, str]]:
        """(device, code, description) of every fault the plant can simulate."""
        return [(d.name, spec.code, spec.description)
                for d in self.devices for spec in d.FAULTS.values()]

    def resolve(self, injection: Injection) -> SimDevice:
        """The device an injection names, or a UsageError saying what exists."""
        candidates = [d for d in self.devices
                      if injection.code in d.FAULTS
                      and (injection.device is None or d.name == injection.device)]
        if len(candidates) == 1:
            return candidates[0]
        if not candidates:
            known = sorted({f"{d.name}.{c}" if len(self.devices) > 1 else c
                            for d in self.devices for c in d.FAULTS})
            raise UsageError(f"unknown fault {injection}; this plant can simulate: "
                             + ", ".join(known))
        names = ", ".join(f"{d.name}.{injection.code}" for d in candidates)
        raise UsageError(f"fault {injection.code} exists on several devices; name one: {names}")

    def inject(self, injection: Injection) -> None:
        device = self.resolve(injection)
        device.inject(injection.code, injection.at_us, injection.duration_us)

    def repair(self, now_us: int, device: str | None = None) -> list[tuple[str, tuple[str, ...]]]:
        """Repair the faulty devices (one, or all of them): (device, codes removed) for each.

        A UsageError names a device that does not exist, or a faulty one whose model cannot
        be repaired (nothing is repaired then: all or nothing)."""
        chosen = [d for d in self.devices if device is None or d.name == device]
        if not chosen:
            raise UsageError(f"no simulated device {device}; this plant has: "
                             + ", ".join(d.name for d in self.devices))
        faulty = [d for d in chosen if d.active_faults or d.pending]
        stuck = [d.name for d in faulty if not d.REPAIRABLE]
        if stuck:
            raise UsageError(f"repair is not modelled for {', '.join(stuck)}: restart the run "
                             "to clear its faults")
        return [(d.name, d.repair(now_us)) for d in faulty]

    def state(self) -> PlantState:
        """Physical state as (name, value) pairs, device-prefixed when there are several;
        the same tuple as long as no device's state changed (SimDevice.state_key)."""
        if len(self.devices) == 1:
            return self.devices[0].state_items(False)
        self._state_parts = last = _joined([d.state_items(True) for d in self.devices],
                                           self._state_parts)
        return last[1]

    def counters(self) -> tuple[tuple[str, int], ...]:
        if len(self.devices) == 1:
            return self.devices[0].counter_items(False)
        self._counter_parts = last = _joined([d.counter_items(True) for d in self.devices],
                                             self._counter_parts)
        return last[1]

    def take_events(self) -> tuple[PlantEvent, ...]:
        """Events recorded since the previous call (once per scan, by the engine, unless
        the scan's write_vector said none waits)."""
        one = self._one
        if one is not None:  # (a plant of one device: one test, no loop)
            if len(one.events) == self._taken[0]:
                return ()  # the common case: nothing new
        else:
            for device, seen in zip(self.devices, self._taken):  # noqa: B905 - same length
                if len(device.events) > seen:
                    break
            else:
                return ()
        new: list[PlantEvent] = []
        for k, device in enumerate(self.devices):
            if len(device.events) > self._taken[k]:
                new.extend(device.events[self._taken[k]:])
                self._taken[k] = len(device.events)
        if len(new) > 1:
            new.sort(key=lambda e: e.time_us)
        return tuple(new)

    def events(self) -> list[PlantEvent]:
        merged = [e for d in self.devices for e in d.events]
        merged.sort(key=lambda e: e.time_us)
        return merged

    def damage(self) -> list[PlantEvent]:
        return [e for e in self.events() if e.damage]


# (the plant's own take_events, whatever replaces it later on the class)
_TAKE_EVENTS = SimPlant.take_events


def _read_device(sensed: Mapping[str, bool], image: list[Any], ports: tuple[str, ...],
                 slots: tuple[int, ...], first: int | None, end: int | None,
                 last: list[Any]) -> None:
    """One device's sensors into the image (SimPlant.read_into): the vector made of the
    mapping the device gave last time while it gives the very same again."""
    if sensed is last[0]:
        values = last[1]
    else:
        values = _vector(sensed, ports)
        last[0], last[1] = sensed, values
    if first is not None:
        image[first:end] = values
    else:
        for index, value in zip(slots, values):  # noqa: B905 - same length
            image[index] = value


def _vector(sensed: Mapping[str, bool], ports: tuple[str, ...]) -> tuple[bool, ...]:
    """A device's sensors as the vector of its ports' values in slot order (a function of
    its own: read_into keeps no closure cell for it)."""
    return tuple([bool(sensed[port]) for port in ports])


def _joined(parts: list[tuple[Any, ...]], last: tuple[list[Any], tuple[Any, ...]] | None
            ) -> tuple[list[Any], tuple[Any, ...]]:
    """The devices' parts as one tuple, and the parts it was made of: `last` again while
    every part is the very object it was (a device whose state did not change returns the
    same tuple), so that a snapshot compares the plant's state by identity."""
    if last is None or any(a is not b for a, b in zip(parts, last[0], strict=True)):
        return parts, tuple(item for part in parts for item in part)
    return last

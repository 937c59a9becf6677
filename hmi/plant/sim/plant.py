"""A simulated plant: the project's devices, bound to its variables by their ports.

Inputs that no device drives (a push button, a selector) read as 0 unless the operator sets
them (:meth:`SimPlant.set_input`), which is how training and commissioning sessions press
buttons on a simulated cell.
"""

from __future__ import annotations

from collections.abc import Mapping

from hmi.errors import UsageError
from hmi.plant.base import Plant, PlantEvent, PlantState, PlantStatus
from hmi.plant.sim.device import SimDevice
from hmi.plant.sim.models import MODELS
from hmi.project.injection import Injection, parse_injection
from hmi.project.model import Project

__all__ = ["Injection", "SimPlant", "parse_injection"]  # Injection: hmi.project.injection


class SimPlant(Plant):
    """The project's simulated devices: faults can be injected and repaired, and the inputs
    no device drives set by the operator."""

    kind = "sim"
    can_inject = True
    can_repair = True
    can_set_inputs = True

    def __init__(self, project: Project):
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
        self.free_inputs = {name: False for name in self.input_names if name not in driven}
        self._values = dict.fromkeys(self.input_names, False)
        self._taken = [0] * len(self.devices)
        models = ", ".join(f"{d.name} ({d.MODEL})" for d in self.devices) or "no devices"
        self._status = PlantStatus("sim", f"simulated: {models}")

    # -- engine side -------------------------------------------------------------------------
    def read(self, now_us: int) -> Mapping[str, bool]:
        values = self._values
        for device, binding in self._sensor_bind:
            device.advance(now_us)
            sensed = device.sensors()
            for port, var in binding:
                values[var] = sensed[port]
        values.update(self.free_inputs)
        return values

    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None:
        for device, binding in self._actuator_bind:
            device.write(now_us, {port: outputs[var] for port, var in binding})

    @property
    def status(self) -> PlantStatus:
        return self._status

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
        """Physical state as (name, value) pairs, device-prefixed when there are several."""
        if len(self.devices) == 1:
            return tuple(self.devices[0].state().items())
        return tuple((f"{d.name}.{key}", value) for d in self.devices
                     for key, value in d.state().items())

    def counters(self) -> tuple[tuple[str, int], ...]:
        if len(self.devices) == 1:
            return tuple(self.devices[0].counters().items())
        return tuple((f"{d.name}.{key}", value) for d in self.devices
                     for key, value in d.counters().items())

    def take_events(self) -> tuple[PlantEvent, ...]:
        """Events recorded since the previous call (once per scan, by the engine)."""
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

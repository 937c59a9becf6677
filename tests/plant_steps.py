"""Driving a simulated device model by hand in the plant tests: hold orders, wait for a
sensor, read the damage. Shared by the palletizer's and the sorting cell's tests, which drive
their models the same way and differ only in the actuators and the sampling step. And the
closed-loop twin of a gliding model (the valve's, the cells'): the same project driving it
and its full-stepping twin, scan for scan."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Protocol

from hmi.engine.scan import Engine
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.model import Project
from hmi.session.session import Session


class Model(Protocol):
    t: int
    events: list

    def write(self, now: int, outputs: dict[str, bool]) -> None: ...
    def advance(self, until: int) -> None: ...
    def sensors(self) -> dict[str, bool]: ...


def order(model: Model, actuators: Iterable[str], orders: dict[str, int]) -> None:
    """Write these orders now, every other actuator off."""
    model.write(model.t, {name: bool(orders.get(name)) for name in actuators})


def hold_until(model: Model, actuators: Iterable[str], sensor: str, value: bool, limit: int,
               step: int, orders: dict[str, int]) -> int:
    """Hold the orders until the sensor reads `value`; fails past `limit` µs. The time it did."""
    order(model, actuators, orders)
    end = model.t + limit
    while model.sensors()[sensor] != value:
        assert model.t < end, f"{sensor} never became {value}"
        model.advance(model.t + step)
    return model.t


def damage(model: Model) -> list[str]:
    """The kinds of the damage events the model has recorded so far."""
    return [e.kind for e in model.events if e.damage]


def run_twins(project: Project, full: Mapping[type, type], injections: Iterable[Injection],
              scans: int) -> tuple[SimPlant, SimPlant]:
    """The project's law drives its simulated plant twice, the same faults injected in both:
    as it is (its models glide), and with each device of a class in `full` turned into that
    class (its twin that steps in full). Every scan's inputs, outputs, plant state, counters
    and events must be the same; the two plants are returned for their physics."""
    injections = tuple(injections)
    sessions = []
    for gliding in (True, False):
        plant = SimPlant(project)
        if not gliding:
            for device in plant.devices:
                device.__class__ = full.get(type(device), type(device))
        for injection in injections:
            plant.inject(injection)
        sessions.append(Session(Engine(project, plant)))
    a, b = sessions
    for _ in range(scans):
        snap_a, snap_b = a.scan_once().snapshot, b.scan_once().snapshot
        assert (snap_a.values, snap_a.plant_state, snap_a.plant_counters,
                snap_a.plant_events) == (snap_b.values, snap_b.plant_state,
                                         snap_b.plant_counters, snap_b.plant_events)
    return a.engine.plant, b.engine.plant

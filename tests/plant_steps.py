"""Driving a simulated device model by hand in the plant tests: hold orders, wait for a
sensor, read the damage. Shared by the palletizer's and the sorting cell's tests, which drive
their models the same way and differ only in the actuators and the sampling step."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol


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

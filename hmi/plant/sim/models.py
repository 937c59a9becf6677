"""The catalogue of simulated device models a project's `plant: kind: sim` can name.

A name -> "module:class" registry: the loader checks a project's devices against the names
and their parameters, ports and faults, and only the models a project names are imported
(a project of one valve does not import the palletizer). :data:`MODELS` reads like the dict
of classes it used to be: ``MODELS["valve"]`` imports the valve model on first use.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from hmi.plant.sim.device import SimDevice

# Model name (as written in a project) -> "module:class".
REGISTRY: dict[str, str] = {
    "valve": "hmi.plant.sim.valve:Valve",
    "conveyor": "hmi.plant.sim.conveyor:Conveyor",
    "robot": "hmi.plant.sim.robot:Robot",
    "sorting_cell": "hmi.plant.sim.sorter:SortingCell",
    "palletizer": "hmi.plant.sim.palletizer:Palletizer",
    "pump": "hmi.plant.sim.pump:Pump",
    "tank": "hmi.plant.sim.tank:Tank",
}


class _Models(Mapping[str, "type[SimDevice]"]):
    """The registry's classes, each imported the first time it is asked for."""

    def __init__(self, registry: Mapping[str, str]):
        self.registry = registry
        self.loaded: dict[str, type[SimDevice]] = {}

    def __getitem__(self, name: str) -> type[SimDevice]:
        cls = self.loaded.get(name)
        if cls is None:
            module, _, attr = self.registry[name].partition(":")
            cls = self.loaded[name] = getattr(importlib.import_module(module), attr)
            if name != cls.MODEL:
                raise LookupError(f"{self.registry[name]} is model {cls.MODEL!r}, not {name!r}")
        return cls

    def __iter__(self) -> Iterator[str]:
        return iter(self.registry)

    def __len__(self) -> int:
        return len(self.registry)

    def __contains__(self, name: object) -> bool:
        return name in self.registry


MODELS: Mapping[str, type[SimDevice]] = _Models(REGISTRY)


def model(name: str) -> type[SimDevice] | None:
    return MODELS.get(name)

"""Simulated plants: the devices a project's `plant: kind: sim` names, with fault injection.

    plant.py    SimPlant, the project's devices bound to its variables
    models.py   the device models by name (imported on use)
    device.py   what every device offers; valve.py, conveyor.py, ... the models

Importing this package imports no device model. ``from hmi.plant.sim.plant import SimPlant`` (and
``Injection``, ``parse_injection``) still works, resolved on use: an alias for the code that
still imports it by that name.
"""

from __future__ import annotations

from typing import Any

_MOVED = {"SimPlant": "hmi.plant.sim.plant", "Injection": "hmi.project.injection",
          "parse_injection": "hmi.project.injection"}


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        import importlib
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

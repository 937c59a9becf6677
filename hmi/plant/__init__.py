"""Plants: the contract (base.py), simulated plants (sim/), real ones over Modbus (modbus/).

The modules moved into sim/ and modbus/ by issue 14 keep their old names for one phase
(``import hmi.plant.modbus_client`` gives hmi.plant.modbus.client), so branches written
against the old layout still run; the aliases are removed in phase B.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from types import ModuleType

MOVED = {f"hmi.plant.{old}": f"hmi.plant.{new}" for old, new in {
    "modbus_client": "modbus.client", "modbus_map": "modbus.address_map",
    "modbus_server": "modbus.server", "link_log": "modbus.link_log",
    "server_process": "modbus.server_process",
    **{name: f"sim.{name}" for name in (
        "device", "models", "valve", "conveyor", "robot", "pump", "tank", "sorter",
        "palletizer", "boxes", "cell", "tasks", "track", "travel")},
}.items()}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports a moved module under its old name: the very same module object."""

    def __init__(self) -> None:
        self.specs: dict[str, importlib.machinery.ModuleSpec | None] = {}

    def find_spec(self, fullname: str, path=None, target=None):
        if fullname in MOVED:
            return importlib.machinery.ModuleSpec(fullname, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(MOVED[spec.name])
        self.specs[module.__name__] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self.specs[module.__name__]  # its own spec, not the alias's



if not any(isinstance(finder, _Alias) for finder in sys.meta_path):
    sys.meta_path.append(_Alias())

"""Old module names of issue 14's moves (phase A), kept importable for one phase.

Branches written against the old layout keep running while they merge: ``import
hmi.plant.modbus.client`` gives the module now at hmi.plant.modbus.client, the very same
module object (so a monkeypatch through either name patches both). New code imports the new
names; phase B removes this module.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
from types import ModuleType

MOVED: dict[str, str] = {
    "hmi.engine.runner": "hmi.session.session",
    "hmi.engine.live": "hmi.session.live",
    "hmi.explain.recorder": "hmi.session.journal_recorder",
    "hmi.logic.control": "hmi.engine.control",
    "hmi.logic.grafcet": "hmi.engine.grafcet",
    "hmi.explain.texts": "hmi.project.texts",
    "hmi.plant.injection": "hmi.project.injection",
    **{f"hmi.plant.{old}": f"hmi.plant.{new}" for old, new in {
        "modbus_client": "modbus.client", "modbus_map": "modbus.address_map",
        "modbus_server": "modbus.server", "link_log": "modbus.link_log",
        "server_process": "modbus.server_process", "modbus_frame": "modbus.frame",
        "modbus_link": "modbus.link", "modbus_tcp_server": "modbus.tcp_server",
        **{name: f"sim.{name}" for name in (
            "device", "models", "valve", "conveyor", "robot", "pump", "tank", "sorter",
            "palletizer", "boxes", "cell", "tasks", "track", "travel")},
    }.items()},
}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports a moved module under its old name: the very same module object."""

    def __init__(self) -> None:
        self.specs: dict[str, importlib.machinery.ModuleSpec | None] = {}

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        if fullname in MOVED:
            return importlib.machinery.ModuleSpec(fullname, self)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(MOVED[spec.name])
        self.specs[module.__name__] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        module.__spec__ = self.specs[module.__name__]  # its own spec, not the alias's


def install() -> None:
    if not any(isinstance(finder, _Alias) for finder in sys.meta_path):
        sys.meta_path.append(_Alias())

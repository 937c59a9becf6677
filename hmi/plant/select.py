"""Which plant a command runs against: the project's, or the one `--plant` names.

    --plant sim                       the project's simulated devices
    --plant modbus                    Modbus TCP with the project's host, port and unit
    --plant modbus://HOST:PORT[/UNIT] Modbus TCP there (overrides the project's settings)

Bad values are usage errors (exit 2); a project that lacks an address for some input or output
cannot run on Modbus, and that is reported at each variable's file:line:column.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from hmi.errors import ProjectError, UsageError
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.model import Project

if TYPE_CHECKING:
    from hmi.plant.modbus.client import ModbusPlant, ModbusSettings

# The Modbus client (and pymodbus under it) is imported only for a Modbus plant: a simulated
# one, the HMI's usual start, does not pay for it (the first frame).


def plant_kind(project: Project, choice: str | None) -> str:
    if choice is None:
        return project.plant.kind
    if choice in ("sim", "modbus") or choice.startswith("modbus://"):
        return "sim" if choice == "sim" else "modbus"
    from hmi.plant.modbus.client import URL_HINT
    raise UsageError(f"--plant {choice!r}: expected sim, modbus or {URL_HINT}")


def modbus_settings(project: Project, choice: str | None) -> ModbusSettings:
    from hmi.plant.modbus.client import ModbusSettings, parse_plant_url
    base = ModbusSettings.from_spec(project.plant)
    if choice and choice.startswith("modbus://"):
        return parse_plant_url(choice, base)
    return base


def open_plant(project: Project, choice: str | None = None, read_only: bool = False,
               injections: Sequence[Injection] = (), period_us: int | None = None
               ) -> SimPlant | ModbusPlant:
    """The plant to run against; nothing is connected yet (see modbus_client.wait_connected)."""
    kind = plant_kind(project, choice)
    if kind == "sim":
        if read_only:
            from hmi.plant.modbus.client import URL_HINT
            raise UsageError("--read-only observes a real device: it needs a Modbus plant "
                             f"(--plant {URL_HINT})")
        if not project.plant.devices:
            raise UsageError("this project has no simulated devices to run on (--plant sim)")
        plant = SimPlant(project)
        for injection in injections:
            plant.resolve(injection)
        for injection in injections:
            plant.inject(injection)
        return plant
    if injections:
        raise UsageError("--inject needs the simulated plant; to inject faults into a plant "
                         "served over Modbus, give them to 'plchmi serve-plant'")
    from hmi.plant.modbus.address_map import address_diagnostics
    from hmi.plant.modbus.client import ModbusPlant
    settings = modbus_settings(project, choice)
    errors = address_diagnostics(project, "a Modbus plant needs one for every input and "
                                 "output")
    if errors:
        raise ProjectError(errors)
    return ModbusPlant(project, settings, read_only=read_only, period_us=period_us)

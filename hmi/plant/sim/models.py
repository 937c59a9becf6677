"""The catalogue of simulated device models a project's `plant: kind: sim` can name."""

from __future__ import annotations

from hmi.plant.conveyor import Conveyor
from hmi.plant.device import SimDevice
from hmi.plant.palletizer import Palletizer
from hmi.plant.pump import Pump
from hmi.plant.robot import Robot
from hmi.plant.sorter import SortingCell
from hmi.plant.tank import Tank
from hmi.plant.valve import Valve

MODELS: dict[str, type[SimDevice]] = {
    Valve.MODEL: Valve,
    Conveyor.MODEL: Conveyor,
    Robot.MODEL: Robot,
    SortingCell.MODEL: SortingCell,
    Palletizer.MODEL: Palletizer,
    Pump.MODEL: Pump,
    Tank.MODEL: Tank,
}


def model(name: str) -> type[SimDevice] | None:
    return MODELS.get(name)

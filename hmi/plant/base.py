"""The plant as the engine sees it: something that gives inputs and takes outputs.

The engine calls :meth:`Plant.read` at the start of a scan and :meth:`Plant.write` at its end,
always passing the scan's time. A simulated plant integrates its physics to that time; a real
plant (Modbus) does I/O and reports its connection state in :attr:`Plant.status`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from hmi.plant.device import PlantEvent


@dataclass(frozen=True)
class PlantStatus:
    kind: str  # "sim" or "modbus"
    description: str  # "simulated valve", "modbus 127.0.0.1:5020 unit 1"
    connected: bool = True
    message: str = ""  # the last problem, in plain words
    details: dict[str, Any] = field(default_factory=dict)


class PlantError(Exception):
    """The plant could not be read or written this scan.

    `lost` is True when the link itself is gone (not connected, closed, no answer) and False
    when the device answered but refused (a Modbus exception response): the operator is told
    one or the other. The message is stable for a given cause, so that the engine's latch,
    which keeps one reason per distinct message, does not grow while the cause lasts.
    """

    def __init__(self, message: str, lost: bool = True):
        super().__init__(message)
        self.lost = lost


class Plant(Protocol):
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def read(self, now_us: int) -> Mapping[str, bool]: ...

    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None: ...

    @property
    def status(self) -> PlantStatus: ...

    def state(self) -> dict[str, Any]:
        """Physical state for traces (simulated plants); empty for real plants."""
        ...

    def events(self) -> list[PlantEvent]: ...

    def close(self) -> None: ...

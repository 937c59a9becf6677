"""The plant as the engine sees it: the full contract, and what each kind of plant can do.

The engine calls :meth:`Plant.read` at the start of a scan and :meth:`Plant.write` at its end,
always passing the scan's time. A simulated plant integrates its physics to that time; a real
plant (Modbus) does I/O and reports its connection state in :attr:`Plant.status`.

Everything else a caller may ask of a plant is declared here too, with a default that says
"this plant has none", so nobody probes a plant with ``getattr``: what a plant *can* do is a
declared capability (``can_inject``, ``can_repair``, ``can_set_inputs``, ``is_real``), and
asking a plant for something it cannot do raises :class:`NotSupported`. The engine checks the
capability first and refuses the operator's command in plain words.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from hmi.plant.modbus.link_log import LinkLog
    from hmi.project.injection import Injection

# The physical state of a plant for traces and the UI: (name, value) pairs, in a stable order
# ("angle", 42.5), ("V1.position", 0.3)... Empty for a real plant, known only through its I/O.
PlantState = tuple[tuple[str, Any], ...]
# Counters of work done ("boxes sorted"...), same shape.
PlantCounters = tuple[tuple[str, int], ...]


@dataclass(frozen=True)
class PlantEvent:
    """Something objective that happened in the plant; `damage` marks a damaging situation."""

    time_us: int
    device: str
    kind: str
    damage: bool
    detail: str


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


class NotSupported(Exception):
    """Asked of a plant that does not declare the capability (a bug in the caller: check
    the capability first)."""


class Plant(ABC):
    """What every plant is and offers. Subclasses declare their capabilities as class
    attributes and override the methods those capabilities name."""

    kind: ClassVar[str]  # "sim", "modbus": what PlantStatus.kind says
    is_real: ClassVar[bool] = False  # a physical device: outputs move real machinery
    can_inject: ClassVar[bool] = False  # simulated faults (inject, faults)
    can_repair: ClassVar[bool] = False  # simulated repairs
    can_set_inputs: ClassVar[bool] = False  # the operator sets the inputs no device drives

    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    # Observing a real device: inputs and outputs are read, nothing is ever written.
    read_only: bool = False
    # Inputs no device drives (push buttons), that the operator may set (can_set_inputs).
    free_inputs: Mapping[str, bool] = MappingProxyType({})
    # A real plant's link events (connections, retries, refusals) for the journal.
    link: LinkLog | None = None

    # -- every scan ----------------------------------------------------------------------------
    @abstractmethod
    def read(self, now_us: int) -> Mapping[str, bool]:
        """Every input's value at `now_us` (and every output's, when read_only); raises
        PlantError when it cannot."""

    @abstractmethod
    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None:
        """Write every output; raises PlantError when it cannot."""

    def read_into(self, now_us: int, image: list[Any],
                  bindings: tuple[tuple[str, int], ...]) -> None:
        """:meth:`read`, each input's value stored at its slot of the engine's image
        (`bindings`: (input, slot) pairs, the same tuple at every scan). A simulated plant
        does it without building the mapping."""
        values = self.read(now_us)
        for name, slot in bindings:
            image[slot] = bool(values[name])

    def write_vector(self, now_us: int, names: tuple[str, ...],
                     values: tuple[bool, ...]) -> bool:
        """:meth:`write` given the outputs as a vector in `names`' order (the engine's).
        Returns True when the plant knows that :meth:`take_events` would give nothing now
        (the engine then does not ask it), False when it does not say (a simulated plant
        says, and skips a write that changes nothing)."""
        self.write(now_us, dict(zip(names, values, strict=True)))
        return False

    @property
    @abstractmethod
    def status(self) -> PlantStatus: ...

    def state(self) -> PlantState:
        """Physical state for traces and the UI; empty for a real plant."""
        return ()

    def counters(self) -> PlantCounters:
        return ()

    def take_events(self) -> tuple[PlantEvent, ...]:
        """Events recorded since the previous call (the engine calls it once per scan,
        unless the scan's write_vector said none waits)."""
        return ()

    def events(self) -> list[PlantEvent]:
        """Every event recorded so far."""
        return []

    # -- simulation (capabilities) ------------------------------------------------------------
    def faults(self) -> list[tuple[str, str, str]]:
        """(device, code, description) of every fault the plant can simulate."""
        return []

    def inject(self, injection: Injection) -> None:
        raise NotSupported(f"{self.kind} plant: no fault injection")

    def repair(self, now_us: int, device: str | None = None
               ) -> list[tuple[str, tuple[str, ...]]]:
        raise NotSupported(f"{self.kind} plant: no repair")

    def set_input(self, name: str, value: bool) -> None:
        raise NotSupported(f"{self.kind} plant: inputs come from the plant")

    # -- end of a run ----------------------------------------------------------------------------
    def stop(self, now_us: int, safe: Mapping[str, bool]) -> bool:
        """Leave the plant as a stopping PLC does and close it; True when the safe vector was
        written (a simulated plant simply stops)."""
        self.close()
        return False

    @abstractmethod
    def close(self) -> None:
        """Release what the plant holds (a connection); reading afterwards is an error."""

"""One frame of the display: a scan plus the few things around it that the UI shows.

The app builds a frame at most ~20 times a second and hands it down to every panel; a panel
only reads its frame, never the engine, so the whole screen shows one consistent scan.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from hmi.engine.snapshot import Snapshot
from hmi.project.injection import Injection
from hmi.session.recorder import ConstraintStats
from hmi.session.view import CellView
from hmi.ui.containment import UIFault
from hmi.wire.messages import ControlInfo

if TYPE_CHECKING:  # the HMI without --opcua never imports anything of OPC UA
    from hmi.opcua.status import ServingStatus
    from hmi.wire.messages import ServiceStatus


@dataclass(frozen=True)
class InjectedFault:
    """A fault the operator scheduled in the simulated plant, as the UI remembers it."""

    injection: Injection
    description: str


@dataclass(frozen=True, eq=False)
class Frame:
    cell: CellView  # the scan shown: the engine's snapshot, its explanations and alarms
    run: str  # "running", "paused" or "stepping"
    speed: float | None  # 1.0 real time, 10.0, None as fast as possible
    live: bool  # scans paced by the wall clock (False: a test or a screenshot drives them)
    project: str
    show_measured: bool = True  # False hides wall-clock figures (snapshot tests)
    overruns: int = 0  # scans that fell more than a period behind (live only)
    changed: Mapping[str, str] = field(default_factory=dict)  # output -> why it differs
    injected: tuple[InjectedFault, ...] = ()
    free_inputs: tuple[str, ...] = ()  # inputs no simulated device drives: push buttons
    damage_count: int = 0  # damaging plant events seen since the app started
    # The mode the operator last commanded, accepted by the engine but not yet in a snapshot
    # (paused: no scan has run since). Manual request keys follow it, so that an operator
    # who paused, then entered manual mode, can prepare requests before stepping.
    mode_commanded: str | None = None
    constraints: Mapping[str, ConstraintStats] = field(default_factory=dict)  # history
    ui_fault: UIFault | None = None  # the latest UI error contained (hmi.ui.containment)
    ui_faults: int = 0  # how many UI errors were contained this session
    serving: ServingStatus | None = None  # the cell's OPC UA server (--opcua), if any
    gateway: ServiceStatus | None = None  # the runtime's OPC UA gateway, if it has one
    control: ControlInfo | None = None  # who is in control (None: no runtime, one screen)
    me: str | None = None  # this screen's id at the runtime
    lost: str | None = None  # why the runtime is gone: nothing shown is live
    silent_s: float = 0.0  # since the runtime last said anything
    # the engineering view: the panels show the model's names (steps, states, labels,
    # flags, constraints, timers, bounds) beside the operator's words
    engineering: bool = False

    @property
    def snapshot(self) -> Snapshot:
        """The engine's snapshot of the scan shown."""
        return self.cell.snapshot

    @property
    def simulated(self) -> bool:
        return self.snapshot.plant.kind == "sim"

    @property
    def manual(self) -> bool:
        """Manual mode in effect (the last scan ran in manual mode)."""
        return self.snapshot.mode == "manual"

    @property
    def manual_keys(self) -> bool:
        """Whether manual requests make sense now: in effect, or commanded and accepted."""
        return (self.mode_commanded or self.snapshot.mode) == "manual"

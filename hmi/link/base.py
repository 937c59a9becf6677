"""What a screen knows of a running cell, and the one door it sends commands through.

A screen (the Textual HMI, the OPC UA gateway) never reaches into the engine: it holds a
:class:`CellLink` — the cell's static facts (:class:`CellFacts`: layout, control variant,
what the plant can do, the safe vector), the latest :class:`View` (one scan's snapshot with
the history as of that same scan and the run state), the per-scan history between views
(:class:`History`: edges for the chronogram, the plant's events) and :meth:`CellLink.command`.

Two links implement it: the in-process one (hmi.link.local: the runtime's session in this
process, for the pilot tests, the screenshots and the single-process bench) and the client of
a runtime process (hmi.link.client, over a local socket). Who sends is said once, when the
link is made (:class:`Identity`), and carried into every command and the journal (`by`).
"""

from __future__ import annotations

import getpass
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from hmi.engine.commands import Command, CommandResult
from hmi.engine.layout import Layout
from hmi.engine.snapshot import Snapshot
from hmi.explain.reset import ResetLine
from hmi.plant.base import PlantEvent
from hmi.project.model import Project
from hmi.session.recorder import ConstraintStats, Signal, Trace

DOORS = ("terminal", "browser", "opcua", "cli")
ROLES = ("viewer", "operator", "engineer")


@dataclass(frozen=True)
class Identity:
    """Who is behind a link: the journal's `by` and the control shown to every screen.

    `door` is how they came in (the local terminal, a browser, the OPC UA gateway, a
    command); `session` tells two screens of the same user apart."""

    user: str
    role: str = "operator"  # viewer, operator, engineer
    door: str = "terminal"
    session: str = ""

    @property
    def by(self) -> str:
        """As the journal writes it: ``terminal:alice``, ``opcua:bob``."""
        return f"{self.door}:{self.user}"

    @property
    def may_command(self) -> bool:
        return self.role != "viewer"


def local_operator(role: str = "operator", door: str = "terminal") -> Identity:
    """The operator at this terminal: the login name, a fresh session id."""
    try:
        user = getpass.getuser()
    except Exception:  # no login name (a container without a passwd entry)
        user = f"uid{os.getuid()}"
    return Identity(user, role, door, os.urandom(4).hex())


@dataclass(frozen=True)
class PlantFacts:
    """What the plant is and can do; fixed for a run."""

    kind: str  # sim, modbus
    description: str
    is_real: bool
    can_inject: bool
    can_repair: bool
    can_set_inputs: bool
    free_inputs: tuple[str, ...]  # inputs no simulated device drives: push buttons
    faults: tuple[tuple[str, str, str], ...]  # (device, code, description) it can simulate


@dataclass(frozen=True)
class CellFacts:
    """What does not change while a cell runs: read once, when the link is made."""

    project: str  # the project's name
    control: str  # the control variant running
    layout: Layout
    safe_vector: tuple[bool, ...]
    devices: Mapping[str, tuple[str, ...]]  # device -> its outputs
    plant: PlantFacts
    period_us: int
    # Where the cell's history is kept (hmi.history.target.parse_target reads it back: a
    # SQLite file's absolute path or a postgresql:// URL; "" if none): the trend screens
    # open it read-only. And the wall time of the run's time 0 (Session.wall_us), which
    # places a snapshot on the history's time axis.
    history: str = ""
    epoch_us: int | None = None

    def safe_text(self) -> str:
        return ", ".join(f"{n}={int(v)}" for n, v in
                         zip(self.layout.outputs, self.safe_vector, strict=True))


@dataclass(frozen=True)
class RunInfo:
    """The run state: running, paused or stepping, and at what speed."""

    label: str  # running, paused, stepping
    running: bool
    speed: float | None  # 1.0 real time, 10.0, None as fast as possible


@dataclass(frozen=True)
class View:
    """One scan as a screen shows it: the snapshot, the history as of that same scan (a
    constraint violated in the snapshot is violated in the history too), the run state."""

    snapshot: Snapshot
    constraints: Mapping[str, ConstraintStats]
    damage_count: int
    run: RunInfo
    overruns: int = 0  # scans that fell more than a period behind (live only)


@dataclass(frozen=True)
class ResetGuard:
    """A fault reset confirmed on a dialog: carried out only if the reset still does what the
    dialog showed (hmi.explain.reset.changes), checked where the scans run, with no scan
    between the check and the reset."""

    shown: tuple[ResetLine, ...]
    seen_scan: int


@dataclass(frozen=True)
class Answer:
    """A command's answer; `declined`: a guarded command not carried out because what it was
    confirmed on had changed (the screen asks again)."""

    result: CommandResult
    declined: bool = False


class History(Protocol):
    """Every scan's Boolean edges and the plant's events, kept between views (a one-scan
    pulse between two frames is never lost): what the chronogram and the SIMULATION strip
    draw."""

    signals: tuple[Signal, ...]
    change_count: int

    def trace(self, name: str, start_us: int, end_us: int) -> Trace: ...

    def recent_events(self, count: int = 20) -> list[PlantEvent]: ...


class CellLink(Protocol):
    """A running cell as a screen sees it (module docstring)."""

    project: Project
    facts: CellFacts
    identity: Identity
    history: History

    def view(self) -> View | None:
        """The latest scan (None before the first)."""

    @property
    def last(self) -> Snapshot | None:
        """The newest snapshot known here (a dialog's contents; a frame shows view())."""

    def command(self, command: Command, guard: ResetGuard | None = None) -> Answer:
        """Send one operator command and wait for its answer."""

    # -- who runs the scans --------------------------------------------------------------
    def start(self) -> None:
        """The screen is up: scans (in this process) or frames (from a runtime) begin."""

    def stop(self) -> None:
        """The screen is going: stop what start() began."""

    @property
    def error(self) -> BaseException | None:
        """Why the scans stopped on their own (a dead scan thread), if they did."""

    def advance(self, duration_us: int) -> int:
        """Virtual time: run the scans `duration_us` holds (none while paused)."""

    def advance_until(self, predicate: Callable[[Snapshot], bool], limit_us: int) -> bool:
        """Virtual time: run scans until `predicate` holds, at most `limit_us`."""

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

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from hmi.engine.commands import Command, CommandResult
from hmi.plant.base import PlantEvent
from hmi.project.model import Project
from hmi.session.recorder import ConstraintStats, Signal, Trace
from hmi.session.view import CellView
from hmi.wire.messages import (
    CellFacts,
    ControlInfo,
    Identity,
    PlantFacts,
    ResetGuard,
    RunInfo,
    ServiceStatus,
    local_operator,
)

__all__ = ["Answer", "CellFacts", "CellLink", "ControlInfo", "History", "Identity",
           "PlantFacts", "ResetGuard", "RunInfo", "ServiceStatus", "View", "local_operator"]


@dataclass(frozen=True)
class View:
    """One scan as a screen shows it: the scan (the engine's snapshot, explained), the
    history as of that same scan (a constraint violated in the snapshot is violated in the
    history too), the run state, who is in control."""

    cell: CellView
    constraints: Mapping[str, ConstraintStats]
    damage_count: int
    run: RunInfo
    overruns: int = 0  # scans that fell more than a period behind (live only)
    control: ControlInfo | None = None  # None: a session in this process, no screens
    services: tuple[ServiceStatus, ...] = ()


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
    scans_here: bool  # the scans run in this process: they end with this screen
    # the runtime asks a reason (and for the riskiest, the password) before the commands
    # that need one (hmi.access.roles): people sign in to it
    accountable: bool
    idle_lock_us: int  # the screen locks untouched after this (0: never), warning before
    idle_warning_us: int

    def view(self) -> View | None:
        """The latest scan (None before the first)."""

    @property
    def history(self) -> History:
        """The per-scan history between views (read-only here: each link keeps its own)."""

    @property
    def last(self) -> CellView | None:
        """The newest scan known here (a dialog's contents; a frame shows view())."""

    def command(self, command: Command, guard: ResetGuard | None = None, *,
                reason: str = "", password: str = "") -> Answer:
        """Send one operator command and wait for its answer; `reason` and `password`
        where the command needs them (see `accountable`)."""

    # -- control (several screens) -------------------------------------------------------
    @property
    def client(self) -> str | None:
        """This screen's id at the runtime (None: no runtime, a session in this process)."""

    @property
    def lost(self) -> str | None:
        """Why the runtime is gone (None while it answers): nothing shown is live then."""

    def silent_s(self) -> float:
        """How long since the runtime last said anything (a tick comes every second)."""

    def lock(self) -> CommandResult:
        """The screen was left untouched (idle_lock_us) and is covered: the runtime refuses
        its commands until `unlock` with the person's password."""

    def unlock(self, password: str) -> CommandResult:
        """The person is back: their password, checked by the runtime."""

    def request_control(self) -> CommandResult:
        """Ask for control (granted at once if nobody holds it, else the holder is asked)."""

    def take_control(self) -> CommandResult:
        """Take control over without the holder's consent (confirmed by the operator)."""

    def release_control(self) -> CommandResult:
        """Nobody in control after this."""

    def hand_over(self, to: str) -> CommandResult:
        """Hand control to screen `to` ("": keep it, refusing a request)."""

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

    def advance_until(self, predicate: Callable[[CellView], bool], limit_us: int) -> bool:
        """Virtual time: run scans until `predicate` holds, at most `limit_us`."""

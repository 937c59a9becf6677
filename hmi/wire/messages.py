"""The messages between a cell's runtime and its screens: plain frozen dataclasses.

A screen (the HMI, the OPC UA gateway) opens with :class:`Hello` — the protocol's version and
schema, the project's fingerprint, who is there (:class:`Identity`) and whether it wants
control — and the runtime answers :class:`Welcome` (the cell's static facts, the screen's
id) or :class:`Refused` (why, in plain words). From then on the runtime pushes a
:class:`Frame` at most 20 times a second (latest wins: a slow screen skips frames and never
slows the scan), and a :class:`Tick` when nothing changed for a second; a screen sends
commands with ids (:class:`Send`, the control requests, :class:`Advance` in virtual time,
:class:`Query`), each answered by a :class:`Reply` or a :class:`Stats` with the same id.

What a frame carries between two frames is kept by the runtime at every scan and sent as a
:class:`HistoryDelta` since the last frame that screen was sent: every Boolean edge, the
plant's events, each scan's alarm transitions — a one-scan pulse is never lost at 20 Hz.

Encoding: :mod:`hmi.wire.codec` (JSON, type-directed), :data:`CODEC_OVERRIDES` naming the
wire type of the fields the classes type loosely. :data:`PROTOCOL` changes when the meaning
of a message changes; the schema digest changes with any field (:func:`schema_digest`).
"""

from __future__ import annotations

import getpass
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hmi.access.audit import SignInRefusal
from hmi.engine.commands import Command, CommandResult
from hmi.engine.layout import Layout
from hmi.engine.monitors import MonitorState
from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import Alarm, AlarmEvent
from hmi.explain.model import Policy
from hmi.explain.reset import ResetLine
from hmi.plant.base import PlantEvent
from hmi.project.model import Grafcet
from hmi.session.recorder import ConstraintStats
from hmi.session.view import CellView
from hmi.wire.codec import LOCAL, Codec

PROTOCOL = 1
DOORS = ("terminal", "browser", "opcua", "cli")
ROLES = ("viewer", "operator", "engineer")


# -- who is there ------------------------------------------------------------------------

@dataclass(frozen=True)
class Identity:
    """Who is behind a screen: the journal's `by` and the control every screen shows.

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

    def __str__(self) -> str:
        return f"{self.user} ({self.role}, {self.door})"


def local_operator(role: str = "operator", door: str = "terminal") -> Identity:
    """The operator at this terminal: the login name, a fresh session id."""
    try:
        user = getpass.getuser()
    except Exception:  # no login name (a container without a passwd entry)
        user = f"uid{os.getuid()}"
    return Identity(user, role, door, os.urandom(4).hex())


@dataclass(frozen=True)
class ClientInfo:
    """A screen attached to the runtime, as every screen sees it."""

    id: str  # the runtime's name for it (c1, c2...)
    identity: Identity
    since_us: int  # the cell's time when it attached

    def __str__(self) -> str:
        who = self.identity
        return f"{who.user} ({who.role}, {who.door}, {self.id})"


@dataclass(frozen=True)
class ControlInfo:
    """Who is in control, who asks for it, and who is attached."""

    holder: ClientInfo | None
    asked_by: ClientInfo | None  # a screen asking the holder to hand control over
    clients: tuple[ClientInfo, ...]


# -- what does not change ------------------------------------------------------------------

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
    """What does not change while a cell runs: read once, when a screen attaches."""

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
class RuntimeInfo:
    """The runtime process a screen attached to."""

    pid: int
    started: str  # wall time, ISO 8601
    virtual: bool  # its scans run in virtual time, when a screen in control says
    realtime: str  # the scan thread's scheduling: "SCHED_FIFO 10", or why not


# -- what changes --------------------------------------------------------------------------

@dataclass(frozen=True)
class RunInfo:
    """The run state: running, paused or stepping, and at what speed."""

    label: str  # running, paused, stepping
    running: bool
    speed: float | None  # 1.0 real time, 10.0, None as fast as possible


@dataclass(frozen=True)
class AlarmBatch:
    """One scan's alarm transitions, with the list as that scan left it (OPC UA Part 9
    sends a condition event per transition, none skipped)."""

    events: tuple[AlarmEvent, ...]
    alarms: tuple[Alarm, ...]


@dataclass(frozen=True)
class HistoryDelta:
    """What happened since the screen's last frame, up to this frame's scan."""

    full: bool  # the whole history kept (a first frame): the screen starts afresh
    edges: tuple[tuple[int, int, bool], ...]  # (signal, time_us, new value) in time order
    events: tuple[PlantEvent, ...]  # the plant's events since
    event_count: int  # events recorded since the runtime started
    damage_count: int
    constraints: Mapping[str, ConstraintStats]  # each violated constraint's history
    alarm_batches: tuple[AlarmBatch, ...]
    batches_lost: int  # alarm batches this screen missed (it fell too far behind)


@dataclass(frozen=True)
class ServiceStatus:
    """A service beside the cell, as the screens show it (the OPC UA gateway)."""

    name: str  # "opcua"
    state: str  # starting, serving, stopped, failed
    text: str  # one line for the status bar's page
    clients: int


@dataclass(frozen=True)
class ResetGuard:
    """A fault reset confirmed on a dialog: carried out only if the reset still does what the
    dialog showed (hmi.explain.reset.changes), checked where the scans run, with no scan
    between the check and the reset."""

    shown: tuple[ResetLine, ...]
    seen_scan: int


# -- screen to runtime ------------------------------------------------------------------

@dataclass(frozen=True)
class Hello:
    protocol: int
    schema: str  # the digest of every message's fields (schema_digest)
    fingerprint: str  # the project's (hmi.project.fingerprint)
    identity: Identity
    want_control: bool  # take control if nobody holds it
    # Who they are, proved (docs/security.md): the password the terminal asked for, or the
    # ticket of a door that checked it (the browser's sign-in page). The runtime decides the
    # role from the users file (hmi.runtime.admission); a password is never kept.
    password: str = ""
    ticket: str = ""


@dataclass(frozen=True)
class Send:
    """An operator command; `on_behalf`: a gateway's user (the OPC UA gateway only)."""

    id: int
    command: Command
    guard: ResetGuard | None = None
    on_behalf: Identity | None = None
    note: str = ""  # said with it in the journal (an OPC UA comment)
    # Asked of the person before the commands that need it (hmi.access.roles): why, into
    # the journal; their password again (switching the filter to monitor), checked, never
    # kept or journalled.
    reason: str = ""
    password: str = ""


@dataclass(frozen=True)
class RequestControl:
    """Ask for control: granted at once if nobody holds it, else the holder is asked."""

    id: int


@dataclass(frozen=True)
class TakeControl:
    """Take control without the holder's consent (the screen confirmed it first)."""

    id: int


@dataclass(frozen=True)
class ReleaseControl:
    id: int


@dataclass(frozen=True)
class HandOver:
    """The holder hands control to a screen (`to`: its id), or keeps it (`to` empty): the
    answer to a request."""

    id: int
    to: str


@dataclass(frozen=True)
class Advance:
    """Virtual time: run the scans `duration_us` holds (none while paused); answered once
    the frame that shows them is sent."""

    id: int
    duration_us: int


@dataclass(frozen=True)
class Query:
    """The runtime's own figures (:class:`Stats`)."""

    id: int


@dataclass(frozen=True)
class Report:
    """A gateway's state for the other screens (the OPC UA server's)."""

    status: ServiceStatus


@dataclass(frozen=True)
class Idle:
    """The screen's person left it untouched for the users file's ``idle-lock``: `locked`
    (the screen is covered; the runtime refuses its commands until it is unlocked), or
    `unlock` with their password again (checked like a sign-in)."""

    id: int
    event: str  # "locked" or "unlock"
    password: str = ""


@dataclass(frozen=True)
class SignInRefused:
    """A gateway refused someone at its door (the OPC UA server): for the journal."""

    refused: SignInRefusal


@dataclass(frozen=True)
class Fault:
    """An error of the screen (its UI), for the journal: contained, or fatal (the screen
    ends; the cell runs on)."""

    what: str
    error: str
    report: str  # the screen's crash file
    fatal: bool


@dataclass(frozen=True)
class Bye:
    """The screen is leaving as asked; `stop`: and the cell stops with it."""

    stop: bool


ClientMessage = (Hello | Send | RequestControl | TakeControl | ReleaseControl | HandOver
                 | Advance | Query | Report | Idle | SignInRefused | Fault | Bye)


# -- runtime to screen ------------------------------------------------------------------

@dataclass(frozen=True)
class Welcome:
    protocol: int
    client: str  # this screen's id
    facts: CellFacts
    runtime: RuntimeInfo
    identity: Identity | None = None  # who the runtime let in (the users file's role)
    # the runtime asks this screen for a reason (and the password) before the commands
    # that need one: people sign in here (a users file exists)
    accountable: bool = False
    # the users file's idle-lock and idle-warning (0: this screen does not lock)
    idle_lock_us: int = 0
    idle_warning_us: int = 0


@dataclass(frozen=True)
class Refused:
    """Not attached: why, in plain words (the connection closes)."""

    reason: str


@dataclass(frozen=True)
class Frame:
    seq: int
    cell: CellView
    run: RunInfo
    overruns: int
    history: HistoryDelta
    control: ControlInfo
    services: tuple[ServiceStatus, ...]


@dataclass(frozen=True)
class Tick:
    """Nothing changed: the runtime is alive (a screen that hears nothing for a while
    says so)."""

    seq: int


@dataclass(frozen=True)
class Reply:
    id: int
    result: CommandResult
    declined: bool = False  # a guarded command not carried out: what it was confirmed on
    #                         changed (the screen asks again)


@dataclass(frozen=True)
class Stats:
    """The runtime's own measurements, answering a :class:`Query`."""

    id: int
    scans: int
    overruns: int
    jitter_p50_us: float
    jitter_p99_us: float
    jitter_max_us: float
    samples: int
    rss_kb: int
    clients: int
    frames_sent: int
    frames_dropped: int  # frames a slow screen did not get (it got a later one)
    backlog_bytes: int  # the most any screen has not read yet (bounded: HIGH_WATER)
    realtime: str


@dataclass(frozen=True)
class Closing:
    """The runtime stops (as asked: `why`); the connection closes after it."""

    why: str


RuntimeMessage = Welcome | Refused | Frame | Tick | Reply | Stats | Closing


# -- the codec ---------------------------------------------------------------------------

CODEC_OVERRIDES: dict[type, dict[str, Any]] = {
    Snapshot: {"layout": LOCAL, "monitors": tuple[MonitorState, ...]},
    Policy: {"command": Command | None},
    Layout: {"grafcet": LOCAL},
}


def codec(layout: Callable[[], Layout] | None = None,
          grafcet: Callable[[], Grafcet | None] | None = None, memo: bool = False) -> Codec:
    """The protocol's codec. A screen gives what is not sent: the layout of every snapshot
    (the Welcome's), the GRAFCET of its own project's control variant. `memo`: a scan
    encoded again (for another screen) is not walked again (the runtime's)."""
    fills: dict[type, dict[str, Callable[[], Any]]] = {}
    if layout is not None:
        fills[Snapshot] = {"layout": layout}
    if grafcet is not None:
        fills[Layout] = {"grafcet": grafcet}
    return Codec(CODEC_OVERRIDES, fills, memo=(CellView, Snapshot) if memo else ())


def schema_digest() -> str:
    """Every field of every message, as a digest: a runtime and a screen compare it."""
    return Codec(CODEC_OVERRIDES).schema_digest(tuple[ClientMessage, RuntimeMessage])

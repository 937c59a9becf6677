"""Where the OPC UA server reads the cell from, and where its clients' commands go.

Two sources, one server (hmi.opcua.server.CellServer):

- :class:`LinkSource`: the cell's runtime seen as a screen sees it (a
  :class:`~hmi.link.base.CellLink`). Over its socket (:class:`~hmi.link.client.SocketLink`)
  this is the OPC UA gateway, a process of its own attached to the runtime like any screen
  (``plchmi gateway``, started by ``plchmi serve --opcua``): a hostile OPC UA client costs
  that process, never the scan's. Every scan's alarm transitions come in the frames
  (``HistoryDelta.alarm_batches``), so a Part 9 client gets one condition event per
  transition, none skipped, as before. A command goes as the gateway's ``Send`` on behalf of
  the OPC UA user: journalled by the runtime with that user (``opcua:alice``), refused unless
  the gateway is in control, like any screen's.
- :class:`SessionSource`: a session in this process, its scans heard as they run
  (``plchmi run --opcua``, a headless run, and the tests of the server itself).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol

from hmi.engine.commands import Command, CommandResult
from hmi.engine.layout import Layout
from hmi.explain.alarms import Alarm, AlarmEvent
from hmi.link.client import SocketLink
from hmi.link.local import LocalLink
from hmi.opcua.users import Identity
from hmi.project.model import Project
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.wire import messages as m

Batch = tuple[tuple[AlarmEvent, ...], tuple[Alarm, ...]]
# told of a command carried out: the command, its result, who sent it ("opcua:alice", "" the
# cell's operator)
CommandListener = Callable[[Command, CommandResult, str], None]


class CellSource(Protocol):
    """What the OPC UA server needs of a cell (module docstring)."""

    project: Project
    layout: Layout
    is_real: bool
    period_us: int

    def start(self, wake: Callable[[], None]) -> None:
        """Begin: `wake` is called (from any thread) when something new may be there."""

    def stop(self) -> None: ...

    def take(self) -> tuple[CellView | None, list[Batch]]:
        """The newest scan, and every scan's alarm transitions since the last take."""

    def run_state(self) -> str:
        """running, paused or stepping."""

    def wall_us(self, time_us: int) -> int:
        """The wall time of the run's time `time_us` (hmi.session.session.Session.wall_us)."""

    def command(self, command: Command, who: Identity, note: str = "") -> CommandResult:
        """An OPC UA user's command (blocking: called from a worker thread)."""

    def refused_for_control(self, result: CommandResult) -> bool:
        """Whether a refused command was refused because this source is not in control."""

    def listen(self, listener: CommandListener) -> None:
        """`listener` hears the commands carried out (SessionSource: every door's; the
        gateway: those of its own users, the others' are the runtime's)."""


class SessionSource:
    """A session in this process (module docstring)."""

    def __init__(self, session: Session):
        self.session = session
        self.project = session.project
        self.layout = session.engine.layout
        self.is_real = session.engine.plant.is_real
        self.period_us = session.period_us
        self._latest: CellView | None = None
        self._batches: deque[Batch] = deque()
        self._wake: Callable[[], None] | None = None

    def _on_scan(self, cell: CellView) -> None:
        """In the scan thread: cheap, never waits (a reference kept, the batch queued)."""
        if cell.alarm_events:
            self._batches.append((cell.alarm_events, cell.alarms))
        self._latest = cell
        if self._wake is not None:
            self._wake()

    def start(self, wake: Callable[[], None]) -> None:
        self._wake = wake
        self.session.scan_listeners.append(self._on_scan)

    def stop(self) -> None:
        if self._on_scan in self.session.scan_listeners:
            self.session.scan_listeners.remove(self._on_scan)
        self._wake = None

    def take(self) -> tuple[CellView | None, list[Batch]]:
        batches = []
        while self._batches:
            batches.append(self._batches.popleft())
        return self._latest, batches

    def run_state(self) -> str:
        return self.session.state.label

    def wall_us(self, time_us: int) -> int:
        return self.session.wall_us(time_us)

    def command(self, command: Command, who: Identity, note: str = "") -> CommandResult:
        origin = f"opcua:{who.name}" + (f" ({note})" if note else "")
        return self.session.command(command, origin)

    def refused_for_control(self, result: CommandResult) -> bool:
        return False  # no screens here: nobody else is in control

    def listen(self, listener: CommandListener) -> None:
        session = self.session
        session.listeners.append(
            lambda command, result, snapshot: listener(command, result, session.origin))


class LinkSource:
    """The cell's runtime through a link (module docstring). `link` is a SocketLink or a
    LocalLink; its receiver hands this every frame, in order."""

    def __init__(self, link: SocketLink | LocalLink):
        self.link = link
        facts: m.CellFacts = link.facts
        self.project = link.project
        self.layout = facts.layout
        self.is_real = facts.plant.is_real
        self.period_us = facts.period_us
        self._epoch_us = facts.epoch_us
        self._batches: deque[Batch] = deque()
        self._lock = threading.Lock()
        self._wake: Callable[[], None] | None = None
        self._listeners: list[CommandListener] = []
        self.batches_lost = 0  # alarm batches the runtime could not send (fell behind)
        link.receiver.listeners.append(self._on_frame)

    def _on_frame(self, frame: m.Frame) -> None:
        """In the link's reader thread (or, in-process, whoever pulled the frame)."""
        delta = frame.history
        with self._lock:
            self._batches.extend((b.events, b.alarms) for b in delta.alarm_batches)
            self.batches_lost += delta.batches_lost
        if self._wake is not None:
            self._wake()

    def start(self, wake: Callable[[], None]) -> None:
        self._wake = wake

    def stop(self) -> None:
        self._wake = None
        with contextlib.suppress(ValueError):
            self.link.receiver.listeners.remove(self._on_frame)

    def take(self) -> tuple[CellView | None, list[Batch]]:
        view = self.link.view()  # (in-process: the frame is pulled now)
        with self._lock:
            batches = list(self._batches)
            self._batches.clear()
        return (view.cell if view is not None else None), batches

    def run_state(self) -> str:
        view = self.link.view()
        if self.link.lost is not None:
            return "lost"
        return view.run.label if view is not None else "starting"

    def wall_us(self, time_us: int) -> int:
        if self._epoch_us is None:  # the runtime had not placed its time 0: place it here
            self._epoch_us = time.time_ns() // 1000 - time_us
        return self._epoch_us + time_us

    def command(self, command: Command, who: Identity, note: str = "") -> CommandResult:
        user = m.Identity(who.name or "", who.role, "opcua", self.link.identity.session)
        answer = self.link.command(command, on_behalf=user, note=note)
        result: CommandResult = answer.result
        for listener in list(self._listeners):
            listener(command, result, user.by)
        return result

    def listen(self, listener: CommandListener) -> None:
        self._listeners.append(listener)

    def refused_for_control(self, result: CommandResult) -> bool:
        if result.accepted:
            return False
        view = self.link.view()
        control = getattr(view, "control", None)
        holder = control.holder if control is not None else None
        return holder is None or holder.id != self.link.client

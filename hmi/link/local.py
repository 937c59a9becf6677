"""A cell whose session runs in this process.

The session's scans run here — in virtual time when the caller says so (:meth:`advance`:
"whoever runs the scans shows the frame"), or on the wall clock in a thread of their own
(``live``: :class:`~hmi.session.live.LiveRunner`).

- :class:`LocalLink`: the protocol in this process: the runtime's hub on the session, every
  message encoded and decoded as over the socket, frames built when the screen reads one.
  The pilot tests, the screenshots and the soak see what a screen of a runtime process sees.
- :class:`SessionLink`: the session read directly, as the HMI did before the runtime had a
  process of its own: the baseline `plchmi bench live` measures the split against.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from datetime import UTC, datetime

from hmi.access.audit import SignInRefusal
from hmi.engine.commands import Command, CommandResult
from hmi.link.base import Answer, Identity, ResetGuard, View
from hmi.link.client import AttachError
from hmi.link.receiver import Receiver
from hmi.runtime.admission import Admission
from hmi.runtime.hub import Client, Hub, cell_facts, run_info
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.live import LiveRunner
from hmi.session.recorder import ScanRecorder
from hmi.session.reset_guard import command_as_shown
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.wire import messages as m

# The scan thread and a UI share one interpreter lock. When the scan thread wakes up for
# its next scan while the UI is rendering, it waits until the UI thread is asked to let go,
# by default after 5 ms: that would be most of a 10 ms period. Half a millisecond bounds
# that wait; measured by `plchmi bench ui`.
SWITCH_INTERVAL_S = 0.0005



def start_runner(runner: LiveRunner | None) -> None:
    """Start the scans in this process (none: virtual time, driven by whoever steps it),
    with a short switch interval so the scan thread gets the interpreter back soon.
    LiveRunner.start freezes what exists (a UI's widgets included) out of the garbage
    collector's sight: a full collection over them took ~40 ms here."""
    if runner is not None:
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        runner.start()


class LocalLink:
    """A :class:`~hmi.link.base.CellLink` speaking the protocol to a hub in this process
    (module docstring). `journal`: the hub journals screens and control as a runtime does."""

    scans_here = True

    def __init__(self, session: Session, live: bool = False,
                 identity: Identity | None = None, want_control: bool = True,
                 journal: JournalRecorder | None = None, admission: Admission | None = None,
                 password: str = ""):
        self.session = session
        self.live = live
        self.project = session.project
        self.identity = identity or Identity("operator", "operator", "terminal", "local")
        self.runner = LiveRunner(session) if live else None
        info = m.RuntimeInfo(os.getpid(), datetime.now(UTC).isoformat(timespec="seconds"),
                             not live, "in this process")
        self.hub = Hub(session, "in-process", info, journal, self.runner, admission)
        self.receiver = receiver = Receiver(session.project)
        hello = m.Hello(m.PROTOCOL, self.hub.schema, "in-process", self.identity,
                        want_control, password)
        sent = self._over(hello)
        assert isinstance(sent, m.Hello)
        client, answer = self.hub.attach(sent)
        if isinstance(answer, m.Refused):
            raise AttachError(answer.reason)
        welcome = self._back(answer)
        assert isinstance(welcome, m.Welcome)
        receiver.welcome(welcome)
        if welcome.identity is not None:
            self.identity = welcome.identity
        self.accountable = welcome.accountable
        self.idle_lock_us, self.idle_warning_us = (welcome.idle_lock_us,
                                                   welcome.idle_warning_us)
        assert client is not None and receiver.facts is not None and receiver.history is not None
        self._client: Client | None = client
        self.facts = receiver.facts
        self.history = receiver.history
        self._pull(force=True)

    def _over(self, message: m.ClientMessage) -> m.ClientMessage:
        """A screen's message as the runtime reads it off the socket."""
        codec = self.receiver.codec
        sent: m.ClientMessage = codec.loads(codec.dumps(message, m.ClientMessage),
                                            m.ClientMessage)
        return sent

    def _back(self, message: m.RuntimeMessage) -> m.RuntimeMessage:
        return self.receiver.decode(self.hub.encode(message))

    def _pull(self, force: bool = False) -> None:
        """The frame the screen would have been pushed now, if anything changed."""
        client = self._client
        if client is None:
            return
        data = self.hub.frame(client, force)
        if data is not None:
            self.receiver.take(self.receiver.decode(data))

    @property
    def recorder(self) -> ScanRecorder:
        """The runtime's recorder (the tests look inside it)."""
        return self.hub.recorder

    def view(self) -> View | None:
        self._pull()
        return self.receiver.view()

    @property
    def last(self) -> CellView | None:
        view = self.view()
        return view.cell if view is not None else None

    @property
    def client(self) -> str | None:
        return self.receiver.client

    def silent_s(self) -> float:
        return 0.0  # the hub is in this process: it always answers

    @property
    def lost(self) -> str | None:
        return self.receiver.lost

    @property
    def error(self) -> BaseException | None:
        return self.runner.error if self.runner is not None else None

    def _ask(self, message: m.ClientMessage) -> m.RuntimeMessage | None:
        client = self._client
        if client is None:
            return None
        answer = self.hub.handle(client, self._over(message))
        self._pull()
        return self._back(answer) if answer is not None else None

    def command(self, command: Command, guard: ResetGuard | None = None,
                on_behalf: Identity | None = None, note: str = "", reason: str = "",
                password: str = "") -> Answer:
        answer = self._ask(m.Send(0, command, guard, on_behalf, note, reason, password))
        return self.receiver.result(answer, type(command).__name__)

    def _control(self, message: m.ClientMessage, what: str) -> CommandResult:
        return self.receiver.result(self._ask(message), what).result

    def lock(self) -> CommandResult:
        return self._control(m.Idle(0, "locked"), "locking the screen")

    def unlock(self, password: str) -> CommandResult:
        return self._control(m.Idle(0, "unlock", password), "unlocking the screen")

    def request_control(self) -> CommandResult:
        return self._control(m.RequestControl(0), "the control request")

    def take_control(self) -> CommandResult:
        return self._control(m.TakeControl(0), "taking control")

    def release_control(self) -> CommandResult:
        return self._control(m.ReleaseControl(0), "releasing control")

    def hand_over(self, to: str) -> CommandResult:
        return self._control(m.HandOver(0, to), "handing control over")

    def report(self, status: m.ServiceStatus) -> None:
        self._ask(m.Report(status))

    def report_refusal(self, refused: SignInRefusal) -> None:
        self._ask(m.SignInRefused(refused))

    def query(self) -> m.Stats:
        return self.hub.stats()

    # -- who runs the scans: this process --------------------------------------------------
    def start(self) -> None:
        start_runner(self.runner)

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop()
        if self._client is not None:
            self.hub.detach(self._client, "client-left", "left")
            self._client = None
        if self.hub._record in self.session.scan_listeners:
            self.session.scan_listeners.remove(self.hub._record)

    def advance(self, duration_us: int) -> int:
        return advance(self.session, duration_us)

    def advance_until(self, predicate: Callable[[CellView], bool], limit_us: int) -> bool:
        return advance_until(self.session, predicate, limit_us)


def advance(session: Session, duration_us: int) -> int:
    """Run the scans `duration_us` of virtual time holds, if running; how many."""
    if not session.state.running:
        return 0
    end = session.engine.now + duration_us
    count = 0
    while session.state.running and session.next_time <= end:
        session.scan_once()
        count += 1
    return count


def advance_until(session: Session, predicate: Callable[[CellView], bool],
                  limit_us: int) -> bool:
    """Run scans until `predicate` holds, at most `limit_us` of virtual time."""
    end = session.engine.now + limit_us
    while session.state.running and session.next_time <= end:
        if predicate(session.scan_once()):
            return True
    return False


class SessionLink:
    """A :class:`~hmi.link.base.CellLink` on a session in this process."""

    scans_here = True

    def __init__(self, session: Session, live: bool = False,
                 identity: Identity | None = None):
        self.session = session
        self.live = live
        self.project = session.project
        self.facts = cell_facts(session)
        self.identity = identity or Identity("operator", session="local")
        self.accountable = False  # nobody signs in to a session in this process
        self.idle_lock_us = self.idle_warning_us = 0
        self.recorder = ScanRecorder(session.engine.layout)
        self.history = self.recorder
        # Told of an error of the recorder (in the scan thread: the scan goes on).
        self.on_recorder_error: Callable[[BaseException], None] | None = None
        self.runner = LiveRunner(session) if live else None
        session.scan_listeners.append(self._record)
        if session.last is None:
            session.scan_once()
        else:
            self._record(session.last)

    def _record(self, cell: CellView) -> None:
        try:
            self.recorder.on_scan(cell)
        except Exception as exc:
            if self.on_recorder_error is not None:
                self.on_recorder_error(exc)

    def view(self) -> View | None:
        recorded = self.recorder.latest()
        if recorded.cell is None:
            return None
        return View(recorded.cell, recorded.constraints, recorded.damage_count,
                    run_info(self.session), self.overruns)

    @property
    def last(self) -> CellView | None:
        return self.session.last

    @property
    def overruns(self) -> int:
        return self.runner.overruns if self.runner is not None else 0

    @property
    def error(self) -> BaseException | None:
        return self.runner.error if self.runner is not None else None

    def lock(self) -> CommandResult:
        return CommandResult.refused("nobody signs in to a cell in this process")

    def unlock(self, password: str) -> CommandResult:
        return self.lock()

    def command(self, command: Command, guard: ResetGuard | None = None, reason: str = "",
                password: str = "") -> Answer:
        """(`password`: nobody signs in here, none is checked; `reason`: journalled.)"""
        session = self.session
        details = {"reason": reason.strip()} if reason.strip() else None
        if guard is None:
            return Answer(session.command(command, self.origin, details))
        result, declined = command_as_shown(session, command, guard.shown, guard.seen_scan,
                                            self.origin, details)
        return Answer(result, declined=declined)

    @property
    def origin(self) -> str:
        return ""

    # -- who runs the scans --------------------------------------------------------------
    def start(self) -> None:
        start_runner(self.runner)

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop()
        if self._record in self.session.scan_listeners:
            self.session.scan_listeners.remove(self._record)

    def advance(self, duration_us: int) -> int:
        return advance(self.session, duration_us)

    def advance_until(self, predicate: Callable[[CellView], bool], limit_us: int) -> bool:
        return advance_until(self.session, predicate, limit_us)

    # -- control: no other screen ------------------------------------------------------------
    client = None
    lost = None

    def silent_s(self) -> float:
        return 0.0

    def request_control(self) -> CommandResult:
        return CommandResult.ok("the only screen: always in control")

    take_control = request_control

    def release_control(self) -> CommandResult:
        return CommandResult.refused("the only screen: control stays here")

    def hand_over(self, to: str) -> CommandResult:
        return CommandResult.refused("the only screen: nobody to hand control to")

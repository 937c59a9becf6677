"""A screen of a cell whose runtime runs in another process: the client over its socket.

:func:`attach` connects to the project's runtime (hmi.runtime.place), says who is there and
which project it loaded (Hello), and gets the cell's facts (Welcome) or why not (Refused:
another version of plchmi, another project's files). A thread then reads what the runtime
pushes: frames (kept: the latest wins), ticks, answers. A command waits for its answer; if
the runtime goes away meanwhile, it is refused with why, and :attr:`SocketLink.lost` says so
at once: the screen never shows the last values as live.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

from hmi.access.audit import SignInRefusal
from hmi.engine.commands import Command, CommandResult
from hmi.link.base import Answer, Identity, ResetGuard, View
from hmi.link.receiver import Receiver
from hmi.project.model import Project
from hmi.runtime.place import socket_address
from hmi.session.view import CellView
from hmi.wire import messages as m
from hmi.wire.framing import MAX_OUT, frame, read_message

ANSWER_S = 120.0  # a command's answer (a step of many scans takes a while)
SILENT_S = 3.0  # no message for this long (a tick comes every second): not responding
CONNECT_S = 10.0


class AttachError(Exception):
    """The runtime cannot be reached, or refused this screen: why, in plain words."""


def connect(path: Path, timeout: float = CONNECT_S) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        with socket_address(path) as address:
            sock.connect(address)
    except OSError as exc:
        sock.close()
        raise AttachError(f"no runtime answers at {path} ({exc.strerror or exc})") from None
    return sock


class SocketLink:
    """A :class:`~hmi.link.base.CellLink` to a runtime process (module docstring)."""

    live = True
    scans_here = False  # the runtime's process scans: quitting this screen need not stop it

    def __init__(self, project: Project, path: Path, fingerprint: str, identity: Identity,
                 want_control: bool = True, timeout: float = CONNECT_S, password: str = "",
                 ticket: str = ""):
        self.project = project
        self.path = path
        self.identity = identity
        self.receiver = receiver = Receiver(project)
        self.codec = receiver.codec
        self._send_lock = threading.Lock()
        self.sock = sock = connect(path, timeout)
        self.attach_s = 0.0
        started = time.perf_counter()
        try:
            self._send(m.Hello(m.PROTOCOL, m.schema_digest(), fingerprint, identity,
                               want_control, password, ticket))
            answer = receiver.decode(read_message(sock, MAX_OUT))
        except (OSError, ConnectionError, ValueError) as exc:
            sock.close()
            raise AttachError(f"the runtime at {path} did not answer: {exc}") from None
        if isinstance(answer, m.Refused):
            sock.close()
            raise AttachError(answer.reason)
        if not isinstance(answer, m.Welcome):
            sock.close()
            raise AttachError(f"the runtime answered a {type(answer).__name__}")
        receiver.welcome(answer)
        if answer.identity is not None:
            self.identity = answer.identity  # as let in: the users file's name and role
        self.accountable = answer.accountable
        self.idle_lock_us, self.idle_warning_us = answer.idle_lock_us, answer.idle_warning_us
        assert receiver.facts is not None and receiver.history is not None
        self.facts = receiver.facts
        self.history = receiver.history
        self.heard = time.monotonic()
        sock.settimeout(None)
        self.first_frame = threading.Event()
        self._reader = threading.Thread(target=self._read, name="plchmi-link", daemon=True)
        self._reader.start()
        self.attach_s = time.perf_counter() - started

    # -- the reader thread ----------------------------------------------------------------
    def _read(self) -> None:
        receiver = self.receiver
        try:
            while True:
                message = receiver.decode(read_message(self.sock, MAX_OUT))
                self.heard = time.monotonic()
                receiver.take(message)
                if isinstance(message, m.Frame):
                    self.first_frame.set()
                if isinstance(message, m.Closing):
                    break
        except (OSError, ConnectionError):
            receiver.lose("its connection closed: the runtime stopped or was killed")
        except ValueError as exc:  # a message this screen cannot read
            receiver.lose(f"the runtime sent what this screen cannot read ({exc})")
        finally:
            receiver.lose("its connection closed")
            self.first_frame.set()

    def _send(self, message: m.ClientMessage) -> None:
        data = self.codec.dumps(message, m.ClientMessage)
        with self._send_lock:
            self.sock.sendall(frame(data))

    def _ask(self, make: Callable[[int], m.ClientMessage], what: str) -> m.RuntimeMessage | None:
        receiver = self.receiver
        if receiver.lost is not None:
            return None
        ident, slot = receiver.expect()
        try:
            self._send(make(ident))
        except OSError as exc:
            receiver.lose(f"the connection to the runtime broke ({exc})")
            return None
        return receiver.answer(ident, slot, ANSWER_S)

    # -- CellLink -------------------------------------------------------------------------
    def view(self) -> View | None:
        return self.receiver.view()

    @property
    def last(self) -> CellView | None:
        view = self.receiver.view()
        return view.cell if view is not None else None

    @property
    def client(self) -> str | None:
        return self.receiver.client

    @property
    def lost(self) -> str | None:
        return self.receiver.lost

    def silent_s(self) -> float:
        """How long since the runtime last said anything (a tick comes every second)."""
        return time.monotonic() - self.heard

    @property
    def error(self) -> BaseException | None:
        return None  # the scans are the runtime's: its loss is `lost`

    def command(self, command: Command, guard: ResetGuard | None = None,
                on_behalf: Identity | None = None, note: str = "", reason: str = "",
                password: str = "") -> Answer:
        answer = self._ask(lambda ident: m.Send(ident, command, guard, on_behalf, note,
                                                reason, password), type(command).__name__)
        return self.receiver.result(answer, type(command).__name__)

    def _control(self, make: Callable[[int], m.ClientMessage], what: str) -> CommandResult:
        return self.receiver.result(self._ask(make, what), what).result

    def lock(self) -> CommandResult:
        """This screen was left untouched and is covered: the runtime refuses its commands
        (and journals it) until :meth:`unlock`."""
        return self._control(lambda ident: m.Idle(ident, "locked"), "locking the screen")

    def unlock(self, password: str) -> CommandResult:
        return self._control(lambda ident: m.Idle(ident, "unlock", password),
                             "unlocking the screen")

    def request_control(self) -> CommandResult:
        return self._control(m.RequestControl, "the control request")

    def take_control(self) -> CommandResult:
        return self._control(m.TakeControl, "taking control")

    def release_control(self) -> CommandResult:
        return self._control(m.ReleaseControl, "releasing control")

    def hand_over(self, to: str) -> CommandResult:
        return self._control(lambda ident: m.HandOver(ident, to), "handing control over")

    def query(self) -> m.Stats | None:
        answer = self._ask(m.Query, "the query")
        return answer if isinstance(answer, m.Stats) else None

    def report(self, status: m.ServiceStatus) -> None:
        self._tell(m.Report(status))

    def report_refusal(self, refused: SignInRefusal) -> None:
        """Someone refused at this gateway's door, for the runtime's journal."""
        self._tell(m.SignInRefused(refused))

    def report_fault(self, fault: object) -> None:
        """An error of this screen (hmi.ui.containment.UIFault), for the runtime's journal."""
        self._tell(m.Fault(str(getattr(fault, "what", "")), str(getattr(fault, "error", "")),
                           str(getattr(fault, "report", "")), bool(getattr(fault, "fatal",
                                                                           False))))

    def _tell(self, message: m.ClientMessage) -> None:
        if self.receiver.lost is None:
            try:
                self._send(message)
            except OSError as exc:
                self.receiver.lose(f"the connection to the runtime broke ({exc})")

    # -- who runs the scans: the runtime --------------------------------------------------
    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass  # the screen closing: it leaves afterwards (leave), as its operator chose

    def leave(self, stop_cell: bool = False) -> None:
        """Leave (the cell runs on), or with `stop_cell` ask the runtime to stop the cell
        (it does if this screen is in control)."""
        if self.receiver.lost is None:
            with contextlib.suppress(OSError):
                self._send(m.Bye(stop_cell))
        if stop_cell:
            self._reader.join(5.0)  # until the runtime closes (Closing), or not
        self.close()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        self.receiver.lose("this screen left")

    def advance(self, duration_us: int) -> int:
        """Virtual time (a runtime started with --virtual): run the scans `duration_us`
        holds; the frame that shows them is here when this returns."""
        answer = self._ask(lambda ident: m.Advance(ident, duration_us), "advance")
        result = self.receiver.result(answer, "advance").result
        if not result.accepted:
            raise RuntimeError(result.message)
        return int(result.message.split()[0])

    def advance_until(self, predicate: Callable[[CellView], bool], limit_us: int) -> bool:
        raise NotImplementedError("a predicate cannot cross the socket: advance(duration)")

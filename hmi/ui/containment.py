"""Fault containment: an error in the UI never stops the scan and never ends the HMI silently.

The scan runs in its own thread and the engine latches its outputs safe on its own internal
errors; the UI is the other half. A bug in a panel, a dialog, a key's action or a palette
entry must not take the operator's screen away while the cell keeps running, nor end the
program as if nothing happened. So the app *contains* such an error where it has the means
to: the operator gets a red banner naming what failed and the file holding the details, the
journal gets an abnormal event, and the screen goes on refreshing (the failing part is tried
again at the next frame: it may recover).

Where an error reaches Textual itself (its own widgets, the compositor) the app cannot carry
on: Textual ends it. It then ends as an abnormal end — the crash file, a journal entry with
the reason, a non-zero exit status, and on a real plant the safe outputs written first (see
``hmi.cli.ui.cmd_ui``) — never as "ended normally".

Where errors are caught:

- every message and event handler of the app, its panels and its dialogs
  (:class:`ContainedPump`): keys and their actions, clicks, resizes, posted messages;
- each panel's share of a frame (``PlcHmiApp.poll``);
- dialog answers, palette entries and the UI's scan listener (the app wraps them).

One crash file per kind of fault (what failed and the exception's type): an error repeated at
every frame is counted, not written twenty times a second.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace

from textual import events
from textual.message import Message

from hmi.crash import write_crash_report
from hmi.ui.textual_adapter import GuardedDispatch


@dataclass(frozen=True)
class UIFault:
    """One kind of UI error: what failed, the error, where its details are, how often."""

    what: str  # "ConstraintsPanel refresh", "action reset", ...
    error: str  # "TypeError: unsupported operand ..."
    report: str  # the crash file's path (or why none could be written)
    count: int = 1  # occurrences so far
    scan: int | None = None  # the engine's scan when it first happened
    time_us: int | None = None
    fatal: bool = False  # the app could not go on (see the module's docstring)

    @property
    def summary(self) -> str:
        times = f" (×{self.count})" if self.count > 1 else ""
        return f"{self.what}: {self.error}{times}"


Listener = Callable[[UIFault], None]


class Containment:
    """The UI errors of a session; thread-safe (the scan thread's listener reports too)."""

    def __init__(self, where: Callable[[], tuple[int | None, int | None]] = lambda: (None, None)):
        self.faults: dict[tuple[str, str], UIFault] = {}
        self.latest: UIFault | None = None
        self.fatal: UIFault | None = None
        self.total = 0
        self.version = 0  # bumped at every record: the screen redraws its banner
        # Told once per kind of fault (its first occurrence) and of the fatal one: the journal.
        self.listeners: list[Listener] = []
        self._where = where
        self._lock = threading.Lock()

    def record(self, what: str, exc: BaseException, fatal: bool = False) -> UIFault:
        """Remember an error; write its crash file and tell the listeners the first time."""
        error = f"{type(exc).__name__}: {exc}"
        key = (what, type(exc).__name__)
        with self._lock:
            self.total += 1
            self.version += 1
            old = self.faults.get(key)
            if old is not None and not fatal:
                fault = self.faults[key] = replace(old, count=old.count + 1)
                self.latest = fault
                return fault
        scan, time_us = self._safe_where()
        report = write_crash_report(exc, f"plchmi UI error in {what} at scan {scan}")
        fault = UIFault(what, error, report, (old.count + 1) if old else 1, scan, time_us,
                        fatal)
        with self._lock:
            self.faults[key] = fault
            self.latest = fault
            if fatal:
                self.fatal = fault
        for listener in list(self.listeners):
            # a listener (the journal) failing must not hide the fault
            with contextlib.suppress(Exception):
                listener(fault)
        return fault

    def _safe_where(self) -> tuple[int | None, int | None]:
        try:
            return self._where()
        except Exception:
            return None, None


# Lifecycle messages: a widget that failed to build or mount is not there to be drawn; those
# errors go on to Textual, which ends the app (an abnormal end).
_NOT_CONTAINED = (events.Compose, events.Mount, events.Unmount)


class ContainedPump(GuardedDispatch):
    """Mixin for the app, its panels and its dialogs: an error in one of their handlers is
    contained (see the module docstring) instead of ending the app.

    It hears every error of the node's handlers where Textual handles each event and message
    (hmi.ui.textual_adapter.GuardedDispatch): wrapping each handler instead would leave out
    the next one written."""

    def handler_failed(self, message: Message, error: Exception) -> bool:
        if isinstance(message, _NOT_CONTAINED):
            return False
        contain = getattr(self.app, "contain", None)  # type: ignore[attr-defined]
        if contain is None:
            return False
        contain(f"{type(self).__name__} {message.handler_name}", error)
        return True

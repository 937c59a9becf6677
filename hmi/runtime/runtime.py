"""A cell's runtime: its scans, its screens' endpoint, and how it ends.

The process runs the scan (a :class:`~hmi.session.live.LiveRunner` at real-time priority
where the kernel allows it, or virtual time driven by the screen in control), the hub and
the socket server, and nothing interactive: no Textual, no network server. It ends when the
screen in control asks it to stop, on SIGTERM or SIGINT, or when its scan thread dies; the
caller (hmi.cli.serve_cell) then leaves a real plant's outputs safe and closes the journal.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from datetime import UTC, datetime
from pathlib import Path

from hmi.runtime.admission import Admission
from hmi.runtime.hub import Hub
from hmi.runtime.server import SocketServer
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.live import LiveRunner
from hmi.session.session import Session
from hmi.wire import messages as m

SWITCH_INTERVAL_S = 0.0005  # a waking scan thread waits at most this for the interpreter
HELPERS_PRIORITY = 5  # SCHED_FIFO of the runtime's other threads, below its scan's


def helpers_realtime(scan_thread: int | None) -> bool:
    """The runtime's other threads (its screens' server, the history's and the journal's
    writers, the main thread) at SCHED_FIFO below the scan.

    The scan needs the interpreter lock as well as a core. On a loaded machine a thread of
    normal priority that holds the lock is descheduled for tens of milliseconds at a time,
    and the scan, which preempted it for its core, waits for it all that while (21 overruns in
    10 minutes at load 20-24 with five screens attached, lateness up to 44 ms). At real-time
    priority below the scan's, the holder runs again at once and gives the lock up within the
    switch interval. They mostly wait (sockets, queues, a disk); threads they start inherit
    the priority, except the sign-in checks (hmi.access.signin), which give it back.

    Called from the main thread before it starts the server and the scan (:meth:`Runtime.start`):
    raising an existing thread from outside races with the threads it is starting (one still
    starting has no kernel id yet and was missed, its connection's thread then ran at normal
    priority for good), but a thread started by a raised one inherits the priority, so only
    the threads started before this call are raised here: their `start()` has returned, every
    one has its id."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(HELPERS_PRIORITY))
    except (OSError, AttributeError):  # no privilege, or not Linux
        return False
    me = threading.get_native_id()
    for thread in threading.enumerate():
        tid = thread.native_id
        if tid is not None and tid not in (me, scan_thread):
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(HELPERS_PRIORITY))
    return True


def helpers_normal(scan_thread: int | None) -> None:
    """Every thread but the scan (which sets its own) back at normal priority: the scan did
    not get its real-time priority above theirs. The kernel's list of the process's threads,
    so none is missed."""
    with contextlib.suppress(OSError):
        for task in Path("/proc/self/task").iterdir():
            with contextlib.suppress(OSError, ValueError):
                if int(task.name) != scan_thread:
                    os.sched_setscheduler(int(task.name), os.SCHED_OTHER, os.sched_param(0))


class Runtime:
    def __init__(self, session: Session, fingerprint: str, socket: Path,
                 journal: JournalRecorder | None = None, virtual: bool = False,
                 realtime: bool = True, admission: Admission | None = None):
        self.session = session
        self.journal = journal
        self.virtual = virtual
        self.runner = None if virtual else LiveRunner(session, realtime=realtime)
        info = m.RuntimeInfo(os.getpid(), datetime.now(UTC).isoformat(timespec="seconds"),
                             virtual, "virtual time" if virtual else "starting")
        # who may attach: the machine's users file (hmi.runtime.admission)
        self.admission = admission or Admission()
        self.hub = Hub(session, fingerprint, info, journal, self.runner, self.admission)
        self.server = SocketServer(self.hub, socket)
        self.ended = threading.Event()
        self.why = ""
        self.hub.on_stop.append(self.end)

    def start(self) -> None:
        """Listen, then scan (a real plant: connected before this is called)."""
        # raised first: the server's and the scan's threads, and theirs, inherit the priority
        raised = self.runner is not None and self.runner.realtime and helpers_realtime(None)
        self.server.start()
        if self.runner is not None:
            sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
            self.runner.start()
            self.runner.realtime_known.wait(5.0)
            state = self.runner.realtime_state
            if raised and state.startswith("SCHED_FIFO"):
                state += f", its other threads SCHED_FIFO {HELPERS_PRIORITY}"
            elif raised:
                helpers_normal(self.runner.thread_id)
            self.hub.runtime = m.RuntimeInfo(
                self.hub.runtime.pid, self.hub.runtime.started, False, state)
            if self.journal is not None:
                self.journal.on_service("runtime", f"the scan thread runs at {state}")

    def end(self, why: str) -> None:
        """Stop serving (every screen is told why) and let wait() return."""
        if not self.ended.is_set():
            self.why = why
            self.ended.set()

    def wait(self, poll_s: float = 0.2) -> str | None:
        """Until the runtime is asked to end; the scan thread's death is an abnormal end:
        returned as the reason (None: it ended as asked)."""
        while not self.ended.wait(poll_s):
            runner = self.runner
            if runner is not None and runner.started and not runner.alive:
                return f"the scan thread stopped: {runner.error!r}"
        return None

    def stop(self, why: str) -> None:
        self.server.stop(why)
        self.admission.close()
        if self.runner is not None:
            self.runner.stop()

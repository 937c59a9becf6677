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
    the priority, except the sign-in checks (hmi.access.signin), which give it back."""
    raised = False
    done: set[int] = set()
    # twice: a thread started meanwhile by one not yet raised (a screen attaching at once) was
    # born at normal priority and is raised by the second pass; after it every parent is
    # raised and its new threads inherit the priority
    for _ in range(2):
        for thread in threading.enumerate():
            tid = thread.native_id
            if tid is None or tid == scan_thread or tid in done:
                continue
            done.add(tid)
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(HELPERS_PRIORITY))
                raised = True
    return raised


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
        self.server.start()
        if self.runner is not None:
            sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
            self.runner.start()
            self.runner.realtime_known.wait(5.0)
            state = self.runner.realtime_state
            if state.startswith("SCHED_FIFO") and helpers_realtime(self.runner.thread_id):
                state += f", its other threads SCHED_FIFO {HELPERS_PRIORITY}"
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

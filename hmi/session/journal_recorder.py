"""Connects a session to the journal: operator actions and alarm transitions.

It listens to the session (commands with their results, and every scan's snapshot), so the
engine itself never touches a file. A manual request is journalled twice: when it is made,
and once the next scan shows what the filter did with it. On a real plant it also drains the
plant's link events (connections, retries, exception responses: hmi.plant.modbus.link_log) and
counts scan overruns, one entry per episode or minute, never one per scan.

If the journal cannot be written during a session (a full disk, an I/O error), what the
operator does and sees is no longer recorded: the recorder latches the outputs to their safe
state with the reason (the operator is told, as for any internal failure), keeps the error in
`failure` for the caller (a headless run stops, exit status 1) and tries again at the next
entry.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Protocol

from hmi.engine.commands import Command, CommandResult, ManualOutput, describe
from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import AlarmEvent
from hmi.explain.journal import Entry, Journal, JournalWriteError, new_session_id
from hmi.explain.model import Explanation, Policy
from hmi.limits import describe_bytes
from hmi.plant.modbus.link_log import Burst
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.timefmt import seconds

DEFAULT_SPACE = 1 << 30  # the journal's space unless told (--journal-space)
SPACE_WARNING = 0.8  # the storage alarm from this share of it
SPACE_KEY = "journal:space"
SPACE_CHECK_S = 60.0


class Fault(Protocol):
    """An error of a screen, for the journal: hmi.ui.containment.UIFault (this process's
    screen) or hmi.wire.messages.Fault (a remote screen's report of one)."""

    @property
    def what(self) -> str: ...
    @property
    def error(self) -> str: ...
    @property
    def report(self) -> str: ...
    @property
    def fatal(self) -> bool: ...


class JournalRecorder:
    def __init__(self, session: Session, journal: Journal, source: str = "hmi",
                 space_bytes: int = DEFAULT_SPACE):
        self.session = session
        self.space_bytes = space_bytes
        self._space_checked = -SPACE_CHECK_S
        self.journal = journal
        self.pending_manual: list[tuple[ManualOutput, str]] = []  # with who sent it
        self.failure: JournalWriteError | None = None
        self.recovery_status = ""  # the last recovery status journalled (done, failed)
        # Told of every entry once it is in the journal (the historian keeps the alarms and
        # actions beside its samples); from the thread that journalled it, so never waiting.
        self.taps: list[Callable[[Entry], None]] = []
        engine = session.engine
        journal.session = new_session_id()
        # (kept for whoever taps the journal later: the historian records it too)
        self.start_entry = {"type": "session", "event": "start", "source": source,
                            "project": engine.project.name, "control": engine.control_name,
                            "policy": engine.policy,
                            "plant": engine.plant.status.description,
                            "scan": engine.scan, "t": seconds(engine.now)}
        journal.append(self.start_entry)
        self.link = engine.plant.link  # a real plant's LinkLog (None: simulated)
        self.overruns = Burst("scan-overrun", "scan-overruns", "scan overruns")
        session.listeners.append(self.on_command)
        session.scan_listeners.append(self.on_scan)
        session.idle_checks[self.on_scan] = self.idle
        session.overrun_listeners.append(self.on_overrun)

    def _append(self, entry: Entry) -> None:
        self._append_all([entry])

    def _append_all(self, entries: list[Entry]) -> None:
        try:
            self.journal.append_all(entries)
        except JournalWriteError as exc:
            self.failure = exc
            self.session.engine.latch_safe(
                "journal", f"{exc}: operator actions and alarms cannot be recorded")
            return
        for tap in self.taps:
            for entry in entries:
                tap(entry)

    def sync(self) -> None:
        """Until every entry so far is on disk (a journal written in the background: a
        command's answer waits for its entry, outside the session's lock)."""
        try:
            self.journal.flush()
        except JournalWriteError as exc:
            self.failure = exc
            self.session.engine.latch_safe(
                "journal", f"{exc}: operator actions and alarms cannot be recorded")

    def on_command(self, command: Command, result: CommandResult,
                   cell: CellView | None) -> None:
        engine = self.session.engine
        entry = {"type": "action", "event": describe(command), "accepted": result.accepted,
                 "message": result.message, "scan": engine.scan, "t": seconds(engine.now)}
        if self.session.origin:
            entry["by"] = self.session.origin
            entry.update(self.session.origin_details)
        self._append(entry)
        if isinstance(command, ManualOutput) and result.accepted and command.value is not None:
            self.pending_manual.append((command, self.session.origin))
        for event in self.session.take_alarm_events():  # acknowledgements, journalled now
            self._alarm(event, self.session.origin)

    def on_overrun(self, total: int) -> None:
        engine = self.session.engine
        for entry in self.overruns.hit(time.monotonic(), total=total, message=(
                f"scan {engine.scan} started more than a whole period late; the runner "
                "re-anchored its schedule")):
            self._plant(entry)

    def _plant(self, entry: Entry) -> None:
        engine = self.session.engine
        self._append({"type": "plant", **entry, "scan": engine.scan,
                      "t": seconds(engine.now)})

    def _drain_plant(self) -> None:
        if self.link is not None:
            for entry in self.link.drain():
                self._plant(entry)

    def idle(self) -> bool:
        """Whether a quiet scan (no news, no alarm: Session.run_for) has nothing to journal:
        no plant link to drain nor overrun episode going on (their entries come with time),
        no manual request waiting for its filter result. Its alarm events are none and its
        recovery state the last one's, journalled then."""
        return (self.link is None and not self.overruns.active and not self.pending_manual
                and not self._due())

    def _due(self) -> bool:
        """The anchor or the storage check is due (once a minute at most)."""
        now = time.monotonic()
        return (now - self._space_checked >= SPACE_CHECK_S
                or self.journal.tick_due(now))

    def space(self, space_bytes: int) -> None:
        """The journal's configured space (the storage alarm's), checked now."""
        self.space_bytes = space_bytes
        self.check_space()

    def check_space(self) -> None:
        """The storage alarm: the journal has used SPACE_WARNING of its space, or of what
        it can still have on its disk if that is less (the disk fills before the space)."""
        self._space_checked = time.monotonic()
        used = self.journal.size()
        try:
            disk = os.statvfs(self.journal.path.parent)
            room = min(self.space_bytes, used + disk.f_bavail * disk.f_frsize)
        except OSError:
            room = self.space_bytes
        if room <= 0 or used < SPACE_WARNING * room:
            self.session.report(SPACE_KEY, None)
            return
        engine = self.session.engine
        disk_bound = room < self.space_bytes
        share = 100 * used / room
        self.session.report(SPACE_KEY, Explanation(
            key=SPACE_KEY, kind="journal", severity="high" if share >= 95 else "medium",
            device="Journal", what=f"The journal has used {share:.0f} % of its space",
            why=(f"The journal {self.journal.path} holds {describe_bytes(used)} of "
                 + (f"{describe_bytes(room)}, all its disk has left" if disk_bound
                    else f"the {describe_bytes(self.space_bytes)} configured for it")
                 + "."),
            consequences=("The cell keeps running and journalling. If the journal cannot be "
                          "written (its disk full), the outputs are held safe and the cell "
                          "stops until a fault reset: archive the journal or give it room "
                          "before then."),
            policies=(Policy("understood", "Understood", "Nothing is sent: archive the "
                             "journal elsewhere, free disk space or configure more space "
                             "(--journal-space)", recommended=True),),
            since_scan=engine.scan, since_us=engine.now,
            detail=f"used {used:,} bytes; space {self.space_bytes:,} bytes; warning at "
                   f"{SPACE_WARNING:.0%}"))

    def on_scan(self, cell: CellView) -> None:
        snapshot = cell.snapshot
        self.journal.tick()
        if time.monotonic() - self._space_checked >= SPACE_CHECK_S:
            self.check_space()
        self._drain_plant()
        for entry in self.overruns.tick(time.monotonic()):
            self._plant(entry)
        if cell.alarm_events:  # one write and one fsync for the scan's transitions
            batch: list[Entry] = []
            for event in cell.alarm_events:
                self._alarm(event, batch=batch)
            self._append_all(batch)
        recovery = snapshot.recovery
        if recovery.status != self.recovery_status:
            self.recovery_status = recovery.status
            if recovery.status in ("done", "failed"):
                self._append({"type": "recovery", "event": recovery.status,
                              "key": f"recovery:{recovery.active}",
                              "message": f"{recovery.device}: {recovery.message}",
                              "scan": snapshot.scan, "t": seconds(snapshot.time_us)})
        if self.pending_manual:
            for request, origin in self.pending_manual:
                outcome = self._manual_outcome(snapshot, request)
                entry = {
                    "type": "action", "event": f"manual {request.name} "
                    f"{'on' if request.value else 'off'}: filter result", "accepted": True,
                    "message": outcome, "scan": snapshot.scan, "t": seconds(snapshot.time_us)}
                if origin:
                    entry["by"] = origin
                self._append(entry)
            self.pending_manual = []

    def _manual_outcome(self, snapshot: Snapshot, request: ManualOutput) -> str:
        """What the first scan after a manual request wrote, judged against the request: a
        scan that ran outside manual mode (the mode changed before it: the request was
        dropped), the filter, a device the operator stopped (held safe before the filter)
        or the diagnosis' mask may each write something else than asked."""
        name = request.name
        written = int(snapshot.outputs[snapshot.layout.outputs.index(name)])
        if snapshot.mode != "manual":
            return f"not applied: the scan ran in {snapshot.mode} mode (written {written})"
        report = snapshot.filter_report
        change = next((c for c in (report.changes if report else ()) if c.output == name),
                      None)
        if change is not None:
            return f"refused: written {written} because of {', '.join(change.by)}"
        if request.value is not None and written == int(request.value):
            return f"written {written} as requested"
        device = next((d for d, outs in self.session.engine.devices.items() if name in outs),
                      None)
        if device in snapshot.stopped_devices:
            return f"refused: written {written}: {device} is stopped by the operator"
        if name in snapshot.masked:
            return f"refused: written {written}: masked by the diagnosis"
        return f"refused: written {written}, not as requested"

    def _alarm(self, event: AlarmEvent, by: str = "", batch: list[Entry] | None = None) -> None:
        """Journal one alarm transition now, or add it to `batch` (written by the caller)."""
        entry = self._alarm_entry(event, by)
        if batch is None:
            self._append(entry)
        else:
            batch.append(entry)

    @staticmethod
    def _alarm_entry(event: AlarmEvent, by: str = "") -> Entry:
        entry: Entry = {
            "type": "alarm", "event": event.event, "key": event.key, "state": event.state,
            "severity": event.severity, "text": event.text, "returns": event.returns,
            "scan": event.scan, "t": seconds(event.time_us)}
        if event.note:
            entry["message"] = event.note
        if by:
            entry["by"] = by
        return entry

    def on_ui_fault(self, fault: Fault, **who: str) -> None:
        """An error of the HMI (hmi.ui.containment.UIFault, or a screen's report of one):
        contained, or fatal; `who`: the screen's (by, role, client)."""
        engine = self.session.engine
        ended = "; the screen ended, the cell runs on" if who else ""
        self._append({
            "type": "session", "event": "ui-error", "what": fault.what, "fatal": fault.fatal,
            "message": f"{fault.error}; details in {fault.report}"
                       + (ended if fault.fatal else "; contained, the scan goes on"),
            "crash_file": fault.report, **who, "scan": engine.scan, "t": seconds(engine.now)})

    def on_service(self, event: str, message: str, **fields: str) -> None:
        """A service beside the scan changed state (the OPC UA server: opcua-serving,
        opcua-stopped, opcua-failed; a screen attached, lost, control handed over), told
        from its own thread; `fields`: who (by, role, client)."""
        engine = self.session.engine
        with self.session.lock:
            self._append({"type": "session", "event": event, "message": message, **fields,
                          "scan": engine.scan, "t": seconds(engine.now)})

    def close(self, abnormal: str | None = None, note: str | None = None) -> None:
        """The session's last entry: `stop` if it ended as asked, else `abnormal-end` with
        the reason (never "ended normally" after an error). `note`: it ended as asked, but
        after errors that were contained (the stop says so, not "normally")."""
        engine = self.session.engine
        self._drain_plant()
        for entry in self.overruns.end(time.monotonic()):
            self._plant(entry)
        name = engine.project.name
        try:
            if abnormal is None:
                how = f"ended as asked, {note}" if note else "ended normally"
                self._append({"type": "session", "event": "stop", "scan": engine.scan,
                              "t": seconds(engine.now), "message": f"{name}, {how}"})
            else:
                self._append({"type": "session", "event": "abnormal-end", "scan": engine.scan,
                              "t": seconds(engine.now),
                              "message": f"{name}, ended abnormally: {abnormal}"})
        finally:
            self.journal.close()

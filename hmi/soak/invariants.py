"""What must hold after every step of a soak, and after every scan: checked from outside.

The checker listens to the session like the journal does (every scan, every command) and
reads the journal file the session writes; it recomputes what it checks from what it sees
rather than trusting the engine's own report of it:

- **no exception anywhere**: no UI error contained, no fatal one, no exception kept by Textual,
  the app still running, no internal error in a scan;
- **safe outputs**: the outputs written satisfy every safety constraint — each constraint is
  evaluated here, on the vector written and the values of the scans before it — unless the
  policy is ``monitor``, or every output of the constraint is masked by a diagnoser (the
  mask has the last word, docs/project-format.md), or the vector written is exactly the
  project's safe state, written by decision (safe blocking, a fallback, a latch): the safe
  state has the last word too — dropping every order may break a constraint of the form
  ``not o and h1`` ("never drop the open order before the valve is open", CSs4). Those scans
  are counted per constraint (:attr:`Invariants.safe_state_violations`), never hidden;
  in recovery mode the constraints are those of the procedure running: the project's but the
  ones it relaxes, plus its own;
- **ISA-18.2**: an alarm never leaves the list unacknowledged (only an acknowledged alarm
  leaves when it clears, a cleared one when it is acknowledged); the priority of an alarm in
  the list (active or unacknowledged) never goes down; every change of an alarm's state seen
  in the list is in the journal, in order; an alarm the operator shelves leaves the list in
  any state (hidden, not gone: its "shelved" line carries its state) and its return is
  journalled too;
- **the status bar** shows the mode and the filter policy of the scan on screen, and the count
  of the most urgent unacknowledged alarms (``3 P1 unack``);
- **the most urgent alarms are visible**: the active unacknowledged alarms of the highest
  priority listed are rows of the alarm list on screen — all of them that fit in its rows
  (the selection keeps a row of its own: all but one when it is an urgent one out of them);
- **no dialog hides the status bar**: over a dialog (or the palette) the status bar and the
  banners are still on screen, and the dialog's screen lets the cell show through;
- **the journal**: every line parses (a JSON object with a type and an event); a manual
  request's outcome never says "as requested" of another value than the one requested.
"""

from __future__ import annotations

import json
import re
from collections import Counter, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from textual.geometry import Region

from hmi.engine.commands import Acknowledge, Command, CommandResult
from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import ACTIVE_ACK, ACTIVE_UNACK, CLEARED_UNACK, Alarm
from hmi.explain.journal import Entry
from hmi.project.model import Constraint
from hmi.project.recovery import recoveries_of
from hmi.session.session import Session
from hmi.session.view import CellView
from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.ui.app import PlcHmiApp

UNACKNOWLEDGED = (ACTIVE_UNACK, CLEARED_UNACK)
MANUAL_RESULT = re.compile(r"manual (\S+) (on|off): filter result")
AS_REQUESTED = re.compile(r"written ([01]) as requested")
MODE_WORDS = {"auto": "AUTO", "manual": "MANUAL"}


@dataclass(frozen=True)
class Broken:
    """A broken invariant: which, what was seen, and when (the engine's scan and time)."""

    invariant: str
    detail: str
    scan: int
    time_us: int

    def __str__(self) -> str:
        return f"{self.invariant} at scan {self.scan} (t = {seconds(self.time_us)} s): " \
               f"{self.detail}"


@dataclass(frozen=True)
class _Term:
    """A literal of a constraint, as the checker reads it: an output written at t (its index
    in the output vector), or a value `depth` scans back (its slot in the image)."""

    output: int | None
    slot: int
    depth: int
    positive: bool


class Invariants:
    def __init__(self, app: PlcHmiApp, session: Session, journal_path: Path):
        self.app = app
        self.session = session
        self.engine = engine = session.engine
        layout = engine.layout
        outputs = {name: k for k, name in enumerate(layout.outputs)}
        def checked(constraints: Iterable[Constraint]
                    ) -> list[tuple[str, frozenset[str], tuple[_Term, ...]]]:
            return [(c.name, frozenset(c.outputs),
                     tuple(_Term(outputs.get(lit.name) if lit.depth == 0 else None,
                                 layout.slots[lit.name], lit.depth, lit.positive)
                           for lit in c.literals))
                    for c in constraints]

        project = engine.project
        self.constraints = checked(project.constraints)
        # A recovery procedure is filtered by the project's constraints but the ones it
        # relaxes, plus its own (docs/ui.md, "Recovery"): while it is the active one, that is
        # what the outputs written must satisfy.
        self.recovery_constraints = {
            spec.name: checked([c for c in project.constraints if c.name not in spec.relaxes]
                               + list(spec.constraints))
            for spec in recoveries_of(project)}
        depth = max([1] + [t.depth for group in (self.constraints,
                                                 *self.recovery_constraints.values())
                           for _, _, terms in group for t in terms])
        self.history: deque[tuple[object, ...]] = deque(maxlen=depth)  # values of the scans before
        self.alarms: dict[str, Alarm] = {}  # the list as last seen, by key
        self.hidden: set[str] = set()  # alarms that left the list for a shelf
        self.expected: dict[str, deque[tuple[str, int]]] = {}  # transitions to find
        self.journal_path = journal_path
        self._journal_at = 0  # bytes read so far
        self._partial = b""
        self.journal_lines = 0
        self.transitions = 0
        self.raised = 0
        self.scans = 0
        self.broken: list[Broken] = []
        self.max_alarms = 0
        # how many times each kind of check ran (the figures of a soak say so)
        self.checks: Counter[str] = Counter()
        # scans where the safe state, written by decision, left a constraint violated
        self.safe_state_violations: Counter[str] = Counter()
        self.safe_vector = tuple(engine.safe_vector)
        session.scan_listeners.append(self.on_scan)
        session.listeners.append(self.on_command)

    @property
    def ok(self) -> bool:
        return not self.broken

    def _break(self, invariant: str, detail: str) -> None:
        self.broken.append(Broken(invariant, detail, self.engine.scan, self.engine.now))

    # -- every scan ---------------------------------------------------------------------------
    def on_scan(self, view: CellView) -> None:
        self.scans += 1
        snap = view.snapshot
        if view.error:
            self._break("engine-error", view.error)
        if snap.policy != "monitor":
            constraints = self.recovery_constraints.get(snap.recovery.active or "",
                                                        self.constraints)
            self.checks["constraint"] += len(constraints)
            violated = self._violated(snap, constraints)
            masked = set(snap.masked)
            unsafe = [name for name, outs in violated if not outs <= masked]
            if unsafe and self._safe_state_by_decision(snap):
                self.safe_state_violations.update(unsafe)
                unsafe = []
            if unsafe:
                written = " ".join(f"{n}={int(v)}" for n, v in
                                   zip(snap.layout.outputs, snap.outputs, strict=True))
                self._break("unsafe-output",
                            f"{', '.join(unsafe)} violated by the outputs written ({written}; "
                            f"policy {snap.policy}, mode {snap.mode}, masked "
                            f"{', '.join(snap.masked) or 'none'}, latched "
                            f"{'; '.join(r.detail for r in snap.latched) or 'no'})")
        self.history.appendleft(snap.values)
        self._observe(view.alarms, acknowledged=())

    def _safe_state_by_decision(self, snap: Snapshot) -> bool:
        """The outputs written are the safe state, and the engine says it chose it."""
        report = snap.filter_report
        decided = bool(snap.latched) or (report is not None and report.safe_state)
        return decided and tuple(snap.outputs) == self.safe_vector

    def _violated(self, snap: Snapshot,
                  constraints: Sequence[tuple[str, frozenset[str], tuple[_Term, ...]]]
                  ) -> list[tuple[str, frozenset[str]]]:
        history = self.history
        values, written = snap.values, snap.outputs
        found: list[tuple[str, frozenset[str]]] = []
        for name, outs, terms in constraints:
            for term in terms:
                if term.depth > len(history):
                    break  # a value from before the first scan seen: not judged
                value: object
                if term.output is not None:
                    value = written[term.output]
                elif term.depth == 0:
                    value = values[term.slot]
                else:
                    value = history[term.depth - 1][term.slot]
                if bool(value) != term.positive:
                    break
            else:
                found.append((name, outs))
        return found

    # -- every command ------------------------------------------------------------------------
    def on_command(self, command: Command, result: CommandResult,
                   view: CellView | None) -> None:
        # the alarm list as the next scan will show it (the session owns it)
        manager = self.session.alarms
        acknowledged: tuple[str, ...] = ()
        if isinstance(command, Acknowledge) and result.accepted:
            acknowledged = (command.key,) if command.key is not None else tuple(self.alarms)
        self._observe(manager.listed(), acknowledged)

    # -- the alarm list -----------------------------------------------------------------------
    def _observe(self, alarms: Iterable[Alarm], acknowledged: tuple[str, ...]) -> None:
        now = {a.key: a for a in alarms}
        self.max_alarms = max(self.max_alarms, len(now))
        self.checks["alarm"] += len(now) + len(self.alarms)
        manager = self.session.alarms
        for key, old in self.alarms.items():
            if key in now:
                continue
            if key in manager.shelved:
                # Shelved by the operator: hidden from the list, not gone; its "shelved"
                # line in the journal carries its state (ISA-18.2 §11).
                self.hidden.add(key)
                held = manager.alarms.get(key)
                self._expect(key, held.state if held is not None else old.state)
                continue
            leaves_ok = (old.state == ACTIVE_ACK and not acknowledged) or \
                (old.state == CLEARED_UNACK and key in acknowledged)
            if old.state in UNACKNOWLEDGED and not leaves_ok:
                self._break("alarm-left-unacknowledged",
                            f"{key} ({old.text!r}, P{old.priority}) left the list while "
                            f"{old.state}")
            self._expect(key, "normal")
        for key, alarm in now.items():
            seen = self.alarms.get(key)
            if seen is None:
                if key in self.hidden:  # back from its shelf (its "unshelved" line)
                    self.hidden.discard(key)
                else:
                    self.raised += 1
                self._expect(key, alarm.state)
                continue
            if alarm.priority > seen.priority:
                self._break("priority-lowered",
                            f"{key} went from P{seen.priority} to P{alarm.priority} while "
                            f"{seen.state} → {alarm.state} ({seen.text!r} → {alarm.text!r})")
            if alarm.state != seen.state:
                self._expect(key, alarm.state)
        self.alarms = now

    def _expect(self, key: str, state: str) -> None:
        self.transitions += 1
        self.expected.setdefault(key, deque()).append((state, self.engine.scan))

    # -- after every step ---------------------------------------------------------------------
    def check_step(self) -> list[Broken]:
        """The checks that need the screen or the journal; returns everything broken so far."""
        self.checks["step"] += 1
        self._check_app()
        self._check_status_bar()
        self._check_urgent_alarms()
        self._check_dialogs()
        self.check_journal()
        return self.broken

    def _check_app(self) -> None:
        app = self.app
        contained = app.containment
        # An error left to Textual's last resort is contained.fatal too (PlcHmiApp.last_resort)
        fault = contained.fatal or contained.latest
        if fault is not None and not any(b.invariant == "exception" for b in self.broken):
            self._break("exception", f"{fault.summary} (details in {fault.report})")
        if not app.is_running and not any(b.invariant == "exception" for b in self.broken):
            self._break("app-ended", f"the app stopped (return code {app.return_code})")

    def _check_status_bar(self) -> None:
        from hmi.ui.status import StatusBar
        app = self.app
        frame = app.frame
        if frame is None:
            return
        status = app.screen_stack[0].query_one(StatusBar)
        width = status.size.width
        if not width:
            return
        strip = status.render_lines(Region(0, 0, width, 1))[0]
        line = strip.text
        snap = frame.snapshot
        mode = MODE_WORDS.get(snap.mode, snap.mode.upper())
        missing = [word for word in (mode, snap.policy) if word not in line]
        if missing:
            self._break("status-bar", f"{' and '.join(missing)} not shown at {app.size.width}"
                        f"×{app.size.height}: {line.rstrip()!r}")

    def _check_urgent_alarms(self) -> None:
        """The most urgent unacknowledged alarms are on screen: each is a row of the alarm
        list (its priority, time raised and the start of its text), as many as the list's
        rows allow, and the status bar counts them. Read from the alarm list's lines as
        drawn, recomputed from the frame's alarms."""
        from hmi.ui.alarm_list import AlarmList, rows_for_height
        from hmi.ui.status import StatusBar
        app = self.app
        frame = app.frame
        if frame is None:
            return
        alarms = frame.cell.alarms
        active = [a for a in alarms if a.state == ACTIVE_UNACK]
        if not active:
            return
        best = min(a.priority for a in active)
        urgent = [a for a in active if a.priority == best]
        self.checks["urgent-alarm"] += len(urgent)
        main = app.screen_stack[0]
        listing = main.query_one(AlarmList)
        # the whole widget, border included: render_lines crops from its outer top-left,
        # so its content's size would cut the last rows off (a list of one row, whose
        # border takes 2 of its 3 lines, read as its top border only)
        outer = listing.outer_size
        if not outer.width:
            return
        lines = [strip.text for strip in listing.render_lines(
            Region(0, 0, outer.width, outer.height))]
        rows = rows_for_height(app.size.height)
        keys = [a.key for a in alarms]
        selected = keys.index(listing.selected) if listing.selected in keys else 0
        # the selection keeps a row: below the urgent ones it gets a row of its own, among
        # them but past the rows it takes the last pinned one
        room = rows - 1 if rows <= selected < len(urgent) else rows
        seen = [a for a in urgent if any(_row_shows(line, a) for line in lines)]
        if len(seen) < min(len(urgent), room):
            missing = [a.text for a in urgent if a not in seen]
            self._break("urgent-alarm-hidden",
                        f"{len(urgent)} P{best} unacknowledged, {len(seen)} on screen at "
                        f"{app.size.width}×{app.size.height}; not shown: {missing[:3]}")
        status = main.query_one(StatusBar)
        line = status.render_lines(Region(0, 0, status.size.width, 1))[0].text
        if f"{len(urgent)} P{best} unack" not in line:
            self._break("urgent-count", f"{len(urgent)} P{best} unacknowledged, status bar: "
                        f"{line.rstrip()!r}")

    def _check_dialogs(self) -> None:
        """Over a dialog, the status bar and the banners are still on screen: nothing the
        dialog draws starts above their last line, and the dialog's screen is not opaque."""
        app = self.app
        stack = app.screen_stack
        if len(stack) < 2:
            return
        main = stack[0]
        clear = max((w.region.bottom for w in main.query("#status, #banners") if w.display),
                    default=0)
        for screen in stack[1:]:
            self.checks["dialog"] += 1
            name = type(screen).__name__
            if screen.styles.background.a >= 1:
                self._break("dialog-hides-status-bar", f"{name} is opaque: the cell, its "
                            "status bar and banners are hidden")
                continue
            for child in screen.children:
                region = child.region
                if region.height and region.y < clear:
                    self._break("dialog-hides-status-bar",
                                f"{name} starts at line {region.y}, over the status bar and "
                                f"banners (lines 0-{clear - 1}) at {app.size.width}×"
                                f"{app.size.height}")

    def _check_manual_outcome(self, entry: Entry) -> None:
        """A manual request's outcome in the journal never says "as requested" of a value
        other than the one requested (`manual O on: filter result` / `written 0 as
        requested` was journalled when the mode changed before the scan, or the device was
        stopped)."""
        asked = MANUAL_RESULT.fullmatch(entry["event"])
        said = AS_REQUESTED.fullmatch(str(entry.get("message", "")))
        if asked and said and int(said[1]) != (asked[2] == "on"):
            self._break("journal-manual-outcome",
                        f"line {self.journal_lines}: {entry['event']!r} says "
                        f"{entry['message']!r} (scan {entry.get('scan')})")

    def check_journal(self) -> None:
        with self.journal_path.open("rb") as f:
            f.seek(self._journal_at)
            data = f.read()
        self._journal_at += len(data)
        data = self._partial + data
        lines = data.split(b"\n")
        self._partial = lines.pop()  # after the last newline: not a whole line yet
        for line in lines:
            self.journal_lines += 1
            try:
                entry = json.loads(line)
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                self._break("journal-line", f"line {self.journal_lines} does not parse: {exc}")
                continue
            if not isinstance(entry, dict) or not {"type", "event", "wall"} <= entry.keys():
                self._break("journal-line", f"line {self.journal_lines} is not an entry: "
                            f"{line[:120]!r}")
                continue
            if entry["type"] == "action" and str(entry["event"]).endswith(": filter result"):
                self._check_manual_outcome(entry)
            if entry["type"] == "alarm":
                pending = self.expected.get(entry.get("key", ""))
                if pending and pending[0][0] == entry.get("state"):
                    pending.popleft()
        for key, pending in self.expected.items():
            if pending:
                state, scan = pending[0]
                self._break("transition-not-journalled",
                            f"{key} became {state} at scan {scan}; no journal entry says so")
                pending.clear()


def _squeezed(text: str) -> str:
    return re.sub(r"[\s:]+", "", text)


def _row_shows(line: str, alarm: Alarm) -> bool:
    """Whether an alarm list line is this alarm's row: its priority, the time it was raised,
    then the start of its text as the row fits it, the text cut with "…" at a narrow width
    (compared without spaces and colons). From 110 columns the device has a column of its
    own (cut to its width) and the text then leaves out a leading device name; a text that
    does not start with it ("Cell: stopped safe" of the device "cispi_valve") is whole."""
    from hmi.ui.alarm_list import DEVICE_W, without_device
    stamp = f"P{alarm.priority} "
    raised = f"{seconds(alarm.raised_us)} s  "
    start = line.find(stamp)
    at = line.find(raised, start) if start >= 0 else -1
    if at < 0:
        return False
    rest, text = line[at + len(raised):].lstrip(), alarm.text
    column = alarm.device[:DEVICE_W]
    if column and rest.startswith(column + " "):
        rest, text = rest[len(column):].lstrip(), without_device(alarm.text, alarm.device)
    shown = _squeezed(rest.split("…")[0].split("  ")[0])
    return bool(shown) and _squeezed(text).startswith(shown[:40])

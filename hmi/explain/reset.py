"""What a fault reset would do, read from a snapshot: the lines its confirmation shows.

A reset releases what is latched — the safe-state latch, monitor labels, latched diagnoser
states, and with them their latched alarms — but a latch whose cause is still present comes
straight back at the next scan (or, for a monitor, is not released at all). The dialog says
which is which, so the operator does not reset in a loop without understanding why nothing
changes. It also names what a reset does *not* touch although the operator may expect it
to: devices the operator stopped (released from the palette).

Each feature that latches something adds a *preview* function to :data:`PREVIEWS`; the
dialog shows the lines of all of them, then those of the latched alarms (:func:`alarm_preview`
reads the session's alarm list, which the snapshot does not carry) and of the stopped
devices. A preview only reads the snapshot.

The cell keeps running while the dialog is open, so what the operator read can stop being
true before they confirm (a valve moving on: the diagnoser would now re-synchronise to
another state, or not at all). :func:`changes` compares what was shown with what the reset
would do now; the runtime checks it when the confirmed reset arrives, under the session's
lock (no scan between the check and the reset), and if anything changed does nothing,
journals why (:func:`declined_message`) and the screen asks again (hmi.ui.reset).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from hmi.engine.monitors import MonitorState
from hmi.engine.snapshot import LatchReason, Snapshot
from hmi.explain.alarms import Alarm
from hmi.explain.plain import latch_words, lower_first, without_notes
from hmi.timefmt import seconds

OK_SYMBOL = "✓"  # the reset releases it
STAYS = "▲ stays"  # it stays (an attention word: symbol and word)


@dataclass(frozen=True)
class ResetLine:
    what: str  # the thing latched, in the operator's words
    resets: bool  # True: the reset releases it; False: it stays (its cause is present)
    why: str = ""  # for a line that stays: why (its cause still present...)
    note: str = ""  # anything else the operator should know about it
    recovery: str = ""  # the recovery procedure that would let it reset (offered)
    target: str = ""  # a diagnoser's: the normal state the reset re-synchronises it to
    # The engineering detail: the model's names (diagnoser state and labels, monitor label,
    # constraints, the I/O values a resync reads), shown after the plain words in the
    # engineering view only.
    detail: str = ""

    @property
    def promise(self) -> tuple[str, bool, str, str]:
        """What this line promises the operator: the thing, whether it is released, where a
        diagnoser goes, the recovery offered; not the figures that move while none of that
        changes (a running task's x, the values a resync reads, which constraint is violated
        now)."""
        return self.what, self.resets, self.target, self.recovery


ResetPreview = Callable[[Snapshot], Iterable[ResetLine]]


def _latch_cause_present(snap: Snapshot, reason: LatchReason) -> str:
    if reason.source == "plant" and not snap.plant.connected:
        return "the plant is still disconnected" + (
            f" ({snap.plant.message})" if snap.plant.message else "")
    if reason.source == "filter":
        report = snap.filter_report
        violations = tuple(getattr(report, "violations", ()) or ()) if report else ()
        if violations:
            rules = "; ".join(dict.fromkeys(lower_first(v.description or v.name)
                                            for v in violations))
            return f"the program still asks for what a safety rule forbids: {rules}"
    return ""


def _violated_names(snap: Snapshot) -> str:
    report = snap.filter_report
    return ", ".join(getattr(report, "violated_names", ()) or ()) if report else ""


def latch_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for reason in snap.latched:
        what = f"outputs held safe: {latch_words(reason)}"
        cause = _latch_cause_present(snap, reason)
        names = _violated_names(snap) if cause and reason.source == "filter" else ""
        yield ResetLine(what, resets=not cause,
                        why=f"its cause is still present: {cause}" if cause else "",
                        detail=f"safe-state latch ({reason.source}): {reason.detail}"
                               + (f"; still violated: {names}" if names else ""))


def _condemned(m: MonitorState) -> bool:
    """A monitor whose latched fault a reset cannot release: the condemned attempt still runs
    (hmi.engine.stopwatch.TaskAutomaton.reset; x - y never decreases within an attempt)."""
    return bool(m.running and m.last_detection is not None
                and m.last_detection.attempt == m.attempt)


def monitor_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for m in snap.monitors:
        d = m.detection
        if d is None:
            continue
        what = f"{m.title}: fault seen at {seconds(d.time_us)} s"
        detail = f"monitor label {m.label} ({d.rule}, x = {seconds(d.x_us)} s)"
        if _condemned(m):
            yield ResetLine(what, resets=False,
                            why=f"the task is still in progress ({seconds(m.x_us)} s of work "
                                "so far) and can no longer end in time; reset again once it "
                                "has ended", detail=detail)
        else:
            yield ResetLine(what, resets=True, detail=detail)


def diagnoser_preview(snap: Snapshot) -> Iterable[ResetLine]:
    """Faulty diagnosers: a reset re-synchronises one when the I/O matches a normal state
    (the engine says which, per scan: DiagnoserState.resync), else the fault stays."""
    for d in snap.diagnosers:
        if not d.faulty:
            continue
        device = d.device or "the device"
        suspected = " or ".join(dict.fromkeys(without_notes(t) for t in d.label_texts if t))
        what = (f"{device}'s diagnosis: {suspected or 'a fault'} (since "
                f"{seconds(d.since_us)} s)")
        state = f"diagnoser {d.name} in {d.state} {{{', '.join(d.labels)}}} and its flags"
        if d.resync:
            yield ResetLine(what, resets=True, target=d.resync,
                            note="its watch starts again from what the I/O show now: "
                                 f"{d.resync_values}",
                            detail=f"{state}; re-synchronised to {d.resync} on "
                                   f"{d.resync_values}")
            continue
        detail = f"{state}; {d.resync_values or 'the I/O'} match no normal state"
        moving = _orders_on(snap, d.resync_values)
        procedures = [p for p in snap.recovery.procedures if d.device in p[3]]
        if moving:
            # Between its ends because it is travelling (a switch seen too early, F7): it
            # reaches its end by itself, and a reset then re-synchronises; no recovery.
            yield ResetLine(what, resets=False,
                            why=f"{device} is still driven (order "
                                f"{', '.join(moving)} on): wait until it reaches its end, "
                                "seconds if it moves, then reset again — no recovery for "
                                "that", detail=detail)
        elif procedures and snap.mode != "recovery":
            name, _, description, _ = procedures[0]
            yield ResetLine(what, resets=False,
                            why=f"reset needs {device} back at a known position (its sensors "
                                "and orders match none it knows) — "
                                + _then_recovery(snap, "after the repair, ", description),
                            recovery=_offered(snap, name), detail=detail)
        else:
            yield ResetLine(what, resets=False,
                            why="its cause is still present: the sensors and orders match "
                                "no normal position; reset once the device is repaired or "
                                "back at rest", detail=detail)


def recovery_preview(snap: Snapshot) -> Iterable[ResetLine]:
    """What the cell needs a recovery for: a reset does not move a device back."""
    if snap.mode == "recovery":
        state = snap.recovery
        if state.status == "running":
            yield ResetLine(f"recovery running: {state.description}", resets=False,
                            why="a reset does not stop it; leave recovery to stop it")
        return
    for name, device, description, text in snap.recovery.needed:
        yield ResetLine(f"{device}: {text}", resets=False,
                        why="a reset does not move it back — " + _then_recovery(
                            snap, "", description), recovery=_offered(snap, name))


def _orders_on(snap: Snapshot, values: str) -> list[str]:
    """The device's orders written on at this scan, of the I/O a diagnoser's resync reads
    (`values`: 'fsc=1, fso=0, C=1, O=0')."""
    written = snap.output_map
    names = [part.partition("=")[0].strip() for part in values.split(",")]
    return [n for n in names if written.get(n)]


def _offered(snap: Snapshot, name: str) -> str:
    """The recovery the dialog offers (its `g`): none while the outputs are held safe — the
    engine starts no recovery under a safe-state latch, so the reset comes first."""
    return "" if snap.latched else name


def _then_recovery(snap: Snapshot, first: str, description: str) -> str:
    if snap.latched:
        return (f"{first}this reset first (the outputs are held safe: no recovery starts "
                f"meanwhile), then start the recovery \u201c{description}\u201d")
    return f"{first}start the recovery \u201c{description}\u201d"


def _alarm_released(snap: Snapshot, key: str) -> bool | None:
    """Whether a reset removes the cause of a latched alarm (None: not known here)."""
    kind, _, name = key.partition(":")
    if kind == "safe_state":  # (safe_state:SOURCE, or safe_state:SOURCE:N for the Nth)
        source = name.partition(":")[0]
        return not any(_latch_cause_present(snap, r) for r in snap.latched
                       if r.source == source)
    if kind == "monitor":
        return not any(_condemned(m) for m in snap.monitors if m.name == name)
    if kind == "diagnosis":
        return all(bool(d.resync) for d in snap.diagnosers if d.name == name and d.faulty)
    return None


def alarm_preview(snap: Snapshot, alarms: tuple[Alarm, ...]) -> Iterable[ResetLine]:
    """Latched alarms (of the alarm list `alarms`) clear with what latched them; they stay
    listed until acknowledged."""
    latched = [a for a in alarms if a.latched and a.active]
    released = [a for a in latched if _alarm_released(snap, a.key) is not False]
    kept = len(latched) - len(released)
    if released:
        n = len(released)
        words = "latched alarm clears with its latch" if n == 1 else \
            "latched alarms clear with their latches"
        yield ResetLine(f"{n} {words}", resets=True,
                        note="listed, cleared, until acknowledged")
    if kept:
        yield ResetLine(f"{kept} latched alarm{'s' if kept != 1 else ''}", resets=False,
                        why=f"what latched {'them' if kept != 1 else 'it'} stays (see above)")


def stopped_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for device in snap.stopped_devices:
        yield ResetLine(f"{device} stopped by the operator", resets=False,
                        note="a fault reset does not release a stopped device: ctrl+p, "
                             f"Release device {device}")


PREVIEWS: list[ResetPreview] = [latch_preview, diagnoser_preview, monitor_preview,
                                 recovery_preview]


def reset_preview(snap: Snapshot, alarms: tuple[Alarm, ...] = ()) -> list[ResetLine]:
    """Every line the registered previews give for this snapshot; then the latched alarms
    of the alarm list `alarms` (they clear with those latches, so they follow them) and the
    devices the operator stopped (a reset never releases them); resets first."""
    lines = [line for preview in PREVIEWS for line in preview(snap)]
    lines += alarm_preview(snap, alarms)
    lines += stopped_preview(snap)
    return sorted(lines, key=lambda line: not line.resets)


def changes(shown: list[ResetLine], now: list[ResetLine]
            ) -> tuple[list[ResetLine], list[ResetLine]]:
    """What the operator was shown that no longer holds, and what holds now that they were
    not shown (each by its promise; both empty: the reset does what they read)."""
    before = {line.promise for line in shown}
    after = {line.promise for line in now}
    return ([line for line in shown if line.promise not in after],
            [line for line in now if line.promise not in before])


def line_text(line: ResetLine, detail: bool = False) -> str:
    """One line of the fault reset dialog in plain words (the screen styles the same words:
    hmi.ui.reset.reset_line): will be reset, or stays and why; `detail`: with the model's
    names after them (the journal's)."""
    if line.resets:
        text = f"{OK_SYMBOL} will be reset: {line.what}"
    else:
        text = f"{STAYS}: {line.what}" + (f" — {line.why}" if line.why else "")
    return text + (f" ({line.note})" if line.note else "") + (
        f" [{line.detail}]" if detail and line.detail else "")


def declined_message(gone: list[ResetLine], new: list[ResetLine], seen_scan: int,
                     scan: int) -> str:
    """Why a confirmed fault reset was not carried out: what the operator read (as of
    `seen_scan`) no longer holds at `scan` (the journal's action entry, the screen's line)."""
    told = "; ".join([*(f"was: {line_text(line, True)}" for line in gone),
                      *(f"now: {line_text(line, True)}" for line in new)])
    return (f"not done, asked again: what it would do changed while its dialog was open "
            f"(scan {seen_scan} to {scan}): {told}")

"""What a fault reset would do, shown in its confirmation dialog before the operator agrees.

A reset releases what is latched — the safe-state latch, monitor labels, latched diagnoser
states, and with them their latched alarms — but a latch whose cause is still present comes
straight back at the next scan (or, for a monitor, is not released at all). The dialog says
which is which, so the operator does not reset in a loop without understanding why nothing
changes. It also names what a reset does *not* touch although the operator may expect it
to: devices the operator stopped (released from the palette).

Each feature that latches something adds a *preview* function to :data:`PREVIEWS`; the
dialog shows the lines of all of them. A preview only reads the snapshot.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from hmi.engine.snapshot import LatchReason, Snapshot
from hmi.timefmt import seconds


@dataclass(frozen=True)
class ResetLine:
    what: str  # the thing latched, in the operator's words
    resets: bool  # True: the reset releases it; False: it stays (its cause is present)
    why: str = ""  # for a line that stays: why (its cause still present...)
    note: str = ""  # anything else the operator should know about it


ResetPreview = Callable[[Snapshot], Iterable[ResetLine]]


def _latch_cause_present(snap: Snapshot, reason: LatchReason) -> str:
    if reason.source == "plant" and not snap.plant.connected:
        return "the plant is still disconnected" + (
            f" ({snap.plant.message})" if snap.plant.message else "")
    if reason.source == "filter":
        report = snap.filter
        violated = tuple(getattr(report, "violated_names", ()) or ()) if report else ()
        if violated:
            return "constraint still violated by the program's orders: " + ", ".join(violated)
    return ""


def latch_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for reason in snap.latched:
        what = f"safe-state latch ({reason.source}): {reason.detail}"
        cause = _latch_cause_present(snap, reason)
        yield ResetLine(what, resets=not cause,
                        why=f"its cause is still present: {cause}" if cause else "")


def _condemned(m) -> bool:
    """A monitor whose latched fault a reset cannot release: the condemned attempt still runs
    (hmi.engine.stopwatch.TaskAutomaton.reset; x - y never decreases within an attempt)."""
    return bool(m.running and m.last_detection is not None
                and m.last_detection.attempt == m.attempt)


def monitor_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for m in snap.monitors:
        d = m.detection
        if d is None:
            continue
        what = f"monitor label {m.label} ({m.title}, since {seconds(d.time_us)} s)"
        if _condemned(m):
            yield ResetLine(what, resets=False,
                            why=f"the task is still in progress (x = {seconds(m.x_us)} s) and "
                                "can no longer end in time; reset again once it has ended")
        else:
            yield ResetLine(what, resets=True)


def diagnoser_preview(snap: Snapshot) -> Iterable[ResetLine]:
    """Faulty diagnosers: a reset re-synchronises one when the I/O matches a normal state
    (the engine says which, per scan: DiagnoserState.resync), else the fault stays."""
    for d in snap.diagnosers:
        if not d.faulty:
            continue
        what = (f"diagnoser {d.name} in {d.state} {{{', '.join(d.labels)}}} and its flags "
                f"(since {seconds(d.since_us)} s)")
        if d.resync:
            yield ResetLine(what, resets=True,
                            note=f"re-synchronised to {d.resync} on {d.resync_values}")
        else:
            yield ResetLine(what, resets=False,
                            why=f"its cause is still present: {d.resync_values or 'the I/O'} "
                                "match no normal state; reset once the device is repaired or "
                                "back at rest")


def _alarm_released(snap: Snapshot, key: str) -> bool | None:
    """Whether a reset removes the cause of a latched alarm (None: not known here)."""
    kind, _, name = key.partition(":")
    if kind == "safe_state":
        return not any(_latch_cause_present(snap, r) for r in snap.latched if r.source == name)
    if kind == "monitor":
        return not any(_condemned(m) for m in snap.monitors if m.name == name)
    if kind == "diagnosis":
        return all(bool(d.resync) for d in snap.diagnosers if d.name == name and d.faulty)
    return None


def alarm_preview(snap: Snapshot) -> Iterable[ResetLine]:
    """Latched alarms clear with what latched them; they stay listed until acknowledged."""
    latched = [a for a in snap.alarms if getattr(a, "latched", False) and a.active]
    released = [a for a in latched if _alarm_released(snap, a.key) is not False]
    kept = len(latched) - len(released)
    if released:
        n = len(released)
        yield ResetLine(f"{n} latched alarm{'s' if n != 1 else ''} clear with their latch",
                        resets=True, note="listed, cleared, until acknowledged")
    if kept:
        yield ResetLine(f"{kept} latched alarm{'s' if kept != 1 else ''}", resets=False,
                        why=f"what latched {'them' if kept != 1 else 'it'} stays (see above)")


def stopped_preview(snap: Snapshot) -> Iterable[ResetLine]:
    for device in snap.stopped_devices:
        yield ResetLine(f"{device} stopped by the operator", resets=False,
                        note="a fault reset does not release a stopped device: ctrl+p, "
                             f"Release device {device}")


PREVIEWS: list[ResetPreview] = [latch_preview, diagnoser_preview, monitor_preview,
                                 alarm_preview, stopped_preview]


def reset_preview(snap: Snapshot) -> list[ResetLine]:
    """Every line the registered previews give for this snapshot, resets first."""
    lines = [line for preview in PREVIEWS for line in preview(snap)]
    return sorted(lines, key=lambda line: not line.resets)

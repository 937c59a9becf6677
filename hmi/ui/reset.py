"""What a fault reset would do, shown in its confirmation dialog before the operator agrees.

A reset releases what is latched — the safe-state latch today; latched diagnoser states and
alarms once those features exist — but a latch whose cause is still present comes straight
back at the next scan. The dialog says which is which, so the operator does not reset in a
loop without understanding why nothing changes.

Each feature that latches something adds a *preview* function to :data:`PREVIEWS`; the
dialog shows the lines of all of them. A preview only reads the snapshot.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from hmi.engine.snapshot import LatchReason, Snapshot


@dataclass(frozen=True)
class ResetLine:
    what: str  # the thing latched, in the operator's words
    resets: bool  # True: the reset releases it; False: it stays (its cause is present)
    why: str = ""  # for a line that stays: the cause still present


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
        yield ResetLine(what, resets=not cause, why=cause)


PREVIEWS: list[ResetPreview] = [latch_preview]


def reset_preview(snap: Snapshot) -> list[ResetLine]:
    """Every line the registered previews give for this snapshot, resets first."""
    lines = [line for preview in PREVIEWS for line in preview(snap)]
    return sorted(lines, key=lambda line: not line.resets)

"""One scan as the session hands it out: the engine's snapshot and what the session made of it.

The engine knows nothing of explanations and alarms (hmi.explain sits above it): its
:class:`~hmi.engine.snapshot.Snapshot` is what the scan did. The session explains that
snapshot, updates the alarm list with it, and hands both out together as a
:class:`CellView` — what the screens, the journal, the history, OPC UA and the soak's
invariants read. A NamedTuple, like the snapshot, because one is built every scan.
"""

from __future__ import annotations

from typing import NamedTuple

from hmi.engine.snapshot import Snapshot
from hmi.explain.alarms import Alarm, AlarmEvent, Shelf
from hmi.explain.model import Explanation


class CellView(NamedTuple):
    """The engine's snapshot of one scan, explained, with the alarm list it left."""

    snapshot: Snapshot
    explanations: tuple[Explanation, ...] = ()
    alarms: tuple[Alarm, ...] = ()  # the alarm list, in the order the operator sees it
    alarm_events: tuple[AlarmEvent, ...] = ()  # alarm transitions during this scan
    shelved: tuple[tuple[Alarm, Shelf], ...] = ()  # the alarms shelved, not listed
    # Explaining the scan failed (the scan went on without explanations): why.
    explain_error: str | None = None
    explain_wall_us: float = 0.0  # the time explaining took (measured, not deterministic)

    @property
    def error(self) -> str | None:
        """An internal error caught during this scan: the engine's, else the explanations'."""
        return self.snapshot.error or self.explain_error

    @property
    def scan_wall_us(self) -> float:
        """The scan's wall time, explaining it included (measured, not deterministic)."""
        return self.snapshot.scan_wall_us + self.explain_wall_us

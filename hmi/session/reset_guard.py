"""A confirmed fault reset, carried out only if it still does what its dialog showed.

The cell keeps running while the operator reads the fault reset dialog
(hmi.explain.reset): what they read can stop being true before they confirm. Every place
that takes a confirmed reset — the runtime's hub for screens over the socket, the link on a
session in this process — checks it here, under the session's lock, so no scan comes between
the check and the reset.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from hmi.engine.commands import Command, CommandResult
from hmi.explain.reset import ResetLine, changes, declined_message, reset_preview
from hmi.session.session import Session


def command_as_shown(session: Session, command: Command, shown: Iterable[ResetLine],
                     seen_scan: int, origin: str = "",
                     details: Mapping[str, str] | None = None) -> tuple[CommandResult, bool]:
    """`command`, confirmed on a dialog that showed `shown` as of scan `seen_scan`: carried
    out if a reset now would do the same, else declined with what changed (journalled like
    any command). The result, and whether it was declined."""
    with session.lock:  # no scan between the check and the command
        now = session.last
        gone, new = changes(list(shown),
                            reset_preview(now.snapshot, now.alarms) if now else [])
        if not gone and not new:
            return session.command(command, origin, details), False
        scan = now.snapshot.scan if now is not None else seen_scan
        why = declined_message(gone, new, seen_scan, scan)
        return session.decline(command, why, origin, details), True

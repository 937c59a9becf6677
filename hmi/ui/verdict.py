"""Why a written output differs from what was asked: the functional value or a manual request.

The operator must see at once when an order was not written as asked, and why. Today two
things can change an output between the control law (or the operator's request) and the
plant: the safe-state latch (every output to its safe value until a fault reset) and the
safety filter's report, when the filter stage fills one in. Later features (masked
actuators) add their reasons here rather than in the widgets.
"""

from __future__ import annotations

from hmi.engine.snapshot import Snapshot


def _filter_changes(snap: Snapshot) -> dict[str, str]:
    """Outputs the filter changed, with the constraint that changed each (if reported)."""
    report = snap.filter
    if report is None:
        return {}
    changes = getattr(report, "changes", None) or ()
    out: dict[str, str] = {}
    for change in changes:
        name = getattr(change, "output", None) or getattr(change, "name", None)
        if name is None and isinstance(change, tuple) and change:
            name = change[0]
        if name is None:
            continue
        by = getattr(change, "constraint", None) or getattr(change, "constraints", None)
        if isinstance(by, tuple | list):
            by = ", ".join(str(b) for b in by)
        out[str(name)] = f"filter: {by}" if by else "filter"
    return out


def output_changes(snap: Snapshot) -> dict[str, str]:
    """Output name -> a short reason, for every output whose written value is not its FOV."""
    reasons = _filter_changes(snap)
    out: dict[str, str] = {}
    masked = set(snap.masked)
    for name, fov, written in zip(snap.layout.outputs, snap.fov, snap.outputs, strict=True):
        if fov == written:
            continue
        if name in reasons:
            out[name] = reasons[name]
        elif snap.latched:
            out[name] = "held safe: " + snap.latched[0].detail
        elif name in masked:
            out[name] = "masked: actuator flagged faulty"
        else:
            out[name] = "changed by the output stage"
    return out


def request_verdict(snap: Snapshot, name: str, requested: bool) -> tuple[bool, str]:
    """(written as requested?, one line) for a manual request, judged on a later scan."""
    written = snap.output_map[name]
    word = "on" if requested else "off"
    if written == requested:
        return True, f"{name} {word}: written {int(written)} at scan {snap.scan}"
    why = output_changes(snap).get(name, "changed by the output stage")
    return False, (f"{name} requested {word}, written {int(written)} at scan {snap.scan} "
                   f"— {why}")

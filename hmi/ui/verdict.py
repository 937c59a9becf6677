"""Why a written output differs from what was asked: the functional value or a manual request.

The operator must see at once when an order was not written as asked, and why. Three things
can change an output between the control law (or the operator's request) and the plant: the
safety filter (its report names the constraints behind each change), the safe-state latch
(every output to its safe value until a fault reset), and a masked actuator. (A device the
operator stopped is held safe before the filter: its FOV already shows it.) The
widgets ask here rather than reading the report themselves, so the wording is the same on
the I/O table, the chronogram and the message line.
"""

from __future__ import annotations

from hmi.engine.snapshot import Snapshot
from hmi.explain.plain import latch_words, lower_first

HOW_WORDS = {
    "F0": "forced 0",
    "F1": "forced 1",
    "combined": "combined repair",
    "safe state": "safe state",
}


def filter_changes(snap: Snapshot, engineering: bool = True,
                   rules: bool = False) -> dict[str, str]:
    """Outputs the filter changed this scan -> "filter CSs2, CSs6 (forced 0)" (engineering
    view), "safety filter (forced 0)" in the operator's (`rules`: followed by the rules'
    descriptions, where there is room: the message line)."""
    report = snap.filter_report
    if report is None:
        return {}
    described = {v.name: v.description for v in report.violations}
    out: dict[str, str] = {}
    for change in report.changes:
        how = HOW_WORDS.get(change.how, change.how)
        by = ", ".join(b for b in change.by if b != "safe state")
        if change.how == "safe state":
            out[change.output] = f"safe state ({report.note})" if report.note else "safe state"
        elif change.how == "masked":  # a diagnoser's flag, not a constraint
            out[change.output] = (f"masked ({by})" if by else "masked") if engineering \
                else "masked: the diagnosis suspects the device"
        elif engineering:
            out[change.output] = f"filter {by} ({how})" if by else f"filter ({how})"
        else:
            said = "; ".join(dict.fromkeys(lower_first(described[b]) for b in change.by
                                           if described.get(b)))
            out[change.output] = f"safety filter ({how})" + (f": {said}" if rules and said
                                                              else "")
    return out


def output_changes(snap: Snapshot, engineering: bool = True,
                   rules: bool = False) -> dict[str, str]:
    """Output name -> a short reason, for every output whose written value is not its FOV
    (in the model's names in the engineering view, else in words)."""
    reasons = filter_changes(snap, engineering, rules)
    out: dict[str, str] = {}
    masked = set(snap.masked)
    for name, fov, written in zip(snap.layout.outputs, snap.fov, snap.outputs, strict=True):
        if fov == written:
            continue
        if snap.latched:
            out[name] = "held safe: " + (snap.latched[0].detail if engineering
                                         else latch_words(snap.latched[0]))
        elif name in reasons:
            out[name] = reasons[name]
        elif name in masked:
            out[name] = "masked: actuator flagged faulty"
        else:
            out[name] = "changed by the output stage"
    return out


def request_verdict(snap: Snapshot, name: str, requested: bool,
                    device: str | None = None, engineering: bool = True
                    ) -> tuple[bool, str]:
    """(written as requested?, one line) for a manual request, judged on a later scan;
    `device` is the output's (a device the operator stopped holds it safe before the filter:
    its FOV is already the safe value, so no change below says why)."""
    written = snap.output_map[name]
    word = "on" if requested else "off"
    if written == requested:
        return True, f"{name} {word}: written {int(written)} at scan {snap.scan}"
    why = output_changes(snap, engineering, rules=True).get(name)
    if why is None:
        why = (f"{device} stopped by the operator" if device in snap.stopped_devices
               else "changed by the output stage")
    return False, (f"{name} requested {word}, written {int(written)} at scan {snap.scan} "
                   f"— {why}")

"""A device's own fault signal (an input declared `fault: true`, e.g. a drive fault relay).

When the device says it is halted by a malfunction, that is the root cause of whatever it
then fails to do: its task runs late, the program waits for it. So the input raises its own
alarm, high, naming the device, with a check of the device recommended — never "continue":
a halted drive does not finish its task by itself. Key ``fault:<input>``; it clears when the
input returns to 0 (the device tells when it runs again). A project's
`explanations: situations: fault_<input>:` texts replace any level.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

from hmi.explain.context import Levels
from hmi.explain.model import Explanation, Policy
from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.context import ExplanationContext


def halted_devices(builder: ExplanationContext, snap: Snapshot) -> set[str]:
    """The devices whose fault signal is on at this scan."""
    return {builder.devices[name] for name in builder.fault_inputs if snap.value(name)}


def device_fault_explanations(builder: ExplanationContext, snap: Snapshot) -> list[Explanation]:
    out: list[Explanation] = []
    for name in builder.fault_inputs:
        if not snap.value(name):
            continue
        key = f"fault:{name}"
        onset = builder.onset(key, snap)
        out.append(builder.cached(key, (onset.scan,), partial(
            _explain, builder, snap, name, onset.scan, onset.time_us)))
    return out


def _explain(builder: ExplanationContext, snap: Snapshot, name: str, scan: int,
             time_us: int) -> Explanation:
    device = builder.devices[name]
    said = builder.plain.name(name)
    what = f"{device}: {said} — it does not move"
    why = (f"{device} has reported since {seconds(time_us)} s that it is {said}: its own "
           "fault signal is on.")
    consequences = (f"{device} stands where it stopped, with whatever it carries; every task "
                    f"of {device} and every step of the program waiting for it waits too. "
                    "Nothing restarts it by itself: the program's orders do not clear a "
                    "drive fault. The alarm clears when the device reports it runs again.")
    policies = [Policy("check", f"Check {device}",
                       f"find out why {device} halted (a jam, an overload, a tripped drive), "
                       "clear it and reset the drive; the cycle resumes when it moves",
                       None, True)]
    if device in builder.stoppable:
        policies.append(builder.policy_stop(device))
    detail = (f"Fault input {name} = 1 ({builder.describe(name)}) since scan {scan} "
              f"({seconds(time_us)} s).")
    defaults = Levels(what=what, why=why, consequences=consequences,
                      policies=tuple(policies), severity="high", alarm=True, detail=detail)
    fields = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(time_us), "since_scan": scan,
              "action": "none (the device stopped itself)", "reason": said, "detail": detail}
    level = builder.apply_texts(builder.texts.get("situations", f"fault_{name}"), defaults,
                                fields)
    return Explanation(f"fault:{name}", "device_fault", level.severity, device,
                       level.what, level.why, level.consequences, level.policies,
                       scan, time_us, level.alarm, detail=level.detail)

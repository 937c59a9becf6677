"""Graduated explanations of stopwatch monitor faults (002), for the explanation builder.

One explanation per latched monitor label, key ``monitor:<task>``: what (the task and the
rule, in plain words), why (the stopwatch values at detection and the rule with its
numbers), consequences (what a late task means and that nothing is stopped), policies
(continue, stop the device, fault reset). A project's `explanations: monitors: <task>:` texts
replace any level; their placeholders are those of hmi.project.texts.PLACEHOLDERS.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

from hmi.engine.stopwatch import Detection, Window
from hmi.explain.context import Levels
from hmi.explain.device_faults import halted_devices
from hmi.explain.model import Explanation, Policy
from hmi.explain.plain import lower_first
from hmi.timefmt import format_duration, seconds

if TYPE_CHECKING:
    from hmi.engine.monitors import MonitorState
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.context import ExplanationContext

WHAT = {
    "cannot_finish": "cannot end within its acceptable time",
    "deadline": "still running past its acceptable time",
    "overrun": "working longer than its normal duration",
    "late_end": "ended too late",
    "too_fast": "ended too early",
}

AFTER = {
    "too_fast": "It ended after less work than it ever needs: the job may not have been done "
                "(a missing part, a skipped operation).",
    "overrun": "It does more work than normal: the device may be slowed down (wear, "
               "slipping, an obstacle).",
}


def monitor_explanations(builder: ExplanationContext, snap: Snapshot) -> list[Explanation]:
    """An explanation for each faulty monitor of this scan."""
    out: list[Explanation] = []
    for m in snap.monitors:
        if m.detection is None:
            continue
        key = f"monitor:{m.name}"
        builder.onset(key, snap)  # so the builder forgets it once the label is released
        halted = m.device is not None and m.device in halted_devices(builder, snap)
        out.append(builder.cached(key, (m.detection, m.running, m.attempt, m.location,
                                        m.phase, halted),
                                  partial(_explain, builder, snap, m, m.detection, halted)))
    return out


def plain_reason(d: Detection, m: MonitorState) -> str:
    """The detection in words, with the numbers an operator checks against the task."""
    f = format_duration
    stopped = d.x_us - d.y_us
    if d.rule == "cannot_finish":
        return (f"It started at {seconds(d.attempt_start_us)} s; by {seconds(d.time_us)} s it "
                f"had done {f(d.y_us)} of the {f(m.alpha_us)} of work it needs"
                + (f" and been stopped for {f(stopped)}" if stopped > 0 else "")
                + f": it can no longer end within {f(m.gamma_us)} of its start, the latest "
                "acceptable.")
    if d.rule == "deadline":
        return (f"It started at {seconds(d.attempt_start_us)} s and was still running "
                f"{f(m.gamma_us)} later, the latest acceptable.")
    if d.rule == "overrun":
        return (f"It has worked {f(d.y_us)}, longer than the {f(m.beta_us)} it normally takes, "
                "and is still working.")
    if d.rule == "late_end":
        return f"It ended {f(d.x_us)} after its start, later than the acceptable {f(m.gamma_us)}."
    return (f"It ended after only {f(d.y_us)} of work; it always needs at least "
            f"{f(m.alpha_us)}.")


def _explain(builder: ExplanationContext, snap: Snapshot, m: MonitorState, d: Detection,
             device_halted: bool) -> Explanation:
    """`d`: the monitor's detection (only a monitor with one is explained)."""
    window = Window(m.alpha_us, m.beta_us, m.gamma_us)
    device = m.device or builder.project.name
    a, b, g = (format_duration(v) for v in (m.alpha_us, m.beta_us, m.gamma_us))
    # A task stopped with its load (a conveyor halted with a pallet on it) is not "late": it
    # is a machine standing where it should move. Said so, in alarm colour, with a check;
    # continuing is never advised. The phase, not the location: a latched task's location
    # is "faulty" whatever it does. A device reporting its own fault is halted too.
    halted = m.running and m.attempt == d.attempt and (
        m.phase == "interrupted" or device_halted)
    if halted:
        what = (f"{device}: stopped in the middle of its task — {lower_first(m.title)} "
                "cannot end in time")
    else:
        what = f"{m.title}: {WHAT[d.rule]}"
    why = plain_reason(d, m)
    detail = (f"Stopwatch monitor {m.name} (label {m.label}): at scan {d.scan} "
              f"({seconds(d.time_us)} s), x = {seconds(d.x_us)} s since the task started at "
              f"{seconds(d.attempt_start_us)} s, y = {seconds(d.y_us)} s of effective work: "
              f"{d.explain(window)}. Normal duration [alpha, beta] = [{a}, {b}], acceptable "
              f"[alpha, gamma] = [{a}, {g}] (002).")
    if halted:
        state = (f"{device} is stopped with its load while its task is under way: that is "
                 "abnormal (a jam, an obstacle, a protective stop). Until it moves again the "
                 "cycle waits.")
        reset = ("the label stays while this task is in progress (it can no longer end in "
                 "time); once it has ended, a reset releases it")
    elif m.running and m.attempt == d.attempt:
        state = ("The task is still in progress and will end outside its acceptable duration; "
                 "expect the cycle to run late.")
        reset = ("the label stays while this task is in progress (it can no longer end in "
                 "time); once it has ended, a reset releases it")
    else:
        state = "The task has ended outside its acceptable behaviour."
        reset = "release the label; the monitor watches the next run of the task normally"
    consequences = " ".join(filter(None, (
        state, AFTER.get(d.rule, ""),
        "The monitor stops nothing: the outputs follow the program. The alarm stays until a "
        "fault reset.")))
    policies: list[Policy] = []
    if halted:
        policies.append(Policy("check", f"Check {device}",
                               f"find out why {device} stopped with its load and clear it; "
                               "the task resumes when it moves", None, True))
    policies.append(builder.policy_continue(
        f"let the cell run as it is; the task finishes only once {device} moves again"
        if halted else "let the cell run; the task finishes when it can", not halted))
    if m.device and m.device in builder.stoppable:
        policies.append(builder.policy_stop(m.device))
    policies.append(builder.policy_reset(reset))
    defaults = Levels(what=what, why=why, consequences=consequences,
                      policies=tuple(policies), severity="high" if halted else "medium",
                      alarm=True, detail=detail)
    fields = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(d.time_us), "since_scan": d.scan,
              "action": "none (monitoring only)", "task": m.title, "label": m.label,
              "x": seconds(d.x_us), "y": seconds(d.y_us), "alpha": a, "beta": b, "gamma": g,
              "reason": d.explain(window)}
    level = builder.apply_texts(builder.texts.get("monitors", m.name), defaults, fields)
    return Explanation(f"monitor:{m.name}", "monitor", level.severity, device,
                       level.what, level.why, level.consequences, level.policies,
                       d.scan, d.time_us, level.alarm, latched=True, detail=level.detail)

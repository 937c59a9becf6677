"""Graduated explanations of stopwatch monitor faults (002), for the explanation builder.

One explanation per latched monitor label, key ``monitor:<task>``: what (the task and the
rule, in plain words), why (the stopwatch values at detection and the rule with its
numbers), consequences (what a late task means and that nothing is stopped), policies
(continue, stop the device, fault reset). A project's `explanations: monitors: <task>:` texts
replace any level; their placeholders are those of hmi.project.texts.PLACEHOLDERS.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hmi.engine.stopwatch import Window
from hmi.explain.model import Explanation
from hmi.timefmt import format_duration, seconds

if TYPE_CHECKING:
    from hmi.engine.monitors import MonitorState
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.builder import ExplanationBuilder

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


def monitor_explanations(builder: ExplanationBuilder, snap: Snapshot) -> list[Explanation]:
    """An explanation for each faulty monitor of this scan."""
    out = []
    for m in snap.monitors:
        if m.detection is None:
            continue
        key = f"monitor:{m.name}"
        builder.onset(key, snap)  # so the builder forgets it once the label is released
        out.append(builder.cached(key, (m.detection, m.running, m.attempt),
                                  lambda m=m: _explain(builder, snap, m)))
    return out


def _explain(builder: ExplanationBuilder, snap: Snapshot, m: MonitorState) -> Explanation:
    d = m.detection
    window = Window(m.alpha_us, m.beta_us, m.gamma_us)
    device = m.device or builder.project.name
    a, b, g = (format_duration(v) for v in (m.alpha_us, m.beta_us, m.gamma_us))
    what = f"{m.title}: {WHAT[d.rule]} ({m.label})"
    why = (f"Stopwatch monitor {m.name}: at scan {d.scan} ({seconds(d.time_us)} s), "
           f"x = {seconds(d.x_us)} s since the task started at "
           f"{seconds(d.attempt_start_us)} s, y = {seconds(d.y_us)} s of effective work: "
           f"{d.explain(window)}. Normal duration [{a}, {b}], acceptable [{a}, {g}].")
    if m.running and m.attempt == d.attempt:
        state = ("The task is still in progress and will end outside its acceptable duration; "
                 "expect the cycle to run late.")
        reset = ("the label stays while this task is in progress (it can no longer end in "
                 "time); once it has ended, a reset releases it")
    else:
        state = "The task has ended outside its acceptable behaviour."
        reset = "release the label; the monitor watches the next run of the task normally"
    consequences = " ".join(filter(None, (
        state, AFTER.get(d.rule, ""),
        "The monitor stops nothing: the outputs follow the program. The label stays latched "
        "until a fault reset.")))
    policies = [builder.policy_continue("let the cell run; the task finishes when it can",
                                        True)]
    if m.device and m.device in builder.stoppable:
        policies.append(builder.policy_stop(m.device))
    policies.append(builder.policy_reset(reset))
    defaults = {"what": what, "why": why, "consequences": consequences,
                "policies": tuple(policies), "severity": "medium", "alarm": True}
    fields = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(d.time_us), "since_scan": d.scan,
              "action": "none (monitoring only)", "task": m.title, "label": m.label,
              "x": seconds(d.x_us), "y": seconds(d.y_us), "alpha": a, "beta": b, "gamma": g,
              "reason": d.explain(window)}
    level = builder.apply_texts(builder.texts.get("monitors", m.name), defaults, fields)
    return Explanation(f"monitor:{m.name}", "monitor", level["severity"], device,
                       level["what"], level["why"], level["consequences"], level["policies"],
                       d.scan, d.time_us, level["alarm"], latched=True)

"""Explanations of recovery: a way back that the cell needs, and the one running.

* ``recovery_needed:<procedure>`` — the procedure's `needed` condition has held long enough
  (a valve stopped between its ends): an alarm whose recommended policy starts it.
* ``recovery:<procedure>`` — recovery mode, running or done: no alarm (the RECOVERY banner
  says it), with the way out (leave recovery, fault reset).
* ``recovery_failed:<procedure>`` — the procedure did not end within its timeout: an alarm.

Project texts (`explanations: situations: recovery_needed_<procedure>` ...) replace the
generated sentences.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

from hmi.engine import commands as cmd
from hmi.explain.context import Levels
from hmi.explain.model import Explanation, Policy
from hmi.project.recovery import recoveries_of
from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.context import ExplanationContext, Onset


def start_policy(name: str, description: str, recommended: bool = True) -> Policy:
    """The policy that enters recovery mode and runs procedure `name` (confirmed first)."""
    return Policy("recovery", "Start recovery",
                  f"recovery mode: {description[:1].lower() + description[1:]}; only that "
                  "moves, filtered by its own constraints, the rest of the cell is held safe",
                  cmd.StartRecovery(name), recommended)


def leave_policy(recommended: bool) -> Policy:
    return Policy("leave_recovery", "Leave recovery",
                  "automatic mode again: the control program starts from its initial steps",
                  cmd.EndRecovery(), recommended)


def recovery_explanations(builder: ExplanationContext, snap: Snapshot) -> list[Explanation]:
    state = snap.recovery
    out: list[Explanation] = []
    for name, device, description, text in state.needed:
        if state.active == name and snap.mode == "recovery":
            continue
        key = f"recovery_needed:{name}"
        onset = builder.onset(key, snap)
        out.append(builder.cached(key, (text,), partial(
            _needed, builder, snap, key, name, device, description, text, onset)))
    if state.active is None or snap.mode != "recovery":
        return out
    name = state.active
    key = f"recovery:{name}"
    onset = builder.onset(key, snap)
    out.append(builder.cached(key, (state.status, state.step),
                              partial(_running, builder, snap, key, onset)))
    if state.status == "failed":
        fkey = f"recovery_failed:{name}"
        fonset = builder.onset(fkey, snap)
        out.append(builder.cached(fkey, (state.message,),
                                  partial(_failed, builder, snap, fkey, fonset)))
    return out


def _needed(builder: ExplanationContext, snap: Snapshot, key: str, name: str, device: str,
            description: str, text: str, onset: Onset) -> Explanation:
    what = f"{device}: {text} — recovery needed"
    why = (f"Since {seconds(onset.time_us)} s {text}. From there the control "
           "program cannot bring it back by itself, and the safety rules refuse "
           "the orders that would.")
    consequences = ("The cell cannot go on in automatic operation until the device "
                    f"is back. The recovery \u201c{description}\u201d does that in "
                    "recovery mode: only it moves, still checked by its own safety "
                    "rules. Repair the cause first (a jam, a dead switch), then start "
                    "it; after it, a fault reset and leaving recovery restart the "
                    "cycle.")
    # stop the device if it is one (not "Valves V1 and V2"), and manual mode: each
    # offered once
    stop = (builder.policy_stop(device),) if device in builder.stoppable else ()
    policies = (start_policy(name, description), *stop, builder.policy_manual())
    return _with_texts(builder, snap, key, f"recovery_needed_{name}", device,
                       (what, why, consequences, policies), "medium", True, onset)


def _running(builder: ExplanationContext, snap: Snapshot, key: str,
             onset: Onset) -> Explanation:
    state = snap.recovery
    device = state.device or builder.project.name
    if state.status == "running":
        what = (f"{device}: RECOVERY running — {state.description} (step {state.step} of "
                f"{state.steps}: {state.step_text.lower()})")
        why = (f"The operator started it at {seconds(state.since_us)} s. It ends by itself "
               f"when its last step is reached, or fails after {seconds(state.timeout_us)} s.")
        consequences = ("Only the recovery moves the device; every other output is held safe "
                        "and the control program waits. Its own safety rules still filter "
                        "every order.")
        policies: tuple[Policy, ...] = (leave_policy(False),)
    elif state.status == "done":
        what = f"{device}: recovery done — {state.description}"
        why = f"The recovery {state.message}."
        consequences = ("Every output is held safe. Next: a fault reset (the diagnosis sees "
                        "the device at its initial position), then leave recovery: the "
                        "program starts again from its initial steps.")
        policies = (builder.policy_reset("re-synchronise the diagnosis now that the device "
                                         "is back", True), leave_policy(False))
    else:
        what = f"{device}: recovery stopped — {state.description}"
        why = f"The recovery {state.message}."
        consequences = ("Every output is held safe. Find out why the device did not move "
                        "(still jammed? a dead switch?), then start the recovery again or "
                        "leave recovery.")
        policies = (leave_policy(True),)
    return _with_texts(builder, snap, key, f"recovery_{state.active}", device,
                       (what, why, consequences, policies), "low", False, onset)


def _failed(builder: ExplanationContext, snap: Snapshot, key: str, onset: Onset) -> Explanation:
    state = snap.recovery
    device = state.device or builder.project.name
    name = state.active or ""
    what = f"{device}: recovery failed — {state.description}"
    why = f"The recovery was {state.message}."
    consequences = ("The device did not reach its position in time: it may still be jammed, "
                    "or the switch that ends the recovery does not work. Every output is held "
                    "safe; nothing moves.")
    description = next((p.description for p in recoveries_of(builder.project)
                        if p.name == name), state.description)
    policies = (Policy("check", f"Check {device}",
                       "look at the device and its end switches before trying again", None,
                       True),
                start_policy(name, description, recommended=False),
                leave_policy(False))
    return _with_texts(builder, snap, key, f"recovery_failed_{name}", device,
                       (what, why, consequences, policies), "high", True, onset)


def _detail(builder: ExplanationContext, name: str) -> str:
    """The procedure as the engineer wrote it."""
    spec = next((p for p in recoveries_of(builder.project) if p.name == name), None)
    if spec is None:
        return ""
    steps = "; ".join(f"{k}. do {', '.join(a.output for a in step.actions)} until "
                      f"`{step.until.source}`" for k, step in enumerate(spec.steps, 1))
    own = ", ".join(f"{c.name} `{c.expr.source}`" for c in spec.constraints) or "none"
    return (f"Recovery procedure {spec.name}: {steps}; timeout {seconds(spec.timeout_us)} s; "
            f"relaxes {', '.join(spec.relaxes) or 'nothing'}; its constraints: {own}"
            + (f"; needed when `{spec.needed.when.source}` for "
               f"{seconds(spec.needed.for_us)} s" if spec.needed else "") + ".")


def _with_texts(builder: ExplanationContext, snap: Snapshot, key: str, text_name: str,
                device: str, levels: tuple[str, str, str, tuple[Policy, ...]], severity: str,
                alarm: bool, onset: Onset) -> Explanation:
    what, why, consequences, policies = levels
    name = key.split(":", 1)[1]
    level = builder.apply_texts(
        builder.texts.get("situations", text_name),
        Levels(what=what, why=why, consequences=consequences, policies=policies,
               severity=severity, alarm=alarm, detail=_detail(builder, name)),
        {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
         "since_time": seconds(onset.time_us), "since_scan": onset.scan,
         "action": "recovery", "reason": "recovery", "detail": snap.recovery.message})
    return Explanation(key, "recovery", level.severity, device, level.what,
                       level.why, level.consequences, level.policies, onset.scan,
                       onset.time_us, level.alarm, detail=level.detail)

"""Graduated explanations of local diagnoser decisions (000 §2-3), for the explanation builder.

One explanation per faulty diagnoser, key ``diagnosis:<name>``, latched like the decision
(until a fault reset). A certain decision names the fault; an ambiguous one reads as such —
"fsc stuck at 0, or the valve blocked between its positions" — and recommends checking the
actuator hypothesis first: a blocked valve can be damaged by further orders, a dead switch
cannot. Consequences say what the flags are already doing (a sensor running on its estimate,
orders held at 0). Texts from the project (`explanations: labels:` for a certain label,
`partitions:` for what a flag does) replace the generated ones.

While a sensor partition's flag is set, the degraded mode has its own explanation (key
``reconstruction:<sensor>``, no alarm: the diagnosis already raised one), with the operator's
choices: continue degraded, stop the device, reset after repair. Likewise while an actuator
partition's orders are masked (key ``masked:<partition>``, no alarm): which orders are held at
0, since when, what the cell loses, and the same choices.
"""

from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import TYPE_CHECKING

from hmi.explain.context import Levels
from hmi.explain.model import Explanation, Policy
from hmi.explain.plain import lower_first
from hmi.explain.recovery import start_policy
from hmi.project.recovery import recoveries_of
from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.engine.diagnoser import DiagnoserState
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.context import ExplanationContext, Onset
    from hmi.project.model import DiagnoserSpec, Partition


def diagnosis_explanations(builder: ExplanationContext, snap: Snapshot) -> list[Explanation]:
    """Explanations of faulty diagnosers and of what their flags do (degraded sensors,
    masked orders), from the scan's snapshot."""
    out: list[Explanation] = []
    specs = builder.diagnosers
    for state in snap.diagnosers:
        if not state.faulty:
            continue
        spec = specs[state.name]
        key = f"diagnosis:{state.name}"
        builder.onset(key, snap)
        out.append(builder.cached(
            key, (state.state, state.labels, state.refined_by, snap.masked, snap.policy),
            partial(_diagnosis, builder, snap, spec, state)))
        for partition in spec.partitions:
            if partition.sensor and partition.sensor in snap.reconstructed:
                rkey = f"reconstruction:{partition.sensor}"
                builder.onset(rkey, snap)
                out.append(builder.cached(
                    rkey, (state.labels,),
                    partial(_reconstruction, builder, snap, spec, partition, partition.sensor,
                            state)))
            held = tuple(o for o in partition.actuators if o in snap.masked)
            if held:
                mkey = f"masked:{partition.name}"
                builder.onset(mkey, snap)
                out.append(builder.cached(
                    mkey, (state.labels, held),
                    partial(_masked, builder, snap, spec, partition, state, held)))
    return out


def _effects(builder: ExplanationContext, snap: Snapshot, spec: DiagnoserSpec,
             state: DiagnoserState) -> tuple[list[str], list[str], list[str]]:
    """What the flags are doing: plain sentences, short forms for the first line, and the
    engineering detail (flags, estimates, masks)."""
    masked = set(snap.masked)
    reconstructed = set(snap.reconstructed)
    plain = builder.plain
    device = spec.device or spec.name
    doing: list[str] = []
    short: list[str] = []
    detail: list[str] = []
    for partition in spec.partitions:
        if not set(partition.labels) & set(state.labels):
            continue
        if partition.sensor:
            sensor = plain.name(partition.sensor)
            if partition.sensor in reconstructed:
                estimate = plain.name(partition.estimate) if partition.estimate else \
                    "an estimate"
                doing.append(f"the {sensor} is no longer trusted: the {estimate} is used "
                             "instead")
                short.append(f"{sensor} ignored")
                detail.append(f"{partition.flag} set: {partition.sensor} read from "
                              f"{partition.estimate} ({_described(builder, partition.estimate)})")
            else:
                doing.append(f"the {sensor} is suspected but still read as is (the diagnosis "
                             "only observes in this mode)")
                short.append("observed only")
                detail.append(f"{partition.flag} set, {partition.sensor} not reconstructed "
                              "(diagnosis observed only)")
        if partition.actuators:
            held = [o for o in partition.actuators if o in masked]
            if held:
                doing.append(f"the {plain.orders(held)} {'are' if len(held) > 1 else 'is'} "
                             f"held off: {device} is no longer driven")
                short.append("no longer driven")
                detail.append(f"{partition.flag} masks {', '.join(held)}")
            else:
                why = "monitor policy" if snap.policy == "monitor" else \
                    "diagnosis observed only"
                doing.append(f"its orders are not held off ({why})")
                short.append("still driven")
                detail.append(f"{partition.flag} set, orders not masked ({why})")
    return doing, short, detail


def _is_actuator(spec: DiagnoserSpec, label: str) -> bool:
    partition = spec.partition_of(label)
    return bool(partition and partition.actuators)


def _diagnosis(builder: ExplanationContext, snap: Snapshot, spec: DiagnoserSpec,
               state: DiagnoserState) -> Explanation:
    device = spec.device or builder.project.name
    texts = dict(zip(state.labels, state.label_texts, strict=True))
    certain = state.certain
    doing, short, effects = _effects(builder, snap, spec, state)
    action = "; ".join(doing) if doing else "nothing is changed"
    short_action = ", ".join(dict.fromkeys(short)) or "observed only"
    hypotheses = ", or ".join(f"{texts[lab]}" for lab in state.labels)
    label_list = ", ".join(state.labels)
    since = builder.onsets[f"diagnosis:{spec.name}"]
    what = f"{device}: {hypotheses} — {short_action}"
    seen = lower_first(state.description) if state.description else "an abnormal behaviour"
    why = f"What was seen, at {seconds(state.since_us)} s: {seen}."
    if state.refined_by:
        why += (" The device alone could not tell which fault it is; the cell as a whole "
                f"did: {state.refined_by.rstrip('.')}.")
    elif certain:
        why += f" Only one fault explains it: {hypotheses}."
    elif state.final:
        why += (f" {len(state.labels)} faults explain it and what can be seen cannot tell them "
                f"apart: {hypotheses.replace(', or ', '; or ')}.")
    else:
        why += (f" It may be {hypotheses.replace(', or ', '; or ')}: the next movements will "
                "tell.")
    final = "final: only a fault reset leaves it" if state.final else \
        "intermediate: the next observations will decide"
    detail = (f"Local diagnoser {spec.name} reached state {state.state} ({state.description}) "
              f"at scan {state.since_scan} ({seconds(state.since_us)} s) by "
              f"{state.via or 'reset'}; its decision is {{{label_list}}} — "
              + ("isolated with certainty" if certain else f"ambiguous ({final})")
              + f". Faulty since scan {since.scan} ({seconds(since.time_us)} s)."
              + (" " + "; ".join(effects) + "." if effects else ""))
    consequences = _consequences(spec, state, texts, action)
    policies = _policies(builder, spec, state, texts, device)
    severity = "high" if any(_is_actuator(spec, lab) for lab in state.labels) else "medium"
    values = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(since.time_us), "since_scan": since.scan,
              "action": short_action, "label": state.labels[0] if certain else label_list,
              "labels": label_list, "label_text": hypotheses, "state": state.state,
              "state_text": state.description, "diagnoser": spec.name,
              "transition": state.via, "values": ""}
    level = Levels(what=what, why=why, consequences=consequences, policies=policies,
                   severity=severity, alarm=True, detail=detail)
    if certain:
        level = builder.apply_texts(builder.texts.get("labels", state.labels[0]), level, values)
    if state.refined_by:
        level = replace(level, detail=level.detail + (
            " The high level diagnoser refined the local decision "
            f"{{{', '.join(spec.state(state.state).labels)}}} to {label_list}."))
    return Explanation(f"diagnosis:{spec.name}", "diagnosis", level.severity, device,
                       level.what, level.why, level.consequences, level.policies,
                       since.scan, since.time_us, level.alarm, latched=True,
                       ambiguous=not certain, detail=level.detail)


def _consequences(spec: DiagnoserSpec, state: DiagnoserState, texts: dict[str, str],
                  action: str) -> str:
    parts: list[str] = []
    if state.certain:
        label = state.labels[0]
        if _is_actuator(spec, label):
            parts.append(f"Ordered to move, a {texts[label]} would not follow: the motor would "
                         "be driven against it and overheat, or the device would move when "
                         "nothing asks it to.")
        else:
            parts.append(f"With a {texts[label]}, every decision based on that sensor would "
                         "be made on a false picture: safe orders could be refused or unsafe "
                         "ones let through.")
    else:
        for label in state.labels:
            kind = "an actuator fault" if _is_actuator(spec, label) else "a sensor fault"
            parts.append(f"If it is {texts[label]} ({kind}): "
                         + ("driving the device again would push against the fault."
                            if _is_actuator(spec, label) else
                            "only the sensor's information is wrong; the device itself "
                            "would work."))
    parts.append(f"Already done: {action}.")
    parts.append("This stays until a fault reset; the reset clears it only if the device is "
                 "seen at rest in a normal position, and says why not otherwise.")
    return " ".join(parts)


def _policies(builder: ExplanationContext, spec: DiagnoserSpec, state: DiagnoserState,
              texts: dict[str, str], device: str) -> tuple[Policy, ...]:
    actuator = [lab for lab in state.labels if _is_actuator(spec, lab)]
    sensor = [lab for lab in state.labels if not _is_actuator(spec, lab)]
    policies: list[Policy] = []
    if not state.certain and actuator and sensor:
        first = ", ".join(texts[lab] for lab in actuator)
        then = ", ".join(texts[lab] for lab in sensor)
        policies.append(Policy(
            "check", f"Check {device} first",
            f"look at the device itself before its sensors: if {first} ({', '.join(actuator)}),"
            " orders would damage it — repair it, then reset; if it is not, the sensor is at "
            f"fault ({then}: {', '.join(sensor)}) — replace it, then reset (or continue "
            "degraded meanwhile)", None, True))
    if sensor and not actuator:
        policies.append(Policy(
            "continue", "Continue degraded",
            "keep running on the reconstructed value; replace the sensor at the next stop",
            None, True))
    policies.append(builder.policy_stop(device))
    for procedure in recoveries_of(builder.project):
        if device in builder.devices_of(procedure.outputs):
            policies.append(start_policy(procedure.name, procedure.description,
                                         recommended=False))
    policies.append(builder.policy_reset(
        "after repair: re-synchronise the diagnoser and release the flags (it stays faulty "
        "if the fault is still visible)", recommended=bool(actuator) and state.certain))
    policies.append(builder.policy_manual())
    return tuple(policies)


def _reconstruction(builder: ExplanationContext, snap: Snapshot, spec: DiagnoserSpec,
                    partition: Partition, sensor: str, state: DiagnoserState) -> Explanation:
    """`sensor`: the partition's (a reconstruction is only of a sensor partition)."""
    device = spec.device or builder.project.name
    key = f"reconstruction:{sensor}"
    since = builder.onsets[key]
    estimate = partition.estimate
    plain = builder.plain
    sensor_text = plain.name(sensor)
    estimate_text = plain.name(estimate) if estimate else "an estimate"
    suspected = " or ".join(state.label_texts)
    what = f"{device}: {sensor_text} ignored, {estimate_text} used — running degraded"
    why = (f"The diagnosis no longer trusts the {sensor_text}: it suspects {suspected}. Since "
           f"{seconds(since.time_us)} s.")
    consequences = (f"The program and the safety filter use the {estimate_text} where they "
                    f"would read the {sensor_text}: an estimate from the orders and the travel "
                    "time, not a measurement. If the device stops moving as the estimate "
                    "assumes (a jam), the estimate will be wrong and only the other sensors and "
                    "the diagnosis can tell.")
    detail = (f"{_flag_since(spec, partition, state, since)}. {partition.filtered} = not "
              f"{partition.flag} and {sensor} or {partition.flag} and {estimate} "
              f"(000 eq. 7-8); {estimate}: {_described(builder, estimate)}.")
    policies = (
        Policy("continue", "Continue degraded",
               f"keep running on the {estimate_text}; plan the sensor's replacement", None,
               True),
        builder.policy_stop(device),
        builder.policy_reset("after replacing the sensor: the flag is released if the "
                             "diagnoser re-synchronises"),
    )
    return _partition_explanation(
        builder, snap, key, "reconstruction", partition, state, since, device,
        _partition_levels(what, why, consequences, policies, detail),
        {"action": "reconstructed", "sensor": sensor, "estimate": estimate or "",
         "outputs": ""})


def _masked(builder: ExplanationContext, snap: Snapshot, spec: DiagnoserSpec,
            partition: Partition, state: DiagnoserState, held: tuple[str, ...]) -> Explanation:
    device = spec.device or builder.project.name
    key = f"masked:{partition.name}"
    since = builder.onsets[key]
    orders = builder.plain.orders(held)
    suspected = " or ".join(state.label_texts)
    what = f"{device}: {orders} held off — the device is not driven"
    why = (f"The diagnosis suspects {device} itself ({suspected}): a device that may be "
           f"blocked is not driven. Since {seconds(since.time_us)} s.")
    consequences = (f"The {orders} stay off whatever the program or a manual request asks, so "
                    f"{device} stays where it is and the steps of the cycle that need it wait. "
                    "The rest of the cell runs on.")
    detail = (f"{_flag_since(spec, partition, state, since)}, whose orders are masked: "
              f"C_filter = not {partition.flag} and C (000 eq. 9-10), applied to "
              f"{', '.join(held)} as the program asks them and as the filter writes them.")
    policies = (
        Policy("continue", "Continue without it",
               f"leave {device} stopped by the mask; the rest of the cell runs", None, True),
        builder.policy_stop(device),
        builder.policy_reset("after the repair: the mask is released if the diagnoser "
                             "re-synchronises"),
    )
    return _partition_explanation(
        builder, snap, key, "masked", partition, state, since, device,
        _partition_levels(what, why, consequences, policies, detail),
        {"action": "masked", "sensor": "", "estimate": "", "outputs": ", ".join(held)})


def _described(builder: ExplanationContext, estimate: str | None) -> str:
    """An estimate's description (the loader gives every sensor partition one)."""
    return builder.describe(estimate) if estimate is not None else "none"


def _partition_levels(what: str, why: str, consequences: str, policies: tuple[Policy, ...],
                      detail: str) -> Levels:
    """A partition flag's words: no alarm (the diagnosis raised one), medium."""
    return Levels(what=what, why=why, consequences=consequences, policies=policies,
                  severity="medium", alarm=False, detail=detail)


def _flag_since(spec: DiagnoserSpec, partition: Partition, state: DiagnoserState,
                since: Onset) -> str:
    return (f"{partition.flag} is set since scan {since.scan} ({seconds(since.time_us)} s): "
            f"the decision of {spec.name} ({', '.join(state.labels)}) holds a label of "
            f"partition {partition.name}")


def _partition_explanation(builder: ExplanationContext, snap: Snapshot, key: str, kind: str,
                           partition: Partition, state: DiagnoserState, since: Onset,
                           device: str, levels: Levels, extra: dict[str, str]) -> Explanation:
    """What a set partition flag does (a sensor on its estimate, orders masked): the generated
    levels, replaced by the project's `partitions:` texts where it has them; no alarm (the
    diagnosis raised one), latched like the decision."""
    values = {"device": device, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(since.time_us), "since_scan": since.scan,
              "partition": partition.name, "labels": ", ".join(state.labels), **extra}
    level = builder.apply_texts(builder.texts.get("partitions", partition.name),
                                levels, values)
    return Explanation(key, kind, level.severity, device, level.what, level.why,
                       level.consequences, level.policies, since.scan, since.time_us,
                       level.alarm, latched=True, detail=level.detail)

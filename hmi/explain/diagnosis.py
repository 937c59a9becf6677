"""Graduated explanations of diagnoser decisions (000 §2.1, §3.1), for the explanation builder.

One explanation per diagnoser holding a faulty decision, key ``diagnosis:<diagnoser>``:

1. what: the device and the label(s), in plain words, with *certain* or *ambiguous* —
   "Valve V1: sensor fsc stuck at 0 (F1) or valve blocked between its positions (F13) —
   ambiguous: check valve and motor first";
2. why: the diagnoser, the state and the transition that led there, since when, and the
   values the diagnoser reads now;
3. consequences: what the flags do (a sensor read from its estimate, orders masked), and that
   the decision stays until a fault reset, which re-synchronises only on an I/O picture of a
   normal state (the record's ``resync`` says whether it would now; the reset dialog shows it);
4. policies: continue degraded, check the device (recommended when ambiguous and a component
   that can be damaged is among the suspects), stop the device, manual, reset after repair.

An ambiguous decision names every label it cannot tell apart and says which to check first
and why: a fault of an actuator partition (the valve and its motor) can damage the plant if
driven again, a sensor fault only blinds the program, which already runs on the estimate.

A project's ``explanations: labels: <label>:`` texts replace any level of a certain decision
of that label (placeholders: hmi.explain.texts.PLACEHOLDERS["labels"]).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hmi.explain.model import Explanation, Policy
from hmi.timefmt import seconds

if TYPE_CHECKING:
    from hmi.engine.diagnoser import DiagnoserState
    from hmi.project.diagnosers import DiagnoserSpec, Partition


def diagnosis_explanations(builder, engine) -> list[Explanation]:
    """The `extra_builders` entry: one explanation per diagnoser with a faulty decision."""
    stage = getattr(engine, "diagnosis", None)
    if stage is None or stage.mode == "off":
        return []
    out = []
    for rt in stage.runtimes:
        record = rt.record  # (the stage's records are empty until it first runs)
        if not record.faulty:
            continue
        key = f"diagnosis:{record.name}"
        builder.onset(key, engine)  # forgotten once the decision is reset
        signature = (record.state, record.since_scan, engine.policy, stage.mode,
                     engine.stopped_devices and tuple(sorted(engine.stopped_devices)))
        out.append(builder.cached(key, signature,
                                  lambda r=record, s=rt.spec: _explain(builder, engine, stage,
                                                                       s, r)))
    return out


def _partitions(spec: DiagnoserSpec, labels: tuple[str, ...]) -> list[Partition]:
    return [p for p in spec.partitions if set(p.labels) & set(labels)]


def _part(p: Partition) -> str:
    return p.description or p.name


def _explain(builder, engine, stage, spec: DiagnoserSpec, d: DiagnoserState) -> Explanation:
    device = d.device or spec.device or builder.project.name
    labels = d.labels
    decision = " or ".join(f"{text} ({lab})" for lab, text in
                           zip(labels, d.label_texts, strict=True))
    parts = _partitions(spec, labels)
    actuator_parts = [p for p in parts if p.actuators]
    sensor_parts = [p for p in parts if p.sensor]
    certain = len(labels) == 1
    ftc = stage.mode == "ftc"
    masking = ftc and engine.policy != "monitor"
    if certain:
        what = f"{device}: {decision} — diagnosed with certainty"
    elif d.final:
        first = actuator_parts[0] if actuator_parts else None
        what = f"{device}: {decision} — ambiguous" + (
            f": check the {_part(first)} first" if first else "")
    else:
        what = f"{device}: {decision} — not yet isolated, the diagnoser is still watching"
    values = _values(engine, spec)
    why = (f"Diagnoser {spec.name} ({spec.description or device}) reached state {d.state}"
           + (f" ({d.description})" if d.description else "")
           + f" at scan {d.since_scan} ({seconds(d.since_us)} s)"
           + (f", by the transition {d.via}" if d.via else "") + ". "
           + ("Its decision isolates one label." if certain else
              f"Its decision holds {len(labels)} labels it cannot tell apart with the sensors "
              "it has" + ("." if d.final else "; a later event may still isolate one."))
           + (f" Values now: {values}." if values else ""))
    consequences = []
    for p in sensor_parts:
        consequences.append(
            f"The flag {p.flag} is set: the filter and the program read {p.sensor} from its "
            f"estimate {p.estimate}" + (" (the cell runs degraded on it)." if ftc else
                                         ", except in the observe mode: not applied now."))
    for p in actuator_parts:
        outs = ", ".join(p.actuators)
        if masking:
            consequences.append(f"The flag {p.flag} is set: the orders {outs} are masked "
                                "(held at 0 whatever the program asks): the device does not "
                                "move, the cycle waits.")
        else:
            consequences.append(f"The flag {p.flag} is set but the orders {outs} are NOT "
                                "masked (" + ("monitor policy" if ftc else "observe mode")
                                + "): the program still drives a device suspected faulty.")
    if not certain and actuator_parts:
        sensors = [p for p in parts if not p.actuators]
        consequences.append(
            f"Check the {_part(actuator_parts[0])} first: a fault there can damage the plant "
            "if it is driven again, whereas "
            + (f"a fault of the {', '.join(_part(p) for p in sensors)} only blinds the "
               "program, which already runs on the estimate." if sensors else
               "the other suspects do not."))
    consequences.append(
        "The decision stays until a fault reset; the reset re-synchronises the diagnoser only "
        "when the I/O matches a normal state (the reset dialog says whether it does now).")
    severity = "high" if actuator_parts else "medium"
    policies: list[Policy] = []
    recommended_check = not certain and bool(actuator_parts)
    if actuator_parts:
        policies.append(Policy("check", f"Check the {_part(actuator_parts[0])}",
                               f"inspect the {_part(actuator_parts[0])} on site before any "
                               "other choice; nothing is sent", None, recommended_check))
    policies.append(builder.policy_continue(
        "keep running degraded: " + ("; ".join(
            [f"{p.sensor} read from {p.estimate}" for p in sensor_parts]
            + [f"{', '.join(p.actuators)} masked" for p in actuator_parts if masking])
            or "nothing is masked or reconstructed"),
        recommended=certain and not actuator_parts))
    if device in engine.devices:
        policies.append(builder.policy_stop(device, recommended=certain and bool(actuator_parts)))
    policies.append(builder.policy_manual())
    policies.append(builder.policy_reset(
        "after the repair: re-synchronise the diagnoser on the I/O (only if it shows a normal "
        "state) and clear its flags"))
    defaults = {"what": what, "why": why, "consequences": " ".join(consequences),
                "policies": tuple(policies), "severity": severity, "alarm": True}
    fields = {"device": device, "time": seconds(engine.now), "scan": engine.scan,
              "since_time": seconds(d.since_us), "since_scan": d.since_scan,
              "action": ", ".join(p.flag for p in parts), "label": ", ".join(labels),
              "labels": ", ".join(labels), "label_text": decision, "state": d.state,
              "state_text": d.description, "diagnoser": spec.name, "transition": d.via,
              "values": values}
    spec_texts = builder.texts.get("labels", labels[0]) if certain else None
    level = builder.apply_texts(spec_texts, defaults, fields) if spec_texts else defaults
    return Explanation(f"diagnosis:{spec.name}", "diagnosis", level["severity"], device,
                       level["what"], level["why"], level["consequences"],
                       level["policies"], d.since_scan, d.since_us, level["alarm"],
                       latched=True, ambiguous=not certain)


def _values(engine, spec: DiagnoserSpec) -> str:
    """`fsc=0, fso=0, C=0, O=0`: the sensors and actuators of the partitions, as read now."""
    names: list[str] = []
    for p in spec.partitions:
        for name in (p.sensor, *p.actuators):
            if name and name not in names:
                names.append(name)
    slots = engine.layout.slots
    return ", ".join(f"{n}={int(bool(engine.image[slots[n]]))}" for n in names if n in slots)

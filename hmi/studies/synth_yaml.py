"""A synthesised diagnoser (hmi/studies/synthesis.py) written in the project's diagnoser
format: a `diagnosers:` file any command loads with `--diagnoser FILE.yaml`, with comments
saying where each state, window and label comes from. The same construction writes the same
text byte for byte (no time, no path of this machine in it)."""

from __future__ import annotations

import json

from hmi.project.device_models import DEVICE_MODELS as MODELS
from hmi.project.model import Project
from hmi.studies.synthesis import MARGIN_SCANS, SYNCH, TIMEOUT, Deviation, Diagnoser, Target
from hmi.timefmt import format_duration


def _q(text: str) -> str:
    """A YAML double-quoted scalar (JSON's string syntax is YAML's)."""
    return json.dumps(text, ensure_ascii=False)


def _labels_text(labels: tuple[str, ...]) -> str:
    return "[" + ", ".join(labels) + "]"


def _window(lo: int, hi: int | None) -> str:
    if lo == 0 and hi is None:
        return ""
    upper = "inf" if hi is None else format_duration(hi)
    return f", within: [{format_duration(lo)}, {upper}]"


def _partitions(project: Project, target: Target) -> list[tuple[str, tuple[str, ...], str]]:
    """(name, labels, the rest of the mapping) per partition: the hand-written diagnoser's
    (the project's observers and constraints read its flags), else one per failing part."""
    codes = [f.code for f in target.faults]
    out: list[tuple[str, tuple[str, ...], str]] = []
    placed: set[str] = set()
    if target.existing is not None:
        for p in target.existing.partitions:
            labels = tuple(c for c in codes if c in p.labels)
            if not labels:
                continue
            placed.update(labels)
            parts: list[str] = []
            if p.sensor:
                parts.append(f"sensor: {p.sensor}")
                if p.estimate:
                    parts.append(f"estimate: {p.estimate}")
            if p.actuators:
                parts.append("actuators: [" + ", ".join(p.actuators) + "]")
            if p.description:
                parts.append(f"description: {_q(p.description)}")
            out.append((p.name, labels, ", ".join(parts)))
    names = {n for n, _, _ in out}
    by_part: dict[str, list[str]] = {}
    for f in target.faults:
        if f.code not in placed:
            by_part.setdefault(f.component, []).append(f.code)
    known = {t.name for t in project.timers} | {o.name for o in project.observers} | \
        {v.name for v in project.inputs}
    for component, codes_of in by_part.items():
        rest: str
        if component == "actuator":
            name = f"{target.name}_actuators"
            rest = "actuators: [" + ", ".join(target.actuators) + "]"
        else:
            sensor = target.ports.get(component, component)
            name = f"{target.name}_{sensor}"
            estimate = f"{sensor}_hat"
            rest = f"sensor: {sensor}" + (f", estimate: {estimate}" if estimate in known else "")
        while name in names:
            name += "_"
        names.add(name)
        out.append((name, tuple(codes_of), rest))
    return out


def to_yaml(project: Project, d: Diagnoser) -> str:
    t = d.target
    nbm = d.nbm
    period = nbm.period
    law = project.default_control
    specs = MODELS[t.model].params
    params = ", ".join(f"{k} {format_duration(int(str(v))) if specs[k].kind == 'duration' else v}"
                       for k, v in sorted(t.params.items()))
    lines = [
        "# yaml-language-server: $schema=../../hmi/project/schema.json",
        "#",
        f"# The local diagnoser of {t.operator_name or t.device}, BUILT by",
        f"#   plchmi diagnose {project.path.name} --build {t.name}",
        "# from the plant model, the fault models and the control law on the closed loop "
        "(000 §2.1",
        "# steps 1-3; hmi/studies/synthesis.py). Built again, the same project gives this "
        "file byte",
        "# for byte; edit the project, not this file. Load it in place of the project's with",
        "#   plchmi check|run|diagnose|campaign PROJECT --diagnoser THIS_FILE.yaml",
        "#",
        f"# Step 1, plant element: device {t.device} (model {t.model}; {params}), observed "
        f"through {', '.join(t.sensors)} (read at t)",
        f"#   and {', '.join(t.actuators)} (the orders written at t-1); faults "
        f"{', '.join(f.code for f in t.faults)} of the {t.model} model.",
        f"# Step 2, normal behaviour: the fault-free closed loop (control law '{law}', filter "
        f"'{project.policy}') seen",
        *_normal_text(d, period),
        f"# Step 3, faults: every fault injected every {format_duration(d.grid_us)} of the "
        "cycle and 1 us before and after each",
        "#   normal event, observing only and under FTC "
        f"({d.runs_used} runs); under FTC iterated with the diagnoser built until",
        f"#   it is the one the loop was explored with: {d.iterations} rounds"
        + ("" if d.converged else " (NOT converged: the last round's diagnoser)") + ".",
        *_split_text(d),
        "diagnosers:",
        f"  {t.name}:",
        "    description: " + _q(f"Diagnoser of {t.operator_name or t.device} built from its "
                                "plant model, fault models and the control law"),
    ]
    if t.operator_name:
        lines.append(f"    device: {_q(t.operator_name)}")
    lines.append("    labels:")
    for f in t.faults:
        text = t.existing.labels.get(f.code) if t.existing is not None else None
        lines.append(f"      {f.code}: {_q(text or f.description)}")
    lines.append("    partitions:")
    for name, labels, rest in _partitions(project, t):
        lines.append(f"      {name}: {{labels: {_labels_text(labels)}"
                     + (f", {rest}" if rest else "") + "}")
    lines.append(f"    initial: {SYNCH}")
    lines.append("    states:")
    lines.append(f"      {SYNCH}: {{description: Synchronising}}  # waits for the device at "
                 "rest (no order) in a state of the fault-free cycle")
    lines.append("      # -- step 2: normal states, one per vector of the fault-free cycle "
                 "(first entered at)")
    for k in range(1, len(nbm.vectors)):
        where = (format_duration(nbm.first_seen[k]) if k in nbm.first_seen else
                 "not in the fault-free cycle: the order given, the plant's answer not seen "
                 "yet")
        lines.append(f"      N{k}: {{description: {_q(t.vector_text(nbm.vectors[k]))}}}  "
                     f"# {where}")
    lines.append("      # -- step 3: faulty states, the labels of the runs that reach them")
    for s in d.faulty:
        runs = ", ".join(f"{f} {n}" for f, n in s.runs.items())
        kind = "certain" if len(s.labels) == 1 else ("ambiguous" if s.events or s.timeout
                                                     else "ambiguous, final")
        lines.append(f"      {s.name}: {{labels: {_labels_text(s.labels)}, description: "
                     f"{_q(s.origin)}}}  # {kind}; runs: {runs}")
    lines.append("    transitions:")
    lines.append(f"      # {SYNCH}: at rest in a state of the cycle")
    at_rest = nbm.rest_states(t)
    for k in at_rest:
        lines.append(f"      - {{from: {SYNCH}, to: N{k}, when: "
                     f"{_q(t.condition(nbm.vectors[k]))}}}")
    deviations: dict[int, list[tuple[Deviation, str]]] = {}
    for dev, target_name in d.deviations:
        deviations.setdefault(dev.state, []).append((dev, target_name))
    n_orders = len(t.actuators)
    for k in range(1, len(nbm.vectors)):
        own = nbm.vectors[k]
        bouncing = nbm.settling.get(k, 0) if nbm.settle else 0
        lines.append(f"      # N{k}: {t.vector_text(own)}" + (
            f"; {_bits(t, bouncing)} may still bounce for {format_duration(nbm.settle)}: its "
            "old value is no event until then" if bouncing else ""))
        exp = nbm.expected.get(k, {})
        for vec in sorted(exp):
            e = exp[vec]
            if e.tmax is None:
                why = "the control law's event (no window)"
            elif not e.dwell or e.dwell == (0,):
                why = "the plant's answer to the order, seen with it in the fault-free runs"
            else:
                why = (f"the plant's event, seen after {_dwell(e.dwell)} in the fault-free "
                       "runs")
            lines.append(f"      - {{from: N{k}, to: N{nbm.state_of(vec)}, when: "
                         f"{_q(t.condition(vec))}{_window(e.tmin, e.tmax)}}}  # {why}")
        if nbm.settling.get(k) and nbm.settle:
            for vec in range(1 << len(t.names)):
                settled = nbm.settle_target(k, vec)
                if settled is not None and settled != k:
                    lines.append(f"      - {{from: N{k}, to: N{settled}, when: "
                                 f"{_q(t.condition(vec))}{_window(0, nbm.settle)}}}  # the "
                                 "control law's event, a switch still bouncing")
        timeout = None
        for dev, target_name in sorted(deviations.get(k, []), key=lambda x: x[0]):
            if dev.vec == TIMEOUT:
                timeout = (dev, target_name)
                continue
            lines.append(f"      - {{from: N{k}, to: {target_name}, when: "
                         f"{_q(t.condition(dev.vec))}{_window(dev.tmin, dev.tmax)}}}  "
                         "# leaves the normal behaviour")
        sensors = t.sensor_bits(own)
        for orders in range(1 << n_orders):
            vec = sensors | orders << len(t.sensors)
            if vec == own or vec in exp:
                continue
            lines.append(f"      - {{from: N{k}, to: {SYNCH}, when: {_q(t.condition(vec))}}}"
                         "  # an order the cycle does not give here: re-synchronise")
        if timeout is not None:
            dev, target_name = timeout
            lines.append(f"      - {{from: N{k}, to: {target_name}, after: "
                         f"{format_duration(dev.tmin)}}}  # the plant's event did not come")
    for s in d.faulty:
        if not s.events and s.timeout is None:
            continue
        lines.append(f"      # {s.name} {_labels_text(s.labels)}")
        for vec, lo, hi, target_name, why in s.events:
            lines.append(f"      - {{from: {s.name}, to: {target_name}, when: "
                         f"{_q(t.condition(vec))}{_window(lo, hi)}}}  # {why}")
        if s.timeout is not None:
            after, timeout_target, because = s.timeout
            lines.append(f"      - {{from: {s.name}, to: {timeout_target}, after: "
                         f"{format_duration(after)}}}  # {because}")
    lines.append("    resync:")
    for k in at_rest:
        lines.append(f"      - {{when: {_q(t.condition(nbm.vectors[k]))}, to: N{k}}}")
    return "\n".join(lines) + "\n"


def _normal_text(d: Diagnoser, period: int) -> list[str]:
    """How the windows were measured: the nominal plant's run alone, or over the band."""
    nbm = d.nbm
    jitter = nbm.margin - MARGIN_SCANS * period
    if not nbm.band:
        return [f"#   through that vector; a window is the dwell observed widened by "
                f"{_scans(MARGIN_SCANS, period)} each side."]
    lines = [f"#   through that vector, at the nominal plant and at the {len(nbm.band)} corners "
             "of the device's declared",
             "#   tolerances (each switch change of a kind bouncing alike):"]
    lines += [f"#     {text}" for text in nbm.band]
    lines.append(f"#   a window is the dwell observed over them widened by "
                 f"{_scans(MARGIN_SCANS, period)}"
                 + (f" and the scan jitter ({format_duration(jitter)})" if jitter else "")
                 + " each side.")
    if nbm.settle:
        lines.append(f"#   A switch that changed may read its old value for "
                     f"{format_duration(nbm.settle)} (its bounce, and a scan): no event "
                     "until then.")
    return lines


def _split_text(d: Diagnoser) -> list[str]:
    if not d.nbm.margin:
        return []
    return ["#   The faults are injected at the nominal plant. Runs leaving the normal behaviour "
            "by one change at",
            "#   different times are told apart by when: each fault's times widened by "
            f"{format_duration(d.nbm.margin)} each side, the",
            "#   window cut where the faults it holds change."]


def _bits(t: Target, bits: int) -> str:
    return ", ".join(n for k, n in enumerate(t.sensors) if bits >> k & 1)


def _scans(n: int, period: int) -> str:
    return f"{n} scans ({format_duration(n * period)})"


def _dwell(times: tuple[int, ...]) -> str:
    if len(times) == 1:
        return format_duration(times[0])
    return f"{format_duration(times[0])} to {format_duration(times[-1])}"

"""Graduated explanations of a stuck sequence: a GRAFCET step past its supervision time.

A step declared with `supervision: 10s` and active longer than that while the program runs
in automatic mode (hmi.engine.grafcet, the snapshot's `overdue_steps`) means the cell is
stuck there: the program waits for a condition that does not come. Key ``step:<step>``, kind
``sequence``: what (the program stuck, for how long, at which step, in the step's own words),
why (what the step waits for, with the values read when the alarm was raised, and since
when), consequences (nothing goes on by itself; what the program does once the condition
comes), policies (manual mode to do by hand what it waits for: the program resumes where it
waits; a recovery if the project declares one; keep waiting).

Severity medium (ISA-18.2 priority 2): production has stopped and only the operator can
restart it, but nothing is damaged or unsafe meanwhile (the safety filter and the
diagnosers still run) — an alarm to act on within minutes, not seconds. Not latched: it
clears as soon as the step is left (and is not raised in manual or recovery mode, where the
program waits on purpose). A project's `explanations: situations: step_<step>:` texts replace
any level; `{reason}` is what it waits for, in words, `{detail}` the engineering detail.

Levels 1 to 3 name no step (X3) nor any internal variable: a step is its description, a
variable its description (an input's or output's name as on the machine), a step time "the
time in this step".
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any

from hmi.engine import commands as cmd
from hmi.engine.criteria import Wait, receptivity_text, value_text
from hmi.explain.context import Levels
from hmi.explain.model import Explanation, Policy
from hmi.explain.plain import lower_first, without_notes
from hmi.explain.recovery import start_policy
from hmi.logic.expr import And, Compare, Const, Duration, Node, Not, Or, StepTime, Var
from hmi.project.recovery import recoveries_of
from hmi.timefmt import format_duration, seconds

if TYPE_CHECKING:
    from hmi.engine.snapshot import Snapshot
    from hmi.explain.context import ExplanationContext
    from hmi.project.model import Grafcet, Step


def sequence_explanations(builder: ExplanationContext, snap: Snapshot) -> list[Explanation]:
    """An explanation for each overdue step of this scan."""
    grafcet = snap.layout.grafcet
    if not snap.overdue_steps or grafcet is None:
        return []
    out = []
    waits: tuple[Wait, ...] | None = None
    for name in snap.overdue_steps:
        key = f"step:{name}"
        onset = builder.onset(key, snap)
        hit = builder.cache.get(key)
        if hit is not None and hit[0] == (name, onset.scan):
            out.append(hit[1])
            continue
        if waits is None:
            waits = snap.waits
        own = tuple(w for w in waits if w.step == name)
        out.append(builder.cached(key, (name, onset.scan),
                                  partial(_explain, builder, snap, grafcet, name, own)))
    return out


def step_words(grafcet: Grafcet, name: str) -> str:
    """A step as the operator reads it: its description, else 'step 3'."""
    step = _step(grafcet, name)
    if step is not None and step.description:
        return step.description
    return f"step {name[1:]}"


def _step(grafcet: Grafcet, name: str) -> Step | None:
    return next((s for s in grafcet.steps if s.name == name), None)


def _quoted(text: str) -> str:
    return f"\u201c{text}\u201d"


def _variable_words(builder: ExplanationContext, grafcet: Grafcet, name: str, value: Any,
                    step: str) -> str:
    """'pallet at the end of conveyor C1 (B) 0'; a step time 'the time in this step
    0.12 s'; a step 'the step “Robot free at home” active'."""
    if name.endswith(".t"):
        owner = name[:-2]
        where = "this step" if owner == step else _quoted(step_words(grafcet, owner))
        return f"the time in {where} {value_text(name, value)}"
    if any(s.name == name for s in grafcet.steps):
        return (f"the step {_quoted(step_words(grafcet, name))} "
                + ("active" if value else "not active"))
    shown = value_text(name, value)
    words = lower_first(without_notes(builder.describe(name))) or name
    if name in builder.devices:  # an input or output: its name is on the machine
        return f"{words} ({name}) {shown}" if words != name else f"{name} {shown}"
    return f"{words} {shown}"


def _reads_only_io(builder: ExplanationContext, wait: Wait) -> bool:
    return all(name in builder.devices for name, _ in wait.values)


def wait_words(builder: ExplanationContext, grafcet: Grafcet, wait: Wait) -> str:
    """One way on from the step, in words: the transition's description and the values it
    reads, else its condition said with the descriptions of what it reads (each with its
    value now); the steps of a join still to come. The expression itself is engineering
    detail (the control panel's engineering view)."""
    condition = next((t.receptivity.root for t in grafcet.transitions
                      if t.number == wait.transition), None)
    if wait.description or condition is None:
        what = _quoted(wait.description) if wait.description else "its condition"
        values = ", ".join(_variable_words(builder, grafcet, n, v, wait.step)
                           for n, v in wait.values)
        text = what + (f" ({values})" if values else "")
    else:
        text = condition_words(builder, grafcet, condition, dict(wait.values), wait.step)
    if wait.joins:
        text += " and for " + " and ".join(_quoted(step_words(grafcet, s))
                                           for s in wait.joins) + " to be reached too"
    return text


_COMPARED = {">=": "{} or more", ">": "more than {}", "<=": "at most {}", "<": "less than {}",
             "==": "exactly {}", "!=": "other than {}"}
_SWAPPED = {">=": "<=", ">": "<", "<=": ">=", "<": ">", "==": "==", "!=": "!="}


def condition_words(builder: ExplanationContext, grafcet: Grafcet, node: Node,
                    values: dict[str, Any], step: str) -> str:
    """A transition's condition with each signal, memory or step by its description and
    its value now: `the end of “box across the turntable's back edge” (tt_back now 1)` for
    fall(tt_back), `3 s or more in this step (now 0.80 s)` for X2.t >= 3s."""
    def thing(name: str) -> str:
        if any(s.name == name for s in grafcet.steps):
            return _quoted(step_words(grafcet, name))
        described = builder.describe(name)
        return _quoted(lower_first(without_notes(described))) if described != name \
            else _quoted(name)

    def now(name: str) -> str:
        if name not in values:
            return ""
        shown = value_text(name, values[name])
        if any(s.name == name for s in grafcet.steps):
            return f" (now {'active' if values[name] else 'not active'})"
        return f" ({name} now {shown})" if name in builder.devices else f" (now {shown})"

    def words(n: Node, inner: bool = False) -> str:
        if isinstance(n, Const):
            return "nothing more (always true)" if n.value else "never"
        if isinstance(n, Var):
            step_var = any(s.name == n.name for s in grafcet.steps)
            said = thing(n.name) + (" active" if step_var else "")
            return said + (" just before" if n.depth else "") + now(n.name)
        if isinstance(n, Not):
            if isinstance(n.operand, Var) and any(s.name == n.operand.name
                                                  for s in grafcet.steps):
                return thing(n.operand.name) + " not active" + now(n.operand.name)
            return "not " + words(n.operand, True)
        if isinstance(n, And) and len(n.operands) == 2:
            edge = _edge(n)
            if edge is not None:
                kind, name = edge
                return f"the {kind} of {thing(name)}{now(name)}"
        if isinstance(n, (And, Or)):
            joined = (" and " if isinstance(n, And) else " or ").join(
                words(op, True) for op in n.operands)
            return f"({joined})" if inner else joined
        if isinstance(n, Compare):
            left, op, right = n.left, n.op, n.right
            if isinstance(left, Duration) and isinstance(right, StepTime):
                left, op, right = right, _SWAPPED[op], left
            if isinstance(left, StepTime) and isinstance(right, Duration):
                where = "this step" if left.step == step else thing(left.step)
                said = _COMPARED[op].format(f"{right.us / 1e6:g} s") + f" in {where}"
                return said + now(f"{left.step}.t")
        return _quoted(receptivity_text(n))

    return words(node)


def _edge(node: And) -> tuple[str, str] | None:
    """("start", x) for rise(x) (x and not prev(x)), ("end", x) for fall(x)."""
    a, b = node.operands
    if isinstance(a, Var) and isinstance(b, Not) and isinstance(b.operand, Var) \
            and a.name == b.operand.name and {a.depth, b.operand.depth} == {0, 1}:
        return ("start" if a.depth == 0 else "end"), a.name
    return None


def _explain(builder: ExplanationContext, snap: Snapshot, grafcet: Grafcet, name: str,
             waits: tuple[Wait, ...]) -> Explanation:
    project = builder.project.name
    step = _step(grafcet, name)
    limit = step.supervision_us if step is not None and step.supervision_us else 0
    words = step_words(grafcet, name)
    waited = int(snap.value(f"{name}.t")) if f"{name}.t" in snap.layout.slots else 0
    since = snap.time_us - waited
    onset = builder.onsets[f"step:{name}"]
    what = (f"Program stuck at {_quoted(words)} — waiting more than "
            f"{format_duration(limit)}")
    if waits:
        reason = " — or for ".join(wait_words(builder, grafcet, w) for w in waits)
        why = (f"The program has waited at {_quoted(words)} since {seconds(since)} s, longer "
               f"than the {format_duration(limit)} it may take. It waits for {reason}, as "
               f"read at {seconds(snap.time_us)} s (the control panel shows what it waits "
               "for now).")
    else:
        reason = "nothing: no transition leaves this step"
        why = (f"The program has waited at {_quoted(words)} since {seconds(since)} s, longer "
               f"than the {format_duration(limit)} it may take, and no transition leaves it.")
    nexts = []
    for w in waits:
        targets = " and ".join(_quoted(step_words(grafcet, t)) for t in w.targets)
        if targets and targets not in nexts:
            nexts.append(targets)
    consequences = ("The cell does not go on by itself: the program stays at "
                    f"{_quoted(words)} for as long as the condition does not come, and no "
                    "other part of the sequence that waits for this one moves either. ")
    if nexts:
        consequences += ("When the condition comes, the program goes on at once to "
                         + " or to ".join(nexts) + ". ")
    consequences += ("Nothing unsafe follows from waiting: the safety filter and the "
                     "diagnosis still run. The alarm clears when the step is left.")
    wanted: dict[str, bool] = {}
    for w in waits[:1]:  # (the first way on: the one the cell normally takes)
        wanted.update((n, v) for n, v in w.missing if n in snap.layout.inputs)
    what_by_hand = " and ".join(
        f"{n} ({lower_first(without_notes(builder.describe(n)))}) is {'on' if v else 'off'}"
        for n, v in wanted.items())
    policies: list[Policy] = [Policy(
        "manual", "Switch to manual",
        "do by hand what the program waits for"
        + (f" (until {what_by_hand})" if what_by_hand else "")
        + "; the program waits meanwhile, and when you leave manual mode it resumes from "
        f"{_quoted(words)}, where it waits now", cmd.SetMode(True), True)]
    procedures = recoveries_of(builder.project)
    if procedures:
        needed = {n for n, *_ in snap.recovery.needed}
        chosen = next((p for p in procedures if p.name in needed), procedures[0])
        recovery = start_policy(chosen.name, chosen.description, recommended=False)
        policies.append(Policy(recovery.id, recovery.label,
                               recovery.effect + "; leaving it, the program starts again from "
                               "its initial steps", recovery.command, False))
    policies.append(builder.policy_continue(
        "keep waiting: the program goes on by itself if the condition comes"))
    conditions = "; ".join(
        f"transition {w.transition} ({', '.join(s for s in (w.step, *w.joins))} -> "
        f"{', '.join(w.targets)}): `{w.receptivity}`"
        + (f", {', '.join(w.joins)} not active" if w.joins else "")
        + (f" — {w.shown_values}" if w.values else "")
        + ("" if w.holds is None else f" ({'true' if w.holds else 'false'})")
        for w in waits) or "no transition leaves it"
    detail = (f"Step {name} active since {seconds(since)} s, supervision "
              f"{format_duration(limit)}: overdue at scan {onset.scan} "
              f"({seconds(onset.time_us)} s). Waits for: {conditions}.")
    defaults = Levels(what=what, why=why, consequences=consequences,
                      policies=tuple(policies), severity="medium", alarm=True, detail=detail)
    fields = {"device": project, "time": seconds(snap.time_us), "scan": snap.scan,
              "since_time": seconds(since), "since_scan": onset.scan,
              "action": "none (the program waits)", "reason": reason, "detail": detail}
    level = builder.apply_texts(builder.texts.get("situations", f"step_{name}"), defaults,
                                fields)
    return Explanation(f"step:{name}", "sequence", level.severity, project,
                       level.what, level.why, level.consequences, level.policies,
                       onset.scan, onset.time_us, level.alarm, detail=level.detail)


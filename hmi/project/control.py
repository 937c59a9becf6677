"""The `control:` section: the control law's variants, each equations and/or a GRAFCET.

Steps are named X<number>; their activity variables are readable by the law's own expressions
only. A step no transition can reach is a warning, an output driven twice an error.
"""

from __future__ import annotations

from hmi.errors import SourcePos
from hmi.logic.names import is_step_number
from hmi.project.model import (
    Action,
    ControlLaw,
    Equation,
    Grafcet,
    Step,
    Transition,
)
from hmi.project.reader import ProjectReader
from hmi.project.yamlnodes import YNode
from hmi.timefmt import format_duration

# What the control law's expressions may read (outputs: the value being computed this scan).
CONTROL_KINDS = {"input", "output", "memory", "timer", "observer", "step", "flag", "filtered"}


def parse_controls(reader: ProjectReader, pos: SourcePos, outputs: set[str],
                   memories: set[str], period_us: int = 10_000
                   ) -> tuple[dict[str, ControlLaw], str]:
    node = reader.sections.get("control")
    if node is None:
        reader.diag.error(pos, "the project has no control law", "a 'control:' section")
        return {}, ""
    mapping = reader.guard(lambda: node.as_map("control"), {})
    if not mapping:
        if node.kind == "map":
            reader.diag.error(node.pos, "the control section is empty",
                              "equations and/or a grafcet")
        return {}, ""
    if set(mapping) & {"equations", "grafcet"}:
        variants = {"main": node}
        positions = {"main": node.pos}
    else:
        variants = mapping
        positions = node.key_pos
    controls: dict[str, ControlLaw] = {}
    for vname, vnode in variants.items():
        law = _control_law(reader, str(vname), vnode, positions[vname], outputs, memories,
                           period_us)
        if law is not None:
            controls[str(vname)] = law
    default = next(iter(variants), "")
    return controls, str(default)


def _control_law(reader: ProjectReader, name: str, node: YNode, kpos: SourcePos, outputs: set[str],
                 memories: set[str], period_us: int) -> ControlLaw | None:
    what = f"control variant {name!r}"
    fields = reader.guard(lambda: node.check_keys(
        what, {"description", "equations", "grafcet"}))
    if fields is None:
        return None
    if "equations" not in fields and "grafcet" not in fields:
        reader.diag.error(node.pos, f"{what} has neither equations nor a grafcet",
                          "'equations:' and/or 'grafcet:'")
        return None
    description = reader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    grafcet = None
    steps: tuple[str, ...] = ()
    if "grafcet" in fields:
        steps = _step_names(fields["grafcet"])
        grafcet = _grafcet(reader, fields["grafcet"], what, steps, outputs, memories,
                           period_us)
    equations = _equations(reader, fields.get("equations"), what, steps, outputs, memories)
    driven_by_actions: dict[str, SourcePos] = {}
    if grafcet:
        for step in grafcet.steps:
            for action in step.actions:
                if action.kind == "N":
                    driven_by_actions.setdefault(action.target, action.pos)
    for eq in equations:
        if eq.target in driven_by_actions:
            reader.diag.error(eq.pos, f"{eq.target!r} is computed by an equation and also "
                              f"by a step action at {driven_by_actions[eq.target]}",
                              "one place that drives each output")
    law = ControlLaw(name, description, tuple(equations), grafcet, kpos)
    for out in sorted(outputs - law.driven_outputs()):
        reader.diag.warning(kpos, f"output {out!r} is never driven by {what}; its "
                            "functional value stays 0")
    return law


def _equations(reader: ProjectReader, node: YNode | None, what: str, steps: tuple[str, ...],
               outputs: set[str], memories: set[str]) -> list[Equation]:
    if node is None:
        return []
    mapping = reader.guard(lambda: node.as_map(f"the equations of {what}"), {})
    equations = []
    for target, enode in mapping.items():
        tpos = node.key_pos[target]
        target = str(target)
        if target not in outputs and target not in memories:
            kind = reader.namespace.get(target)
            reader.diag.error(tpos, f"equation target {target!r} is "
                              + (f"a {kind}" if kind else "not declared"),
                              "an output or a memory")
            continue
        ewhat = f"the equation of {target!r}"
        if enode.kind == "map":
            fields = reader.guard(lambda n=enode, w=ewhat: n.check_keys(
                w, {"set", "reset", "dominant"}, ["set", "reset"]))
            if fields is None:
                continue
            dominant = "reset"
            if "dominant" in fields:
                dominant = reader.guard(lambda f=fields: reader.choice(
                    f["dominant"], "dominant", ("set", "reset")), "reset")
            set_ = reader.expr(fields["set"], f"the set of {target!r}", CONTROL_KINDS, steps)
            reset = reader.expr(fields["reset"], f"the reset of {target!r}", CONTROL_KINDS,
                                steps)
            if set_ and reset:
                equations.append(Equation(target, None, set_, reset, dominant == "set",
                                          tpos))
        else:
            expr = reader.expr(enode, ewhat, CONTROL_KINDS, steps)
            if expr:
                equations.append(Equation(target, expr, pos=tpos))
    return equations


def _step_names(node: YNode) -> tuple[str, ...]:
    if node.kind != "map" or "steps" not in node.value:
        return ()
    steps = node.value["steps"]
    if steps.kind != "map":
        return ()
    return tuple(f"X{int(k)}" for k in steps.value if is_step_number(k))


def _grafcet(reader: ProjectReader, node: YNode, what: str, step_names: tuple[str, ...],
             outputs: set[str], memories: set[str], period_us: int) -> Grafcet | None:
    fields = reader.guard(lambda: node.check_keys(
        f"the grafcet of {what}", {"steps", "transitions"}, ["steps", "transitions"]))
    if fields is None:
        return None
    step_map = reader.guard(lambda: fields["steps"].as_map("steps"), {})
    steps: list[Step] = []
    numbered: dict[int, SourcePos] = {}
    for key, snode in step_map.items():
        spos = fields["steps"].key_pos[key]
        if not is_step_number(key):
            reader.diag.error(spos, f"step {key!r} is not a step number",
                              "a whole number: steps are named X<number>")
            continue
        if int(key) in numbered:  # "7" and "007"
            reader.diag.error(spos, f"step {int(key)} is defined twice (first at "
                              f"{numbered[int(key)]})", "each step number once")
            continue
        numbered[int(key)] = spos
        step = _step(reader, int(key), snode, spos, step_names, outputs, memories, period_us)
        if step:
            steps.append(step)
    if not step_map:
        reader.diag.error(fields["steps"].pos, "the grafcet has no steps", "at least one step")
        return None
    if not any(s.initial for s in steps) and len(steps) == len(step_map):
        reader.diag.error(fields["steps"].pos, "the grafcet has no initial step",
                          "at least one step with 'initial: true'")
    trans_nodes = reader.guard(lambda: fields["transitions"].as_seq("transitions"), [])
    transitions = []
    for index, tnode in enumerate(trans_nodes, start=1):
        tr = _transition(reader, index, tnode, step_names)
        if tr:
            transitions.append(tr)
    grafcet = Grafcet(tuple(steps), tuple(transitions), node.pos)
    _check_reachability(reader, grafcet)
    return grafcet


def _step(reader: ProjectReader, number: int, node: YNode, spos: SourcePos, steps: tuple[str, ...],
          outputs: set[str], memories: set[str], period_us: int) -> Step | None:
    name = f"X{number}"
    if node.kind == "scalar" and node.value is None:
        return Step(number, name, False, "", (), spos)
    fields = reader.guard(lambda: node.check_keys(
        f"step {number}", {"initial", "description", "actions", "supervision"}))
    if fields is None:
        return None
    initial = reader.guard(lambda: fields["initial"].as_bool("initial"), False) \
        if "initial" in fields else False
    description = reader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    actions = []
    if "actions" in fields:
        items = reader.guard(lambda: fields["actions"].as_seq(
            f"the actions of step {number}"), [])
        for anode in items:
            action = _action(reader, anode, number, steps, outputs, memories)
            if action:
                actions.append(action)
    supervision = _supervision(reader, fields["supervision"], number, period_us) \
        if "supervision" in fields else None
    return Step(number, name, initial, description, tuple(actions), spos, supervision)


def _supervision(reader: ProjectReader, node: YNode, number: int, period_us: int) -> int | None:
    """A step's supervision time (S7-GRAPH's): a duration of at least one scan period (the
    program cannot be seen waiting less); one that is not a multiple of the period is a
    warning (the alarm comes at the first scan past it)."""
    what = f"the supervision of step {number}"
    us: int | None = reader.guard(lambda: node.as_duration(what))
    if us is None:
        return None
    if us < period_us:
        reader.diag.error(node.pos, f"{what} ({format_duration(us)}) is shorter than the scan "
                          f"period ({format_duration(period_us)}): the step would be "
                          "reported stuck as soon as it is active",
                          f"a duration of at least {format_duration(period_us)}, longer than "
                          "the step lasts in a normal cycle")
        return None
    if us % period_us:
        reader.diag.warning(node.pos, f"{what} ({format_duration(us)}) is not a multiple of "
                            f"the scan period {format_duration(period_us)}: the alarm comes "
                            "at the first scan past it")
    return us


def _action(reader: ProjectReader, node: YNode, number: int, steps: tuple[str, ...],
            outputs: set[str], memories: set[str]) -> Action | None:
    what = f"an action of step {number}"
    if node.kind == "scalar":
        target = reader.guard(lambda: node.as_str(what))
        if target is None:
            return None
        if target not in outputs:
            _bad_target(reader, node.pos, target, "a continuous action", "an output")
            return None
        return Action("N", target, None, node.pos)
    fields = reader.guard(lambda: node.check_keys(what, {"do", "if", "set", "reset"}))
    if fields is None:
        return None
    kinds = [k for k in ("do", "set", "reset") if k in fields]
    if len(kinds) != 1:
        reader.diag.error(node.pos, f"{what} must have exactly one of do, set, reset",
                          "'O', {do: O, if: cond}, {set: M} or {reset: M}")
        return None
    kind = kinds[0]
    target = reader.guard(lambda: fields[kind].as_str(f"the target of {what}"))
    if target is None:
        return None
    if kind == "do":
        if target not in outputs:
            _bad_target(reader, fields[kind].pos, target, "a continuous action", "an output")
            return None
        condition = None
        if "if" in fields:
            condition = reader.expr(fields["if"], f"the condition of {what}", CONTROL_KINDS,
                                    steps)
            if condition is None:
                return None
        return Action("N", target, condition, node.pos)
    if "if" in fields:
        reader.diag.error(fields["if"].pos, "a stored action takes no condition",
                          "{set: M} or {reset: M}")
        return None
    if target not in memories:
        _bad_target(reader, fields[kind].pos, target, f"a stored action ({kind})",
                         "a memory (drive outputs with continuous actions or equations)")
        return None
    return Action("S" if kind == "set" else "R", target, None, node.pos)


def _bad_target(reader: ProjectReader, pos: SourcePos, target: str, what: str,
                expected: str) -> None:
    kind = reader.namespace.get(target)
    reader.diag.error(pos, f"{what} targets {target!r}, which is "
                      + (f"a {kind}" if kind else "not declared"), expected)


def _transition(reader: ProjectReader, index: int, node: YNode,
                steps: tuple[str, ...]) -> Transition | None:
    what = f"transition {index}"
    fields = reader.guard(lambda: node.check_keys(
        what, {"from", "to", "when", "description"}, ["from", "to", "when"]))
    if fields is None:
        return None
    sources = _step_refs(reader, fields["from"], what, steps)
    targets = _step_refs(reader, fields["to"], what, steps)
    description = reader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    receptivity = reader.expr(fields["when"], f"the receptivity of {what}", CONTROL_KINDS,
                              steps)
    if sources is None or targets is None or receptivity is None:
        return None
    return Transition(index, sources, targets, receptivity, description, node.pos)


def _step_refs(reader: ProjectReader, node: YNode, what: str,
               steps: tuple[str, ...]) -> tuple[str, ...] | None:
    items = node.value if node.kind == "seq" else [node]
    refs = []
    for item in items:
        if item.kind != "scalar" or not is_step_number(item.value):
            reader.diag.error(item.pos, f"{what} refers to {item.raw!r}, not a step number",
                              "a step number or a list of step numbers")
            return None
        name = f"X{int(item.value)}"
        if name not in steps:
            reader.diag.error(item.pos, f"{what} refers to step {item.value}, which is not "
                              "declared", "one of the steps: " + ", ".join(
                                s[1:] for s in steps))
            return None
        refs.append(name)
    if not refs:
        reader.diag.error(node.pos, f"{what} has no step", "a step number")
        return None
    return tuple(refs)


def _check_reachability(reader: ProjectReader, grafcet: Grafcet) -> None:
    reached = {s.name for s in grafcet.steps if s.initial}
    # A transition fires (for this check) once all its source steps are reached; each is
    # looked at when one of its sources is reached: linear in the transitions.
    waiting: dict[str, list[Transition]] = {}
    for tr in grafcet.transitions:
        for source in set(tr.sources):
            waiting.setdefault(source, []).append(tr)
    frontier = list(reached)
    while frontier:
        for tr in waiting.get(frontier.pop(), ()):
            if set(tr.sources) <= reached:
                for target in tr.targets:
                    if target not in reached:
                        reached.add(target)
                        frontier.append(target)
    for step in grafcet.steps:
        if step.name not in reached:
            reader.diag.warning(step.pos, f"step {step.number} can never become active "
                                "(no path of transitions from an initial step)")

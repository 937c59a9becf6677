"""Load and validate a project folder.

A project is a folder with a `project.yaml` (and optional files it `include`s). Loading is
two passes: the first declares every name (I/O, memories, timers, observers), the second
parses every expression against those names. Errors are collected, not thrown one at a time,
and each names its file, line and column. The result is an immutable :class:`Project`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from hmi.errors import ProjectError, SourcePos, display_path
from hmi.limits import MAX_CONSTRAINTS, MIN_SCAN_PERIOD_US
from hmi.logic.expr import (
    NotMonomial,
    monomial_literals,
)
from hmi.logic.names import (
    NAME_HINT,
    is_step_number,
    name_problem,
)
from hmi.project.campaign import parse_campaign
from hmi.project.components import ComponentInstance, load_components, merge_texts
from hmi.project.confine import Refused, confined_file, project_roots
from hmi.project.device_models import DEVICE_MODELS, ParamSpec
from hmi.project.diagnosers import declare_diagnoser_names, parse_diagnosers
from hmi.project.model import (
    MAX_SOLVER_BUDGET,
    MIN_SOLVER_BUDGET,
    POLICIES,
    READ_ONLY_TABLES,
    TABLES,
    Action,
    Constraint,
    ControlLaw,
    DeviceSpec,
    Equation,
    Grafcet,
    Observer,
    PlantAddress,
    PlantSpec,
    Project,
    Step,
    Timer,
    Transition,
    Variable,
)
from hmi.project.monitors import parse_monitors
from hmi.project.reader import ProjectReader
from hmi.project.scenarios import parse_scenarios
from hmi.project.yamlnodes import NodeError, YNode, load_yaml
from hmi.timefmt import DURATION_HINT, format_duration

PROJECT_FILE = "project.yaml"

TOP_KEYS = {
    "name", "description", "scan_period", "include", "inputs", "outputs", "memories",
    "timers", "observers", "control", "constraints", "policy", "solver", "solver_budget",
    "plant", "explanations", "monitors", "scenarios", "diagnosers", "campaign", "components",
}


# What each kind of expression may read. Outputs at the current scan are only known once the
# control law has run, so timers and observers (updated before it) read them through prev();
# so are partition flags and filtered sensors (hmi/project/diagnosers.py), computed after them.
GLOBAL_KINDS = {"input", "output", "timer", "observer", "flag", "filtered"}
CONTROL_KINDS = {"input", "output", "memory", "timer", "observer", "step", "flag", "filtered"}
CONSTRAINT_KINDS = {"input", "output", "timer", "observer", "flag", "filtered"}
PREV_ONLY = {"output", "flag", "filtered"}  # for timers and observers


def resolve_project_file(path: str | Path) -> Path:
    """The project.yaml a command-line path designates (a folder or the file itself)."""
    p = Path(path)
    try:
        return _project_file(p, str(path))
    except (OSError, ValueError) as exc:  # a name too long, a NUL: not a project anywhere
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ProjectError.single(SourcePos(str(path)[:200]), f"cannot use this path: {reason}",
                                  f"a folder holding {PROJECT_FILE}") from None


def _project_file(p: Path, shown: str) -> Path:
    if p.is_dir():
        candidate = p / PROJECT_FILE
        if not candidate.exists():
            raise ProjectError.single(
                SourcePos(display_path(p)),
                f"this folder has no {PROJECT_FILE}",
                f"a project folder holding {PROJECT_FILE}")
        return candidate
    if p.exists():
        return p
    raise ProjectError.single(SourcePos(shown), "no such project folder or file",
                              f"a folder holding {PROJECT_FILE}")


def load_project(path: str | Path, diagnoser_variant: str | None = None) -> Project:
    """Load, validate and return the project at `path`; raise ProjectError listing problems.

    `diagnoser_variant` loads that variant of every diagnoser declaring `variants:` (by
    default each loads its first)."""
    loader = ProjectLoader(resolve_project_file(path))
    loader.diagnoser_variant = diagnoser_variant
    return loader.load()


class ProjectLoader(ProjectReader):
    """Reads project.yaml and its includes, then each section, into a :class:`Project`."""

    def __init__(self, file: Path):
        super().__init__(file)
        self.pending_includes: list[YNode] = []

    # -- top level --------------------------------------------------------------------------
    def load(self) -> Project:
        display = display_path(self.file)
        root = load_yaml(self.file, display)
        self.files.append(display)
        top = self.guard(lambda: root.as_map("a project file"))
        if top is None:
            self.diag.raise_if_errors()
        self._collect_sections(root, top, display, allow_include=True)
        for item in self.pending_includes:
            self._include(item)
        self.diag.raise_if_errors()
        return self._build(root)

    def _collect_sections(self, root: YNode, top: dict[str, YNode], display: str,
                          allow_include: bool) -> None:
        for key, node in top.items():
            kpos = root.key_pos[key]
            if key not in TOP_KEYS:
                self.diag.error(kpos, f"unknown section {key!r}",
                                "one of " + ", ".join(sorted(TOP_KEYS)))
                continue
            if key == "include":
                if not allow_include:
                    self.diag.error(kpos, "an included file cannot include others",
                                    "includes listed in project.yaml")
                    continue
                # Included files are read after this file's own sections, so a section
                # repeated by an include is reported in the include.
                self.pending_includes.extend(self.guard(lambda n=node: n.as_seq("include"), []))
                continue
            if key in self.sections:
                self.diag.error(kpos, f"section {key!r} is defined twice (first at "
                                f"{self.section_pos[key]})", "each section once")
                continue
            self.sections[key] = node
            self.section_pos[key] = kpos

    def _include(self, item: YNode) -> None:
        name = self.guard(lambda: item.as_str("an included file name"))
        if name is None:
            return
        try:
            path = confined_file(self.folder, name, project_roots(self.folder),
                                 "the included file")
        except Refused as exc:
            self.diag.error(item.pos, exc.message, exc.expected)
            return
        if not path.exists():
            self.diag.error(item.pos, f"included file {name!r} not found",
                            "a YAML file in the project folder")
            return
        display = display_path(path)
        try:
            root = load_yaml(path, display)
        except ProjectError as exc:
            self.diag.items.extend(exc.errors)
            return
        self.files.append(display)
        top = self.guard(lambda: root.as_map("an included file"))
        if top is not None:
            self._collect_sections(root, top, display, allow_include=False)

    def _build(self, root: YNode) -> Project:
        s = self.sections
        pos = root.pos
        name = self.guard(lambda: s["name"].as_str("name"), "") if "name" in s else ""
        if "name" not in s:
            self.diag.error(pos, "the project has no name", "a 'name:' entry")
        description = self.guard(lambda: s["description"].as_str("description"), "") \
            if "description" in s else ""
        period = 10_000
        if "scan_period" in s:
            period = self.guard(lambda: s["scan_period"].as_duration("scan_period"), period)
            if period < MIN_SCAN_PERIOD_US:
                self.diag.error(s["scan_period"].pos, f"scan_period {s['scan_period'].raw!r} is "
                                "shorter than the shortest scan period plchmi runs",
                                f"at least {format_duration(MIN_SCAN_PERIOD_US)}")
                period = MIN_SCAN_PERIOD_US
        else:
            self.diag.error(pos, "the project has no scan period", "'scan_period: 10ms'")

        inputs = self._variables("inputs", "input", {"description", "address", "device"})
        outputs = self._variables("outputs", "output",
                                  {"description", "address", "safe", "device"})
        memories = self._variables("memories", "memory", {"description", "initial"})
        if "inputs" not in s:
            self.diag.error(pos, "the project has no inputs", "an 'inputs:' section")
        if "outputs" not in s:
            self.diag.error(pos, "the project has no outputs", "an 'outputs:' section")
        # Component instances add timers, observers, constraints, diagnosers and explanations,
        # read below with the project's own (hmi/project/components.py).
        self.components = load_components(self)
        self.files.extend(self.components.files)
        timer_nodes = self._declare_items("timers", "timer")
        observer_nodes = self._declare_items("observers", "observer")
        declare_diagnoser_names(self)  # def_<partition> flags, <sensor>_filter names

        timers = [t for t in (self._timer(n, k, p) for n, k, p in timer_nodes) if t]
        observers = [o for o in (self._observer(n, k, p) for n, k, p in observer_nodes) if o]
        controls, default_control = self._controls(pos, {v.name for v in outputs},
                                                   {m.name for m in memories})
        constraints = self._constraints()
        policy = "correct"
        if "policy" in s:
            policy = self.guard(lambda: self.choice(s["policy"], "policy", POLICIES), policy)
        solver = "exact"
        if "solver" in s:
            solver = self.guard(lambda: self.choice(s["solver"], "solver", ("exact", "paper")),
                                solver)
        solver_budget = None
        if "solver_budget" in s:
            solver_budget = self.guard(lambda: s["solver_budget"].as_int(
                "solver_budget", MIN_SOLVER_BUDGET, MAX_SOLVER_BUDGET), None)
        plant = self._plant(pos, inputs, outputs)
        self._check_addresses(inputs, outputs)
        monitors = parse_monitors(self, period)  # stopwatch monitors: hmi/project/monitors.py
        scenarios = parse_scenarios(self, plant)
        diagnosers = parse_diagnosers(self)  # hmi/project/diagnosers.py
        campaign = parse_campaign(self, plant)  # hmi/project/campaign.py
        texts = None
        sources: list[tuple[ComponentInstance | None, YNode]] = [*self.components.explanations]
        if "explanations" in s:
            sources.append((None, s["explanations"]))
        if sources:
            from hmi.project.explanations import parse_explanations
            known = {"constraints": {c.name for c in constraints},
                     "monitors": {m.name for m in monitors},
                     "labels": self.declared_labels,
                     "partitions": self.declared_partitions}
            texts = merge_texts(self, [
                (owner, parse_explanations(node, self.guard, known, self.diag.error))
                for owner, node in sources])
        self.diag.raise_if_errors()
        project = Project(
            name=name, description=description, path=self.folder, scan_period_us=period,
            inputs=tuple(inputs), outputs=tuple(outputs), memories=tuple(memories),
            timers=tuple(timers), observers=tuple(observers), controls=controls,
            default_control=default_control, constraints=tuple(constraints), policy=policy,
            plant=plant, pos=pos, files=tuple(self.files), solver=solver,
            solver_budget=solver_budget, diagnosers=diagnosers, monitors=monitors,
            scenarios=scenarios, campaign=campaign, explanations=texts,
            components=tuple(self.components.instances), warnings=tuple(self.diag.warnings),
            check_sections=((tuple(self.components.check_lines()),)
                            if self.components.instances else ()),
        )
        return project

    # -- declarations -----------------------------------------------------------------------
    def _variables(self, key: str, kind: str, allowed: set[str]) -> list[Variable]:
        out = []
        for name, node, kpos in self.section_items(key):
            if not self.declare(str(name), kind, kpos):
                continue
            var = self.guard(lambda n=node, nm=str(name), p=kpos: self._variable(
                n, nm, kind, allowed, p))
            if var is not None:
                out.append(var)
        return out

    def _variable(self, node: YNode, name: str, kind: str, allowed: set[str],
                  kpos: SourcePos) -> Variable:
        """A declared variable, even when one of its fields is wrong: that field's error is
        reported and a neutral value stands in, so that the rest of the project is checked
        against a variable that exists (not "'C' is not an output" after "bad safe value")."""
        if node.kind == "scalar" and node.tag.endswith(":str"):
            return Variable(name, kind, node.value, pos=kpos)
        fields = node.check_keys(f"{kind} {name!r}", allowed)
        guard = self.guard
        description = guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        safe = False
        if "safe" in fields:
            safe = guard(lambda: fields["safe"].as_bool("safe value"), False)
        if "initial" in fields:
            safe = guard(lambda: fields["initial"].as_bool("initial value"), False)
        address = None
        if "address" in fields:
            address = guard(lambda: parse_address(fields["address"], kind))
        device = guard(lambda: fields["device"].as_str("device")) if "device" in fields \
            else None
        return Variable(name, kind, description, safe, address, kpos, device)

    def _declare_items(self, key: str, kind: str) -> list[tuple[str, YNode, SourcePos]]:
        declared = []
        for name, node, kpos in self.section_items(key):
            if self.declare(str(name), kind, kpos):
                declared.append((str(name), node, kpos))
        return declared

    # -- timers and observers --------------------------------------------------------------
    def _timer(self, name: str, node: YNode, kpos: SourcePos) -> Timer | None:
        fields = self.guard(lambda: node.check_keys(
            f"timer {name!r}", {"type", "input", "preset", "description"}, ["type", "input"]))
        if fields is None:
            return None
        if "preset" not in fields:
            self.diag.error(node.pos, f"timer {name!r} has no preset",
                            "'preset:' with " + DURATION_HINT)
            return None
        kind = self.guard(lambda: self.choice(fields["type"], "timer type", ("TON", "TOF")))
        preset = self.guard(lambda: fields["preset"].as_duration("preset"))
        description = self.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        expr = self.expr(fields["input"], f"the input of timer {name!r}", GLOBAL_KINDS,
                         prev_only=PREV_ONLY)
        if kind is None or preset is None or expr is None:
            return None
        return Timer(name, kind, expr, preset, description, kpos)

    def _observer(self, name: str, node: YNode, kpos: SourcePos) -> Observer | None:
        what = f"observer {name!r}"
        if node.kind == "scalar":
            expr = self.expr(node, what, GLOBAL_KINDS, prev_only=PREV_ONLY)
            return Observer(name, "", expr=expr, pos=kpos) if expr else None
        fields = self.guard(lambda: node.check_keys(
            what, {"expr", "set", "reset", "initial", "description"}))
        if fields is None:
            return None
        description = self.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        initial = self.guard(lambda: fields["initial"].as_bool("initial"), False) \
            if "initial" in fields else False
        has_expr = "expr" in fields
        has_sr = "set" in fields or "reset" in fields
        if has_expr == has_sr:
            self.diag.error(node.pos, f"{what} needs either 'expr' or a 'set'/'reset' pair",
                            "expr: ... , or set: ... and reset: ...")
            return None
        if has_expr:
            expr = self.expr(fields["expr"], what, GLOBAL_KINDS, prev_only=PREV_ONLY)
            return Observer(name, description, expr=expr, initial=initial, pos=kpos) \
                if expr else None
        if "set" not in fields or "reset" not in fields:
            self.diag.error(node.pos, f"{what} has a {'set' if 'set' in fields else 'reset'} "
                            "but no " + ("reset" if "set" in fields else "set"),
                            "both set: and reset:")
            return None
        set_ = self.expr(fields["set"], f"the set of {what}", GLOBAL_KINDS,
                         prev_only=PREV_ONLY)
        reset = self.expr(fields["reset"], f"the reset of {what}", GLOBAL_KINDS,
                          prev_only=PREV_ONLY)
        if set_ is None or reset is None:
            return None
        return Observer(name, description, set=set_, reset=reset, initial=initial, pos=kpos)

    # -- control law ------------------------------------------------------------------------
    def _controls(self, pos: SourcePos, outputs: set[str],
                  memories: set[str]) -> tuple[dict[str, ControlLaw], str]:
        node = self.sections.get("control")
        if node is None:
            self.diag.error(pos, "the project has no control law", "a 'control:' section")
            return {}, ""
        mapping = self.guard(lambda: node.as_map("control"), {})
        if not mapping:
            if node.kind == "map":
                self.diag.error(node.pos, "the control section is empty",
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
            law = self._control_law(str(vname), vnode, positions[vname], outputs, memories)
            if law is not None:
                controls[str(vname)] = law
        default = next(iter(variants), "")
        return controls, str(default)

    def _control_law(self, name: str, node: YNode, kpos: SourcePos, outputs: set[str],
                     memories: set[str]) -> ControlLaw | None:
        what = f"control variant {name!r}"
        fields = self.guard(lambda: node.check_keys(
            what, {"description", "equations", "grafcet"}))
        if fields is None:
            return None
        if "equations" not in fields and "grafcet" not in fields:
            self.diag.error(node.pos, f"{what} has neither equations nor a grafcet",
                            "'equations:' and/or 'grafcet:'")
            return None
        description = self.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        grafcet = None
        steps: tuple[str, ...] = ()
        if "grafcet" in fields:
            steps = self._step_names(fields["grafcet"])
            grafcet = self._grafcet(fields["grafcet"], what, steps, outputs, memories)
        equations = self._equations(fields.get("equations"), what, steps, outputs, memories)
        driven_by_actions: dict[str, SourcePos] = {}
        if grafcet:
            for step in grafcet.steps:
                for action in step.actions:
                    if action.kind == "N":
                        driven_by_actions.setdefault(action.target, action.pos)
        for eq in equations:
            if eq.target in driven_by_actions:
                self.diag.error(eq.pos, f"{eq.target!r} is computed by an equation and also "
                                f"by a step action at {driven_by_actions[eq.target]}",
                                "one place that drives each output")
        law = ControlLaw(name, description, tuple(equations), grafcet, kpos)
        for out in sorted(outputs - law.driven_outputs()):
            self.diag.warning(kpos, f"output {out!r} is never driven by {what}; its "
                              "functional value stays 0")
        return law

    def _equations(self, node: YNode | None, what: str, steps: tuple[str, ...],
                   outputs: set[str], memories: set[str]) -> list[Equation]:
        if node is None:
            return []
        mapping = self.guard(lambda: node.as_map(f"the equations of {what}"), {})
        equations = []
        for target, enode in mapping.items():
            tpos = node.key_pos[target]
            target = str(target)
            if target not in outputs and target not in memories:
                kind = self.namespace.get(target)
                self.diag.error(tpos, f"equation target {target!r} is "
                                + (f"a {kind}" if kind else "not declared"),
                                "an output or a memory")
                continue
            ewhat = f"the equation of {target!r}"
            if enode.kind == "map":
                fields = self.guard(lambda n=enode, w=ewhat: n.check_keys(
                    w, {"set", "reset", "dominant"}, ["set", "reset"]))
                if fields is None:
                    continue
                dominant = "reset"
                if "dominant" in fields:
                    dominant = self.guard(lambda f=fields: self.choice(
                        f["dominant"], "dominant", ("set", "reset")), "reset")
                set_ = self.expr(fields["set"], f"the set of {target!r}", CONTROL_KINDS, steps)
                reset = self.expr(fields["reset"], f"the reset of {target!r}", CONTROL_KINDS,
                                  steps)
                if set_ and reset:
                    equations.append(Equation(target, None, set_, reset, dominant == "set",
                                              tpos))
            else:
                expr = self.expr(enode, ewhat, CONTROL_KINDS, steps)
                if expr:
                    equations.append(Equation(target, expr, pos=tpos))
        return equations

    def _step_names(self, node: YNode) -> tuple[str, ...]:
        if node.kind != "map" or "steps" not in node.value:
            return ()
        steps = node.value["steps"]
        if steps.kind != "map":
            return ()
        return tuple(f"X{int(k)}" for k in steps.value if is_step_number(k))

    def _grafcet(self, node: YNode, what: str, step_names: tuple[str, ...], outputs: set[str],
                 memories: set[str]) -> Grafcet | None:
        fields = self.guard(lambda: node.check_keys(
            f"the grafcet of {what}", {"steps", "transitions"}, ["steps", "transitions"]))
        if fields is None:
            return None
        step_map = self.guard(lambda: fields["steps"].as_map("steps"), {})
        steps: list[Step] = []
        numbered: dict[int, SourcePos] = {}
        for key, snode in step_map.items():
            spos = fields["steps"].key_pos[key]
            if not is_step_number(key):
                self.diag.error(spos, f"step {key!r} is not a step number",
                                "a whole number: steps are named X<number>")
                continue
            if int(key) in numbered:  # "7" and "007"
                self.diag.error(spos, f"step {int(key)} is defined twice (first at "
                                f"{numbered[int(key)]})", "each step number once")
                continue
            numbered[int(key)] = spos
            step = self._step(int(key), snode, spos, step_names, outputs, memories)
            if step:
                steps.append(step)
        if not step_map:
            self.diag.error(fields["steps"].pos, "the grafcet has no steps", "at least one step")
            return None
        if not any(s.initial for s in steps) and len(steps) == len(step_map):
            self.diag.error(fields["steps"].pos, "the grafcet has no initial step",
                            "at least one step with 'initial: true'")
        trans_nodes = self.guard(lambda: fields["transitions"].as_seq("transitions"), [])
        transitions = []
        for index, tnode in enumerate(trans_nodes, start=1):
            tr = self._transition(index, tnode, step_names)
            if tr:
                transitions.append(tr)
        grafcet = Grafcet(tuple(steps), tuple(transitions), node.pos)
        self._check_reachability(grafcet)
        return grafcet

    def _step(self, number: int, node: YNode, spos: SourcePos, steps: tuple[str, ...],
              outputs: set[str], memories: set[str]) -> Step | None:
        name = f"X{number}"
        if node.kind == "scalar" and node.value is None:
            return Step(number, name, False, "", (), spos)
        fields = self.guard(lambda: node.check_keys(
            f"step {number}", {"initial", "description", "actions"}))
        if fields is None:
            return None
        initial = self.guard(lambda: fields["initial"].as_bool("initial"), False) \
            if "initial" in fields else False
        description = self.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        actions = []
        if "actions" in fields:
            items = self.guard(lambda: fields["actions"].as_seq(
                f"the actions of step {number}"), [])
            for anode in items:
                action = self._action(anode, number, steps, outputs, memories)
                if action:
                    actions.append(action)
        return Step(number, name, initial, description, tuple(actions), spos)

    def _action(self, node: YNode, number: int, steps: tuple[str, ...], outputs: set[str],
                memories: set[str]) -> Action | None:
        what = f"an action of step {number}"
        if node.kind == "scalar":
            target = self.guard(lambda: node.as_str(what))
            if target is None:
                return None
            if target not in outputs:
                self._bad_target(node.pos, target, "a continuous action", "an output")
                return None
            return Action("N", target, None, node.pos)
        fields = self.guard(lambda: node.check_keys(what, {"do", "if", "set", "reset"}))
        if fields is None:
            return None
        kinds = [k for k in ("do", "set", "reset") if k in fields]
        if len(kinds) != 1:
            self.diag.error(node.pos, f"{what} must have exactly one of do, set, reset",
                            "'O', {do: O, if: cond}, {set: M} or {reset: M}")
            return None
        kind = kinds[0]
        target = self.guard(lambda: fields[kind].as_str(f"the target of {what}"))
        if target is None:
            return None
        if kind == "do":
            if target not in outputs:
                self._bad_target(fields[kind].pos, target, "a continuous action", "an output")
                return None
            condition = None
            if "if" in fields:
                condition = self.expr(fields["if"], f"the condition of {what}", CONTROL_KINDS,
                                      steps)
                if condition is None:
                    return None
            return Action("N", target, condition, node.pos)
        if "if" in fields:
            self.diag.error(fields["if"].pos, "a stored action takes no condition",
                            "{set: M} or {reset: M}")
            return None
        if target not in memories:
            self._bad_target(fields[kind].pos, target, f"a stored action ({kind})",
                             "a memory (drive outputs with continuous actions or equations)")
            return None
        return Action("S" if kind == "set" else "R", target, None, node.pos)

    def _bad_target(self, pos: SourcePos, target: str, what: str, expected: str) -> None:
        kind = self.namespace.get(target)
        self.diag.error(pos, f"{what} targets {target!r}, which is "
                        + (f"a {kind}" if kind else "not declared"), expected)

    def _transition(self, index: int, node: YNode, steps: tuple[str, ...]) -> Transition | None:
        what = f"transition {index}"
        fields = self.guard(lambda: node.check_keys(
            what, {"from", "to", "when", "description"}, ["from", "to", "when"]))
        if fields is None:
            return None
        sources = self._step_refs(fields["from"], what, steps)
        targets = self._step_refs(fields["to"], what, steps)
        description = self.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        receptivity = self.expr(fields["when"], f"the receptivity of {what}", CONTROL_KINDS,
                                steps)
        if sources is None or targets is None or receptivity is None:
            return None
        return Transition(index, sources, targets, receptivity, description, node.pos)

    def _step_refs(self, node: YNode, what: str, steps: tuple[str, ...]) -> tuple[str, ...] | None:
        items = node.value if node.kind == "seq" else [node]
        refs = []
        for item in items:
            if item.kind != "scalar" or not is_step_number(item.value):
                self.diag.error(item.pos, f"{what} refers to {item.raw!r}, not a step number",
                                "a step number or a list of step numbers")
                return None
            name = f"X{int(item.value)}"
            if name not in steps:
                self.diag.error(item.pos, f"{what} refers to step {item.value}, which is not "
                                "declared", "one of the steps: " + ", ".join(
                                    s[1:] for s in steps))
                return None
            refs.append(name)
        if not refs:
            self.diag.error(node.pos, f"{what} has no step", "a step number")
            return None
        return tuple(refs)

    def _check_reachability(self, grafcet: Grafcet) -> None:
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
                self.diag.warning(step.pos, f"step {step.number} can never become active "
                                  "(no path of transitions from an initial step)")

    # -- constraints ------------------------------------------------------------------------
    def _constraints(self) -> list[Constraint]:
        out: list[Constraint] = []
        seen: dict[str, SourcePos] = {}
        items = self.section_items("constraints")
        if len(items) > MAX_CONSTRAINTS:
            self.diag.error(self.section_pos.get("constraints", items[0][2]),
                            f"the project has {len(items):,} safety constraints",
                            f"at most {MAX_CONSTRAINTS:,} (a limit of plchmi)")
            return out
        for name, node, kpos in items:
            name = str(name)
            if name in seen:
                continue  # YAML duplicate keys are already refused
            seen[name] = kpos
            problem = name_problem(name)
            if problem is not None:
                self.diag.error(kpos, f"{name!r} is not a valid constraint name"
                                if problem == "is not a valid name"
                                else f"constraint name {name[:40]!r} {problem}", NAME_HINT)
                continue
            constraint = self._constraint(name, node, kpos)
            if constraint:
                out.append(constraint)
        return out

    def _constraint(self, name: str, node: YNode, kpos: SourcePos) -> Constraint | None:
        what = f"constraint {name!r}"
        description = ""
        if node.kind == "map":
            fields = self.guard(lambda: node.check_keys(what, {"expr", "description"},
                                                        ["expr"]))
            if fields is None:
                return None
            if "description" in fields:
                description = self.guard(lambda: fields["description"].as_str("description"),
                                         "")
            enode = fields["expr"]
        else:
            enode = node
        expr = self.expr(enode, what, CONSTRAINT_KINDS,
                         context="in a safety constraint (the filter may only read inputs, "
                         "outputs, timers, observers and flags)")
        if expr is None:
            return None
        try:
            literals = monomial_literals(expr)
        except NotMonomial as exc:
            self.diag.error(expr.pos_of(exc.node), f"{what} is not a monomial: {exc.reason}",
                            "a product of literals such as 'C and not fsc and prev(C)'")
            return None
        if literals is None:
            self.diag.error(expr.pos, f"{what} can never be true (it holds a variable and its "
                            "negation, or False), so it constrains nothing",
                            "a satisfiable product of literals")
            return None
        outputs = []
        for lit in literals:
            if lit.depth == 0 and self.namespace.get(lit.name) == "output":
                outputs.append(lit.name)
        if not outputs:
            self.diag.error(expr.pos, f"{what} has no output at the current scan, so the "
                            "filter cannot enforce it",
                            "at least one output without prev(), e.g. 'C and fsc'")
            return None
        kind = "simple" if len(outputs) == 1 else "combined"
        positive = None
        if kind == "simple":
            positive = next(lit.positive for lit in literals
                            if lit.depth == 0 and lit.name == outputs[0])
        return Constraint(name, expr, literals, kind, tuple(outputs), description, kpos,
                          positive)

    # -- plant ------------------------------------------------------------------------------
    def _plant(self, pos: SourcePos, inputs: list[Variable],
               outputs: list[Variable]) -> PlantSpec:
        node = self.sections.get("plant")
        if node is None:
            self.diag.error(pos, "the project has no plant", "a 'plant:' section (kind: sim)")
            return PlantSpec("sim")
        fields = self.guard(lambda: node.check_keys(
            "plant", {"kind", "model", "params", "ports", "devices", "host", "port", "unit",
                      "timeout", "read_gap", "write_refresh"}, ["kind"]))
        if fields is None:
            return PlantSpec("sim")
        kind = self.guard(lambda: self.choice(fields["kind"], "plant kind", ("sim", "modbus")),
                          "sim")
        devices: list[DeviceSpec] = []
        self._links: list[tuple[str, str, str, SourcePos, tuple[str, ...]]] = []
        if "model" in fields and "devices" in fields:
            self.diag.error(fields["devices"].pos, "the plant has both 'model' and 'devices'",
                            "'model' for one device, or 'devices' for several")
        elif "model" in fields:
            device = self._device(None, node, fields, inputs, outputs)
            if device:
                devices.append(device)
        elif "devices" in fields:
            dmap = self.guard(lambda: fields["devices"].as_map("devices"), {})
            for dname, dnode in dmap.items():
                dfields = self.guard(lambda n=dnode, d=dname: n.check_keys(
                    f"device {d!r}", {"model", "params", "ports"}, ["model"]))
                if dfields is None:
                    continue
                device = self._device(str(dname), dnode, dfields, inputs, outputs)
                if device:
                    devices.append(device)
        elif kind == "sim":
            self.diag.error(node.pos, "a simulated plant needs a model",
                            "'model: valve' or a 'devices:' mapping")
        self._check_links(devices)
        if kind == "sim":
            bound = {var for d in devices for var in d.ports.values()}
            for var in inputs:
                if var.name not in bound:
                    self.diag.warning(var.pos, f"input {var.name!r} is not connected to the "
                                      "simulated plant; it reads 0 unless set by the operator")
        spec_kwargs: dict[str, Any] = {}
        if "host" in fields:
            spec_kwargs["host"] = self.guard(lambda: fields["host"].as_str("host"), "127.0.0.1")
        if "port" in fields:
            spec_kwargs["port"] = self.guard(lambda: fields["port"].as_int("port", 1, 65535),
                                             502)
        if "unit" in fields:
            spec_kwargs["unit"] = self.guard(lambda: fields["unit"].as_int("unit", 0, 255), 1)
        if "timeout" in fields:
            spec_kwargs["timeout_us"] = self.guard(
                lambda: fields["timeout"].as_duration("timeout"), 1_000_000)
        if "read_gap" in fields:
            spec_kwargs["read_gap"] = self.guard(
                lambda: fields["read_gap"].as_int("read_gap", 0, 2000), 8)
        if "write_refresh" in fields:
            spec_kwargs["write_refresh_us"] = self.guard(
                lambda: fields["write_refresh"].as_duration("write_refresh", allow_zero=True),
                1_000_000)
        if kind == "modbus":  # a real device: every input and output needs its address
            for var in (*inputs, *outputs):
                if var.address is None:
                    self.diag.error(var.pos, f"{var.kind} {var.name!r} has no plant address, "
                                    "which a Modbus plant needs for every input and output",
                                    "address: di:N or coil:N (or ir:N.B, hr:N.B)")
        return PlantSpec(kind, tuple(devices), pos=node.pos, **spec_kwargs)

    def _device(self, name: str | None, node: YNode, fields: dict[str, YNode],
                inputs: list[Variable], outputs: list[Variable]) -> DeviceSpec | None:
        model_name = self.guard(lambda: fields["model"].as_str("model"))
        if model_name is None:
            return None
        model = DEVICE_MODELS.get(model_name)
        if model is None:
            self.diag.error(fields["model"].pos, f"unknown plant model {model_name!r}",
                            "one of " + ", ".join(sorted(DEVICE_MODELS)))
            return None
        params: dict[str, Any] = {}
        if "params" in fields:
            pmap = self.guard(lambda: fields["params"].check_keys(
                f"the parameters of {model_name}", set(model.params)), {})
            for pname, pnode in pmap.items():
                value = self.guard(lambda s=model.params[pname], n=pnode, p=pname:
                                   _param_value(s, n, p))
                if value is not None:
                    params[pname] = value
                    if model.params[pname].kind == "device":
                        self._links.append((name or model_name, pname, value, pnode.pos,
                                            model.params[pname].choices))
            for pname, message, expected in model.param_problems(params):
                self.diag.error(pmap[pname].pos if pname in pmap else fields["params"].pos,
                                f"{model_name} parameter {pname!r}: {message}", expected)
        input_names = {v.name for v in inputs}
        output_names = {v.name for v in outputs}
        # A port binds by identity to a project variable of the same name unless 'ports:'
        # says otherwise; a port with no such variable is simply not connected.
        ports = {p: p for p in model.sensors if p in input_names}
        ports.update({p: p for p in model.actuators if p in output_names})
        if "ports" in fields:
            pmap = self.guard(lambda: fields["ports"].check_keys(
                f"the ports of {model_name}", {*model.sensors, *model.actuators}), {})
            for port, vnode in pmap.items():
                var = self.guard(lambda n=vnode: n.as_str("a port's variable"))
                if var is not None:
                    ports[port] = var
        for port, var in ports.items():
            want_input = port in model.sensors
            ok = var in input_names if want_input else var in output_names
            if not ok:
                pos = fields["ports"].value[port].pos if "ports" in fields and \
                    port in fields["ports"].value else fields["model"].pos
                self.diag.error(pos, f"{model_name} port {port!r} is bound to {var!r}, which is "
                                f"not an {'input' if want_input else 'output'} of the project",
                                f"an {'input' if want_input else 'output'} name (map it under "
                                "'ports:')")
        for port in model.actuators:
            if port not in ports:
                self.diag.warning(fields["model"].pos, f"{model_name} actuator {port!r} is not "
                                  "bound to any output; it is never driven")
        return DeviceSpec(name or model_name, model_name, params, ports, node.pos)

    def _check_links(self, devices: list[DeviceSpec]) -> None:
        """A "device" parameter (a pipe to another device) names a device of the right model."""
        models = {d.name: d.model for d in devices}
        for owner, param, target, pos, allowed in self._links:
            if target == owner:
                self.diag.error(pos, f"device {owner!r}: parameter {param!r} names the device "
                                "itself", "another device of the plant")
            elif target not in models:
                self.diag.error(pos, f"device {owner!r}: parameter {param!r} names {target!r}, "
                                "which is not a device of the plant",
                                "one of " + ", ".join(sorted(models)))
            elif allowed and models[target] not in allowed:
                self.diag.error(pos, f"device {owner!r}: parameter {param!r} names {target!r}, "
                                f"a {models[target]}", "a device of model " + " or ".join(allowed))

    def _check_addresses(self, inputs: list[Variable], outputs: list[Variable]) -> None:
        used: dict[tuple[str, int, int | None], Variable] = {}
        for var in (*inputs, *outputs):
            if var.address is None:
                continue
            key = (var.address.table, var.address.index, var.address.bit)
            if key in used:
                self.diag.error(var.pos, f"{var.name!r} uses address {var.address}, already "
                                f"used by {used[key].name!r}", "one variable per address")
            whole = (var.address.table, var.address.index, None)
            if var.address.bit is not None and whole in used:
                self.diag.error(var.pos, f"{var.name!r} overlaps {used[whole].name!r}",
                                "distinct addresses")
            used[key] = var
            if var.kind == "output" and var.address.table in READ_ONLY_TABLES:
                self.diag.error(var.pos, f"output {var.name!r} is mapped to a read-only table "
                                f"({TABLES[var.address.table]})", "coil or hr")


def _param_value(spec: ParamSpec, node: YNode, name: str) -> Any:
    if spec.kind == "duration":
        return node.as_duration(f"parameter {name!r}")
    if spec.kind == "bool":
        return node.as_bool(f"parameter {name!r}")
    if spec.kind == "device":
        return node.as_str(f"parameter {name!r} (a device name)")
    if spec.kind == "choice":
        value = node.as_str(f"parameter {name!r}")
        if value not in spec.choices:
            raise NodeError(node.pos, f"parameter {name!r} is {value!r}",
                            "one of " + ", ".join(spec.choices))
        return value
    number = node.as_number(f"parameter {name!r}")
    low, high = spec.minimum, spec.maximum
    if (low is not None and number < low) or (high is not None and number > high):
        if low is not None and high is not None:
            expected = f"a number from {low:g} to {high:g}"
        elif low is not None:
            expected = f"a number of at least {low:g}"
        else:
            expected = f"a number of at most {high:g}"
        raise NodeError(node.pos, f"parameter {name!r} is {number:g}, out of range", expected)
    return number


_ADDRESS_RE = re.compile(r"(coil|di|hr|ir):([0-9]{1,6})(?:\.([0-9]{1,3}))?\Z")


def parse_address(node: YNode, kind: str) -> PlantAddress:
    text = node.as_str("address")
    match = _ADDRESS_RE.match(text.strip())
    hint = "TABLE:INDEX with TABLE coil, di, hr or ir (e.g. di:0, coil:3, hr:10.4)"
    if not match:
        raise NodeError(node.pos, f"address {text!r} is not a plant address", hint)
    table, index, bit = match.group(1), int(match.group(2)), match.group(3)
    if index > 65535:
        raise NodeError(node.pos, f"address index {index} is out of range", "0 to 65535")
    if table in ("hr", "ir"):
        if bit is None:
            raise NodeError(node.pos, f"a {TABLES[table]} address needs a bit number",
                            f"{table}:{index}.BIT with BIT 0 to 15")
        if int(bit) > 15:
            raise NodeError(node.pos, f"bit {bit} is out of range", "a bit from 0 to 15")
        return PlantAddress(table, index, int(bit))
    if bit is not None:
        raise NodeError(node.pos, f"a {TABLES[table]} address has no bit", f"{table}:{index}")
    return PlantAddress(table, index)

"""Load and validate a project folder.

A project is a folder with a `project.yaml` (and optional files it `include`s). Loading is
two passes: the first declares every name (I/O, memories, timers, observers), the second
parses every expression against those names. Errors are collected, not thrown one at a time,
and each names its file, line and column. The result is an immutable :class:`Project`.
"""

from __future__ import annotations

from pathlib import Path

from hmi.errors import ProjectError, SourcePos, display_path, excerpt
from hmi.limits import MAX_NAME_CHARS, MIN_SCAN_PERIOD_US
from hmi.project.campaign import parse_campaign
from hmi.project.components import load_components, merge_texts
from hmi.project.confine import Refused, confined_file, project_roots
from hmi.project.constraints import parse_constraints
from hmi.project.control import parse_controls
from hmi.project.diagnosers import declare_diagnoser_names, parse_diagnosers
from hmi.project.high_level import parse_high_level
from hmi.project.model import (
    MAX_SOLVER_BUDGET,
    MIN_SOLVER_BUDGET,
    POLICIES,
    ComponentInstance,
    PolicyName,
    Project,
    SolverName,
)
from hmi.project.monitors import parse_monitors
from hmi.project.plant import parse_plant
from hmi.project.reader import ProjectReader
from hmi.project.recovery import RECOVERY_SITUATIONS, parse_recovery
from hmi.project.scenarios import parse_scenarios
from hmi.project.variables import (
    check_addresses,
    declare_items,
    read_observer,
    read_timer,
    read_variables,
)
from hmi.project.yamlnodes import YNode
from hmi.timefmt import format_duration

PROJECT_FILE = "project.yaml"

TOP_KEYS = {
    "name", "description", "scan_period", "include", "inputs", "outputs", "memories",
    "timers", "observers", "control", "constraints", "policy", "solver", "solver_budget",
    "plant", "explanations", "monitors", "scenarios", "diagnosers", "campaign", "components",
    "recovery", "high_level",
}



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
        return _confined(candidate)
    if p.exists():
        return _confined(p)
    raise ProjectError.single(SourcePos(shown), "no such project folder or file",
                              f"a folder holding {PROJECT_FILE}")


def _confined(file: Path) -> Path:
    """`file`, if it lies in its own folder once symlinks are followed: the project file is
    confined like every file it names (a project.yaml that is a symlink to /etc/passwd, or to
    a secret elsewhere, is refused without being opened, so nothing of it is ever quoted)."""
    try:
        confined_file(file.parent, file.name, project_roots(file.parent), "the project file")
    except Refused as exc:
        raise ProjectError.single(SourcePos(display_path(file)), exc.message,
                                  exc.expected) from None
    return file


def is_diagnosers_file(choice: str | None) -> bool:
    """Whether a `--diagnoser` choice names a file of diagnosers rather than a variant."""
    return choice is not None and choice.lower().endswith((".yaml", ".yml"))


def load_project(path: str | Path, diagnoser_variant: str | None = None) -> Project:
    """Load, validate and return the project at `path`; raise ProjectError listing problems.

    `diagnoser_variant` loads that variant of every diagnoser declaring `variants:` (by
    default each loads its first); a path ending in .yaml loads the diagnosers of that file
    (a `diagnosers:` section, e.g. one `plchmi diagnose --build` wrote) in place of the
    project's of the same names."""
    loader = ProjectLoader(resolve_project_file(path))
    if is_diagnosers_file(diagnoser_variant):
        loader.diagnosers_file = Path(str(diagnoser_variant))
    else:
        loader.diagnoser_variant = diagnoser_variant
    return loader.load()


class ProjectLoader(ProjectReader):
    """Reads project.yaml and its includes, then each section, into a :class:`Project`."""

    def __init__(self, file: Path):
        super().__init__(file)
        self.pending_includes: list[YNode] = []
        self.diagnosers_file: Path | None = None

    # -- top level --------------------------------------------------------------------------
    def load(self) -> Project:
        from hmi.project.yamlcompose import load_yaml  # PyYAML: not for a project read back

        display = display_path(self.file)
        root = load_yaml(self.file, display)
        self.files.append(display)
        top = self.guard(lambda: root.as_map("a project file"))
        if top is None:
            self.diag.raise_if_errors()
        self._collect_sections(root, top, display, allow_include=True)
        for item in self.pending_includes:
            self._include(item)
        if self.diagnosers_file is not None:
            self._override_diagnosers(self.diagnosers_file)
        self.diag.raise_if_errors()
        return self._build(root)

    def _override_diagnosers(self, file: Path) -> None:
        """The diagnosers of `file` (given on the command line, not by the project) replace
        the project's of the same names; the project's others stay, in their order."""
        from hmi.project.yamlcompose import load_yaml
        display = display_path(file)
        if not file.is_file():
            self.diag.error(SourcePos(display), "no such diagnosers file",
                            "a YAML file holding a 'diagnosers:' section")
            return
        try:
            root = load_yaml(file, display)
        except ProjectError as exc:
            self.diag.items.extend(exc.errors)
            return
        top = self.guard(lambda: root.as_map("a diagnosers file"))
        if top is None:
            return
        for key in top:
            if key != "diagnosers":
                self.diag.error(root.key_pos[key], f"a diagnosers file holds only the "
                                f"'diagnosers:' section, not {excerpt(key)}",
                                "diagnosers: {NAME: {...}}")
        node = top.get("diagnosers")
        if node is None:
            self.diag.error(root.pos, "this diagnosers file has no 'diagnosers:' section",
                            "diagnosers: {NAME: {...}}")
            return
        if node.kind != "map":
            self.diag.error(node.pos, "'diagnosers:' must be a mapping", "NAME: {...}")
            return
        self.files.append(display)
        old = self.sections.get("diagnosers")
        if old is not None and old.kind == "map":
            value = {**old.value, **node.value}
            key_pos = {**old.key_pos, **node.key_pos}
            node = YNode("map", value, node.pos, node.tag, key_pos)
        self.sections["diagnosers"] = node
        self.section_pos["diagnosers"] = root.key_pos["diagnosers"]

    def _collect_sections(self, root: YNode, top: dict[str, YNode], display: str,
                          allow_include: bool) -> None:
        for key, node in top.items():
            kpos = root.key_pos[key]
            if key not in TOP_KEYS:
                self.diag.error(kpos, f"unknown section {excerpt(key)}",
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
        from hmi.project.yamlcompose import load_yaml
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
        elif len(name) > MAX_NAME_CHARS:
            self.diag.error(s["name"].pos, f"the project's name is {len(name):,} characters "
                            f"long, more than {MAX_NAME_CHARS}",
                            f"a name of at most {MAX_NAME_CHARS} characters")
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

        inputs = read_variables(self, "inputs", "input",
                                {"description", "address", "device", "fault"})
        outputs = read_variables(self, "outputs", "output",
                                  {"description", "address", "safe", "device"})
        memories = read_variables(self, "memories", "memory", {"description", "initial"})
        if "inputs" not in s:
            self.diag.error(pos, "the project has no inputs", "an 'inputs:' section")
        if "outputs" not in s:
            self.diag.error(pos, "the project has no outputs", "an 'outputs:' section")
        # Component instances add timers, observers, constraints, diagnosers and explanations,
        # read below with the project's own (hmi/project/components.py).
        self.components = load_components(self)
        self.files.extend(self.components.files)
        timer_nodes = declare_items(self, "timers", "timer")
        observer_nodes = declare_items(self, "observers", "observer")
        declare_diagnoser_names(self)  # def_<partition> flags, <sensor>_filter names

        timers = [t for t in (read_timer(self, n, k, p) for n, k, p in timer_nodes) if t]
        observers = [o for o in (read_observer(self, n, k, p) for n, k, p in observer_nodes) if o]
        controls, default_control = parse_controls(self, pos, {v.name for v in outputs},
                                                   {m.name for m in memories}, period)
        constraints = parse_constraints(self)
        policy: PolicyName = "correct"
        if "policy" in s:
            policy = self.guard(lambda: self.choice(s["policy"], "policy", POLICIES), policy)
        solver: SolverName = "exact"
        if "solver" in s:
            solver = self.guard(lambda: self.choice(s["solver"], "solver", ("exact", "paper")),
                                solver)
        solver_budget = None
        if "solver_budget" in s:
            solver_budget = self.guard(lambda: s["solver_budget"].as_int(
                "solver_budget", MIN_SOLVER_BUDGET, MAX_SOLVER_BUDGET), None)
        plant = parse_plant(self, pos, inputs, outputs)
        check_addresses(self, inputs, outputs)
        monitors = parse_monitors(self, period)  # stopwatch monitors: hmi/project/monitors.py
        scenarios = parse_scenarios(self, plant)
        diagnosers = parse_diagnosers(self)  # hmi/project/diagnosers.py
        high_level = parse_high_level(self, diagnosers)  # hmi/project/high_level.py
        campaign = parse_campaign(self, plant)  # hmi/project/campaign.py
        recovery = parse_recovery(self, constraints, outputs, observers)  # hmi/project/recovery.py
        texts = None
        sources: list[tuple[ComponentInstance | None, YNode]] = [*self.components.explanations]
        if "explanations" in s:
            sources.append((None, s["explanations"]))
        if sources:
            from hmi.project.explanations import parse_explanations
            known = {"constraints": {c.name for c in constraints},
                     "monitors": {m.name for m in monitors},
                     "labels": self.declared_labels,
                     "partitions": self.declared_partitions,
                     "situations": {f"{prefix}_{r.name}" for r in recovery
                                    for prefix in RECOVERY_SITUATIONS}
                     | {f"step_{step.name}" for law in controls.values() if law.grafcet
                        for step in law.grafcet.steps if step.supervision_us is not None}
                     | {f"fault_{v.name}" for v in inputs if v.fault}}
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
            solver_budget=solver_budget, diagnosers=diagnosers, high_level=high_level,
            monitors=monitors,
            scenarios=scenarios, campaign=campaign, explanations=texts, recovery=recovery,
            components=tuple(self.components.instances), warnings=tuple(self.diag.warnings),
            check_sections=((tuple(self.components.check_lines()),)
                            if self.components.instances else ()),
            diagnosers_file=str(self.diagnosers_file) if self.diagnosers_file else "",
        )
        return project

"""What the project's sections read a project with: its sections, its names, its diagnostics.

The loader (hmi/project/loader.py) reads the top level and hands this reader to each section
(hmi/project/components.py, diagnosers.py, monitors.py, scenarios.py, campaign.py...): the
one public API a section uses to read its YAML nodes, declare and check names, parse an
expression against them, and report a problem at its file, line and column without stopping
(errors are collected, so one load lists them all).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hmi.errors import Diagnostics, SourcePos
from hmi.limits import MAX_TOTAL_EXPR_CHARS, MAX_VARIABLES
from hmi.logic.expr import Expr, ExprError, Var, check_names, parse_expr, walk
from hmi.logic.names import NAME_HINT, RESERVED, STEP_RE, name_problem
from hmi.project.model import ComponentInstance
from hmi.project.yamlnodes import NodeError, YNode, expr_start


class ProjectReader:
    """The state a load shares between sections, and the helpers they read it with."""

    def __init__(self, file: Path):
        self.file = file
        self.folder = file.parent
        self.diag = Diagnostics()
        self.namespace: dict[str, str] = {}  # name -> kind
        self.declared_at: dict[str, SourcePos] = {}
        self.sections: dict[str, YNode] = {}
        self.section_pos: dict[str, SourcePos] = {}
        self.files: list[str] = []
        self.components = Components()  # component instances (hmi/project/components.py)
        self.declared_labels: set[str] = set()  # by every diagnoser, valid or not
        self.declared_partitions: set[str] = set()
        self.diagnoser_variant: str | None = None  # --diagnoser NAME
        self.too_many_names = False
        self.expr_chars = 0  # characters of every expression read, for MAX_TOTAL_EXPR_CHARS
        self.too_much_expression = False
        self._with_steps: dict[tuple[tuple[str, ...], int],  # expr()
                               tuple[dict[str, str], frozenset[str]]] = {}

    # -- reading ----------------------------------------------------------------------------
    def guard(self, fn: Callable[..., Any], default: Any = None) -> Any:
        """Run one parsing step; a NodeError becomes a diagnostic and the default is used."""
        try:
            return fn()
        except NodeError as exc:
            self.diag.items.append(exc.diagnostic)
        except ExprError as exc:
            self.diag.error(exc.pos, exc.message, exc.expected)
        return default

    def declare(self, name: str, kind: str, pos: SourcePos) -> bool:
        problem = name_problem(name)
        if problem is not None:
            shown = repr(name) if len(name) <= 40 else repr(name[:40] + "...")
            self.diag.error(pos, f"{shown} {problem}" if problem != "is not a valid name"
                            else f"{shown} is not a valid name", NAME_HINT)
            return False
        if len(self.namespace) >= MAX_VARIABLES:
            if not self.too_many_names:  # reported once, at the first name past the limit
                self.too_many_names = True
                self.diag.error(pos, f"more than {MAX_VARIABLES:,} names are declared",
                                f"at most {MAX_VARIABLES:,} inputs, outputs, memories, timers "
                                "and observers (a limit of plchmi)")
            return False
        if name in RESERVED:
            self.diag.error(pos, f"{name!r} is a reserved word", "another name")
            return False
        if STEP_RE.match(name):
            self.diag.error(pos, f"{name!r} looks like a GRAFCET step variable",
                            "a name not of the form X<number> (reserved for steps)")
            return False
        if name.startswith("def_"):
            self.diag.error(pos, f"{name!r} starts with def_, reserved for partition flags",
                            "another name")
            return False
        if name in self.namespace:
            first = self.declared_at[name]
            self.diag.error(pos, f"{name!r} is already declared as {self.namespace[name]} "
                            f"at {first}", "unique names across inputs, outputs, memories, "
                            "timers and observers")
            return False
        self.namespace[name] = kind
        self.declared_at[name] = pos
        return True

    def expr(self, node: YNode, what: str, kinds: set[str], steps: Iterable[str] = (),
             prev_only: AbstractSet[str] = frozenset(), context: str = "") -> Expr | None:
        """Parse and name-check one expression; report problems and return None on error."""
        def parse() -> Expr | None:
            text = node.as_text(what)
            if not self._within_expression_total(node, text):
                return None
            return parse_expr(text, expr_start(node, text))
        parsed = self.guard(parse)
        if parsed is None:
            return None
        parsed = self.components.localise(node, parsed)  # a component's names, per instance
        steps = tuple(steps)
        namespace: dict[str, str] = self.namespace
        step_set: frozenset[str] = frozenset()
        if steps:  # the names with a law's steps: built once per law, not per expression
            key = (steps, len(self.namespace))
            if key not in self._with_steps:
                self._with_steps[key] = ({**namespace, **dict.fromkeys(steps, "step")},
                                         frozenset(steps))
            namespace, step_set = self._with_steps[key]
        problems = check_names(parsed, namespace, step_set, kinds, context or f"in {what}")
        for var in (n for n in walk(parsed.root) if isinstance(n, Var)):
            kind = namespace.get(var.name)
            if var.depth == 0 and kind in prev_only:
                kind_text = {"flag": "a partition flag", "filtered": "a filtered sensor"}.get(
                    kind or "", f"an {kind}")
                problems.append(ExprError(
                    parsed.pos_of(var), f"{var.name!r} is {kind_text}: its value at this scan "
                    f"is not known yet when {what} is computed",
                    f"prev({var.name}), the value written at the previous scan"))
        for problem in problems:
            self.diag.error(problem.pos, problem.message, problem.expected)
        return None if problems else parsed

    def _within_expression_total(self, node: YNode, text: str) -> bool:
        """Count `text` into the project's expressions in all (each use of a YAML alias,
        each component instance counted as the copy it is); past MAX_TOTAL_EXPR_CHARS, one
        error at the expression that passes it and nothing more is parsed. What a project
        costs to compile, check and run grows with that total, not with its file's size."""
        self.expr_chars += len(text)
        if self.expr_chars <= MAX_TOTAL_EXPR_CHARS:
            return True
        if not self.too_much_expression:
            self.too_much_expression = True
            self.diag.error(node.pos, f"the project's expressions pass "
                            f"{MAX_TOTAL_EXPR_CHARS:,} characters in all here (each use of a "
                            "YAML alias and each component instance counted as a copy)",
                            f"at most {MAX_TOTAL_EXPR_CHARS:,} characters of expressions in a "
                            "project (a limit of plchmi)")
        return False

    def section_items(self, key: str) -> list[tuple[str, YNode, SourcePos]]:
        """(name, node, key position) of a section's items: the component instances' first
        (in instance order; the project's own timers and observers may read theirs), then
        the project's."""
        instances = list(self.components.items.get(key, ()))
        node = self.sections.get(key)
        if node is None:
            return instances
        if node.kind == "scalar" and node.value is None:
            return instances
        mapping = self.guard(lambda: node.as_map(key), {})
        return instances + [(name, item, node.key_pos[name]) for name, item in mapping.items()]

    @staticmethod
    def choice(node: YNode, what: str, choices: Iterable[str]) -> str:
        value = node.as_str(what)
        choices = tuple(choices)
        if value not in choices:
            raise NodeError(node.pos, f"{what} {value!r} is not known", "one of "
                            + ", ".join(choices))
        return value


@dataclass
class Components:
    """The component instances read so far and the sections they add, ready for the loader:
    hmi/project/components.py fills it, `ProjectReader.expr` renames an instance's
    expressions with it."""

    instances: list[ComponentInstance] = field(default_factory=list)
    items: dict[str, list[tuple[str, YNode, SourcePos]]] = field(default_factory=dict)
    explanations: list[tuple[ComponentInstance, YNode]] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    # id(YNode) -> (the node, its instance): the node is kept so that its id is never reused
    scopes: dict[int, tuple[YNode, ComponentInstance]] = field(default_factory=dict)

    def localise(self, node: YNode, expr: Expr) -> Expr:
        """An expression read from `node`, renamed if the node belongs to an instance."""
        entry = self.scopes.get(id(node))
        if entry is None or entry[0] is not node:
            return expr
        return entry[1].rename_expr(expr)

    def check_lines(self) -> list[str]:
        """The `plchmi check` section: each instance, its bindings and the names it adds."""
        lines = [f"Components ({len(self.instances)} instance"
                 f"{'s' if len(self.instances) != 1 else ''})"]
        for inst in self.instances:
            comp = inst.component
            lines.append(f"  {inst.name}  {comp.name} ({comp.file})  device {inst.device}")
            lines.append("      bind " + ", ".join(f"{k}={v}" for k, v in inst.bind.items()))
            groups: dict[str, list[str]] = {}
            for name, what, _ in inst.declared():
                groups.setdefault(what, []).append(name)
            lines.append("      declares " + "; ".join(
                f"{what}{'s' if len(names) > 1 else ''} {', '.join(names)}"
                for what, names in groups.items()))
        return lines

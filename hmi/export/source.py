"""Everything the export reads from a loaded project, in one place.

The builders never reach into `Project` themselves, they call these functions, so a change
of the project model (a section's fields renamed or retyped) is one edit here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hmi.logic.expr import Expr, Node, Var, walk
from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import (
    Constraint,
    DiagnoserSpec,
    Observer,
    PlantAddress,
    Project,
    TaskMonitor,
    Timer,
    Variable,
)
from hmi.project.monitors import monitors_of
from hmi.studies.filter_analysis import analyse


def name(project: Project) -> str:
    return project.name


def description(project: Project) -> str:
    return project.description


def source_files(project: Project) -> tuple[str, ...]:
    """The project's files relative to its folder (an export must not depend on the cwd)."""
    folder = project.path if project.path.is_dir() else project.path.parent
    return tuple(os.path.relpath(f, folder) for f in project.files)


def scan_period_us(project: Project) -> int:
    return project.scan_period_us


def policy(project: Project) -> str:
    return project.policy


def solver(project: Project) -> str:
    return project.solver


def inputs(project: Project) -> tuple[Variable, ...]:
    return project.inputs


def outputs(project: Project) -> tuple[Variable, ...]:
    return project.outputs


def timers(project: Project) -> tuple[Timer, ...]:
    return project.timers


def observers(project: Project) -> tuple[Observer, ...]:
    return project.observers


def constraints(project: Project) -> tuple[Constraint, ...]:
    return project.constraints


def diagnosers(project: Project) -> tuple[DiagnoserSpec, ...]:
    return diagnosers_of(project)


def monitors(project: Project) -> tuple[TaskMonitor, ...]:
    return monitors_of(project)


def address(variable: Variable) -> PlantAddress | None:
    return variable.address


def refs(expr: Expr | Node) -> list[tuple[str, int]]:
    """The (name, depth) pairs an expression reads, in first-seen order."""
    root = expr.root if isinstance(expr, Expr) else expr
    seen: dict[tuple[str, int], None] = {}
    for node in walk(root):
        if isinstance(node, Var):
            seen.setdefault((node.name, node.depth))
    return list(seen)


@dataclass(frozen=True)
class FilterBound:
    """What the static checks (`plchmi check`) say about the corrector's search."""

    worst_distance: int  # the worst-case Hamming distance over situations and FOVs
    proven: bool  # exhaustive over every situation and every functional vector
    combined_outputs: int  # outputs that appear in a combined constraint
    situations: int
    unreachable: int
    no_solution: int  # situations in which no safe vector exists


def filter_bound(project: Project) -> FilterBound:
    a = analyse(project)
    return FilterBound(a.worst_distance, a.exhaustive and a.worst_exhaustive,
                       len(a.combined_outputs), a.situations, a.unreachable,
                       a.no_solution_count)

"""``plchmi check PROJECT``: load and validate a project, print its summary."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from hmi.cli.common import load
from hmi.cli.options import diagnoser_arg, project_arg
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from collections.abc import Sequence

    from hmi.cli.common import Subparsers
    from hmi.errors import Diagnostic
    from hmi.project.model import Constraint, ControlLaw, Project


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("check", help="load and validate a project, print a summary")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--closed-loop", action="store_true",
                   help="compute the diagnosability on the closed loop if it is not cached "
                   "(as plchmi diagnose does)")


def cmd_check(args: argparse.Namespace) -> int:
    from hmi.studies.filter_analysis import analyse
    project = load(args.project, getattr(args, "diagnoser", None))
    sections = [analyse(project).lines(len(project.outputs))]
    if project.plant.kind == "modbus":
        from hmi.plant.modbus.address_map import AddressMap
        from hmi.plant.modbus.client import ModbusSettings
        settings = ModbusSettings.from_spec(project.plant)
        sections.append([f"Modbus {settings.where}: requests per scan"] + [
            f"  {line}" for line in
            AddressMap.for_project(project, settings.read_gap).describe()])
    from hmi.studies.diag_report import check_sections
    sections += check_sections(project, args.closed_loop)
    from hmi.studies.band_report import check_band
    lines, warnings = check_band(project)
    if lines:
        sections.append(lines)
    print(check_report(project, sections, warnings))
    return 0


def _table(rows: list[list[str]], indent: str = "  ") -> list[str]:
    if not rows:
        return []
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    lines = []
    for row in rows:
        cells = [cell.ljust(widths[i]) for i, cell in enumerate(row)]
        lines.append((indent + "  ".join(cells)).rstrip())
    return lines


def constraint_meaning(c: Constraint) -> str:
    """What a constraint forces, in the papers' words (h0: must be 0, h1: must be 1)."""
    if c.kind == "combined":
        return "combined over " + ", ".join(c.outputs)
    ctx = " and ".join(str(lit) for lit in c.context_literals) or "always"
    if c.output_positive:
        return f"{c.outputs[0]} must be 0 when {ctx}"
    return f"{c.outputs[0]} must be 1 when {ctx}"


def _law_summary(law: ControlLaw) -> str:
    parts = []
    if law.grafcet:
        g = law.grafcet
        initial = ", ".join(s.name for s in g.steps if s.initial)
        parts.append(f"GRAFCET {len(g.steps)} steps (initial {initial}), "
                     f"{len(g.transitions)} transitions")
        supervised = [f"{s.name} {format_duration(s.supervision_us)}" for s in g.steps
                      if s.supervision_us is not None]
        if supervised:
            parts.append("supervision " + ", ".join(supervised))
    if law.equations:
        parts.append(f"{len(law.equations)} equations")
    return "; ".join(parts)


def check_report(project: Project, sections: Sequence[Sequence[str]] = (),
                 more_warnings: Sequence[Diagnostic] = ()) -> str:
    lines = [f"Project {project.name}: {project.description}".rstrip(": "),
             "  files: " + ", ".join(project.files),
             f"  scan period {format_duration(project.scan_period_us)}, "
             f"filter policy {project.policy}, plant {project.plant.kind}"
             + (": " + ", ".join(f"{d.name} ({d.model})" for d in project.plant.devices)
                if project.plant.devices else ""),
             ""]
    lines.append(f"Inputs ({len(project.inputs)})")
    lines += _table([[v.name, str(v.address or ""), v.description] for v in project.inputs])
    lines.append(f"Outputs ({len(project.outputs)})")
    lines += _table([[v.name, str(v.address or ""), f"safe {int(v.safe)}", v.description]
                     for v in project.outputs])
    if project.memories:
        lines.append(f"Memories ({len(project.memories)})")
        lines += _table([[v.name, f"initial {int(v.safe)}", v.description]
                         for v in project.memories])
    lines.append(f"Timers ({len(project.timers)})")
    lines += _table([[t.name, t.kind, format_duration(t.preset_us), f"input {t.input}",
                      t.description] for t in project.timers])
    lines.append(f"Observers ({len(project.observers)})")
    rows = []
    for o in project.observers:
        body = str(o.expr) if o.expr else f"set {o.set}, reset {o.reset}"
        rows.append([o.name, body, o.description])
    lines += _table(rows)
    lines.append(f"Control law ({len(project.controls)} variant"
                 f"{'s' if len(project.controls) != 1 else ''})")
    lines += _table([[name + (" (default)" if name == project.default_control else ""),
                      _law_summary(law), law.description]
                     for name, law in project.controls.items()])
    simple = len(project.simple_constraints)
    combined = len(project.combined_constraints)
    lines.append(f"Safety constraints ({len(project.constraints)}: {simple} simple, "
                 f"{combined} combined)")
    lines += _table([[c.name, c.kind, c.expr.source, constraint_meaning(c)]
                     for c in project.constraints])
    from hmi.studies.monitor_report import monitor_check_lines
    monitor_lines = monitor_check_lines(project)
    if monitor_lines:
        lines += ["", *monitor_lines]
    for section in (*project.check_sections, *sections):
        lines.append("")
        lines.extend(section)
    warnings = (*project.warnings, *more_warnings)
    if warnings:
        lines.append("")
        lines.append(f"Warnings ({len(warnings)})")
        lines += [f"  {w}" for w in warnings]
    lines.append("")
    lines.append("OK: the project is valid")
    return "\n".join(lines)

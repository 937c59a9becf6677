"""``plchmi check PROJECT``: load and validate a project, print its summary."""

from __future__ import annotations

import argparse

from hmi.cli.common import load
from hmi.cli.options import diagnoser_arg, project_arg


def add_parser(sub) -> None:
    p = sub.add_parser("check", help="load and validate a project, print a summary")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--closed-loop", action="store_true",
                   help="compute the diagnosability on the closed loop if it is not cached "
                   "(as plchmi diagnose does)")


def cmd_check(args: argparse.Namespace) -> int:
    from hmi.engine.filter_analysis import analyse
    from hmi.report import check_report
    project = load(args.project, getattr(args, "diagnoser", None))
    sections = [analyse(project).lines(len(project.outputs))]
    if project.plant.kind == "modbus":
        from hmi.plant.modbus.address_map import AddressMap
        from hmi.plant.modbus.client import ModbusSettings
        settings = ModbusSettings.from_spec(project.plant)
        sections.append([f"Modbus {settings.where}: requests per scan"] + [
            f"  {line}" for line in
            AddressMap.for_project(project, settings.read_gap).describe()])
    from hmi.diag_report import check_sections
    sections += check_sections(project, args.closed_loop)
    from hmi.band_report import check_band
    lines, warnings = check_band(project)
    if lines:
        sections.append(lines)
    print(check_report(project, sections, warnings))
    return 0

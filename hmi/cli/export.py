"""``plchmi export PROJECT --format st|plcopen -o DIR [--control LAW]``: the controlled cell
(its control law and safety layer) as IEC 61131-3 code for a PLC (docs/plc-export.md)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import load
from hmi.cli.options import project_arg
from hmi.errors import UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser(
        "export", help="the control law, safety filter, diagnosers and monitors as IEC 61131-3 "
        "code",
        description="Export the controlled cell (its control law, the safety filter, local "
        "diagnosers, stopwatch monitors) for a PLC: Structured Text (st) or PLCopen TC6 XML "
        "(plcopen, for CODESYS, TwinCAT and OpenPLC's editor). See docs/plc-export.md.")
    project_arg(p)
    p.add_argument("--format", choices=("st", "plcopen"), required=True,
                   help="st: one IEC 61131-3 file; plcopen: PLCopen TC6 XML")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR",
                   help="folder to write into (created if missing)")
    p.add_argument("--control", metavar="LAW",
                   help="the control law to export (default: the project's default one)")


def cmd_export(args: argparse.Namespace) -> int:
    from hmi.export import export
    project = load(args.project)
    if args.output.exists() and not args.output.is_dir():
        raise UsageError(f"-o {args.output}: not a folder")
    if args.control is not None and args.control not in project.controls:
        raise UsageError(f"--control {args.control}: the project has no such control law "
                         f"(it has {', '.join(sorted(project.controls))})")
    try:
        written = export(project, args.format, args.output, args.control)
    except OSError as exc:
        raise UsageError(f"-o {args.output}: cannot write there ({exc.strerror})") from None
    print(f"Wrote {written.path}")
    for line in written.model.summary:
        print(f"  {line}")
    if args.format == "plcopen":
        for chart in written.model.charts:
            print(f"  SFC chart {chart.name}: the control law's GRAFCET ({len(chart.steps)} "
                  f"steps, {len(chart.transitions)} transitions) for the PLC's editor; the "
                  "task does not call it, it runs the control FB")
    return 0

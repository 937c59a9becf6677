"""``plchmi band PROJECT``: the cell run fault-free across its declared tolerances (the
band's corners and a seeded sample), or one point of the band replayed (``--point``)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from hmi.cli.common import load
from hmi.cli.farm import add_farm_args, farm_of, print_report
from hmi.cli.options import diagnoser_arg, duration, project_arg
from hmi.errors import UsageError
from hmi.limits import MAX_RUN_SCANS

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers

DEFAULT_SAMPLES = 1000
MAX_SAMPLES = 1_000_000


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("band", help="run the cell fault-free across its declared tolerances: "
                       "false diagnoses, monitor faults, damage, and the windows' margins")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--runs", type=int, default=DEFAULT_SAMPLES, metavar="N",
                   help=f"seeded points besides the corners (default {DEFAULT_SAMPLES})")
    p.add_argument("--seed", type=int, default=1, metavar="S",
                   help="seed of the points drawn (default 1)")
    p.add_argument("--for", dest="length", type=duration, default=None, metavar="TIME",
                   help="virtual time of each run (default: the campaign's length, else 60s)")
    p.add_argument("--point", metavar="NAME=VALUE,...",
                   help="replay one run, e.g. 'travel=2.4s,bounce=20ms,seed=3' (what check "
                   "and the report print): every diagnoser state it went through")
    add_farm_args(p)


def cmd_band(args: argparse.Namespace) -> int:
    from hmi.studies.band import fault_free_points, run_band
    from hmi.studies.band_report import band_lines, fault_free_band, point_lines, run_length

    project = load(args.project, getattr(args, "diagnoser", None))
    band = fault_free_band(project)
    if band.empty:
        raise UsageError(f"project {project.name} declares no tolerance that acts on a "
                         "fault-free run ('tolerances:' under its plant's devices, "
                         "'scan_jitter:')")
    length = args.length or run_length(project)
    if not 0 <= args.runs <= MAX_SAMPLES:
        raise UsageError(f"--runs {args.runs}: expected 0 to {MAX_SAMPLES:,}")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: expected a whole number from 0")
    if args.point is not None:
        print("\n".join(point_lines(project, band, band.parse_point(args.point), length)))
        return 0
    points = fault_free_points(band, args.runs, args.seed)
    scans = len(points) * (length // project.scan_period_us + 1)
    if scans > MAX_RUN_SCANS:
        raise UsageError(f"{len(points):,} runs of {length // 1_000_000} s are {scans:,} "
                         f"scans, more than the {MAX_RUN_SCANS:,} plchmi runs at once")
    with farm_of(args) as farm:
        runs = run_band(project, band, points, length, farm)
    print_report("\n".join(band_lines(project, runs, args.runs, args.seed)), farm)
    return 0

"""``plchmi soak PROJECT``: the whole HMI driven by a seeded random operator. Its options are
declared here, the soak itself (hmi/soak/) is imported only when the command runs: it
imports the whole HMI, which no other command's parsing should pay for."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.farm import add_farm_args
from hmi.cli.options import project_arg
from hmi.errors import UsageError
from hmi.timefmt import parse_duration

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers

DEFAULT_SHRINK_REPLAYS = 200
MAX_SEEDS = 100_000


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("soak", help="drive the whole HMI with a seeded random operator and "
                       "check its invariants after every step (virtual time)")
    project_arg(p)
    p.add_argument("--control", metavar="VARIANT",
                   help="control law variant (default: the project's first)")
    p.add_argument("--minutes", type=_minutes, default=30.0,
                   help="virtual minutes to run (default 30)")
    p.add_argument("--seed", type=int, default=1, help="the operator's random seed (1)")
    p.add_argument("--size", type=_size, default=(80, 24), metavar="WxH",
                   help="terminal size at the start (default 80x24)")
    p.add_argument("--steps", type=int, metavar="N",
                   help="stop after N steps too (a bounded run, as the tests do)")
    p.add_argument("--split", action="store_true",
                   help="the HMI attached over the runtime's real socket (frames, commands "
                   "and virtual time as messages), instead of the protocol in-process")
    p.add_argument("--replay", type=Path, metavar="FILE",
                   help="run the steps of FILE (as printed on a failure) instead")
    p.add_argument("--shrink", type=_seconds, default=None, metavar="TIME",
                   help="time allowed to shrink a failing step list (default 5m; 0: none)")
    p.add_argument("--seeds", type=_seeds, metavar="LIST",
                   help="a soak farm: one session per seed (1-1000, or 1-5,9,12), on local "
                   "processes or a cluster; prints the figures added up and each failing "
                   "seed with its shrunk step list")
    p.add_argument("--shrink-replays", type=_replays, default=None, metavar="N",
                   help=f"with --seeds: replays allowed to shrink each failing seed's steps "
                   f"(default {DEFAULT_SHRINK_REPLAYS}; 0: none); a count, not a time, so "
                   "the report is the same on any machine")
    add_farm_args(p)


def _size(text: str) -> tuple[int, int]:
    from hmi.soak.steps import parse_size
    try:
        width, height = parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not (40 <= width <= 500 and 10 <= height <= 200):
        raise argparse.ArgumentTypeError(f"{text}: a terminal from 40x10 to 500x200")
    return width, height


def _minutes(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of minutes") from None
    if not 0 < value <= 10_000:
        raise argparse.ArgumentTypeError(f"{text}: from more than 0 to 10000 minutes")
    return value


def _seconds(text: str) -> float:
    if text.strip() == "0":  # the help's "0: none", a bare zero without a unit
        return 0.0
    try:
        return parse_duration(text) / 1e6
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a duration (30s, 5m)") from None


def _seeds(text: str) -> list[int]:
    seeds: set[int] = set()
    for part in text.split(","):
        first, dash, last = part.strip().partition("-")
        if not first.isdigit() or (dash and not last.isdigit()):
            raise argparse.ArgumentTypeError(
                f"{text!r}: expected seeds as 1-1000 or 1-5,9,12 (whole numbers)")
        low, high = int(first), int(last) if dash else int(first)
        if low > high:
            raise argparse.ArgumentTypeError(f"{part.strip()!r}: the range goes down")
        if high - low + len(seeds) >= MAX_SEEDS:
            raise argparse.ArgumentTypeError(f"{text!r}: more than {MAX_SEEDS:,} seeds")
        seeds.update(range(low, high + 1))
    return sorted(seeds)


def _replays(text: str) -> int:
    if not text.isdigit() or int(text) > 100_000:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of replays from 0 to 100000")
    return int(text)


def cmd_soak(args: argparse.Namespace) -> int:
    farm_options = [name for name, value in (("--jobs", args.jobs), ("--cluster", args.cluster),
                                             ("--resume", args.resume),
                                             ("--shrink-replays", args.shrink_replays))
                    if value is not None]
    if args.seeds is None:
        if farm_options:
            raise UsageError(f"{', '.join(farm_options)}: with --seeds only (a soak farm)")
        from hmi.soak.command import cmd_soak
        if args.shrink is None:
            args.shrink = 300.0
        return cmd_soak(args)
    clash = [name for name, value in (("--seed", args.seed != 1), ("--replay", args.replay),
                                      ("--shrink", args.shrink is not None)) if value]
    if clash:
        raise UsageError(f"--seeds and {', '.join(clash)}: a farm runs each seed of --seeds, "
                         "and shrinks by replays (--shrink-replays), not by time")
    return _farm(args)


def _farm(args: argparse.Namespace) -> int:
    import sys

    from hmi.cli.farm import farm_of, print_report
    from hmi.project.loader import load_project
    from hmi.soak.farm import report_lines, run_farm, save_steps
    from hmi.soak.runner import SoakConfig

    project = load_project(args.project)
    if args.control and args.control not in project.controls:
        raise UsageError(f"--control {args.control!r}: the project has "
                         + ", ".join(project.controls))
    if args.steps is not None and args.steps < 1:
        raise UsageError("--steps: at least 1")
    replays = DEFAULT_SHRINK_REPLAYS if args.shrink_replays is None else args.shrink_replays
    config = SoakConfig(Path(args.project), args.control, args.size, args.minutes, 1,
                        args.steps, split=args.split)
    with farm_of(args) as farm:
        results = run_farm(project, config, args.seeds, replays, farm)
    print_report("\n".join(report_lines(results, project, config, args.project, replays)),
                 farm)
    folder = farm.stats[-1].folder if farm.stats else None
    if folder is not None:
        saved = save_steps(folder, results, args.project, config)
        if saved:
            print(f"  the failing seeds' step lists: {folder}/seed*.steps", file=sys.stderr)
    return 0 if all(r.ok for r in results) else 1

"""The studies of a project's faults and monitors: ``plchmi diagnose`` (the diagnosers'
automata and diagnosability), ``plchmi campaign`` (000 Table 1, or a sweep of fault
instants) and ``plchmi sweep`` (stopwatch monitor vs watchdog)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from hmi.cli.common import load
from hmi.cli.farm import add_farm_args, farm_of, print_report
from hmi.cli.options import diagnoser_arg, duration, project_arg
from hmi.errors import UsageError
from hmi.limits import MAX_RUN_SCANS
from hmi.timefmt import format_duration, parse_duration

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers
    from hmi.project.model import CampaignSpec, Project
    from hmi.studies.band import BandPoint
    from hmi.studies.campaign import RunResult


def add_parsers(sub: Subparsers) -> None:
    """diagnose and campaign (sweep is added later: the help lists commands in order)."""
    p = sub.add_parser("diagnose", help="print the diagnosers' automata and diagnosability")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--no-closed-loop", action="store_true",
                   help="print the closed-loop diagnosability only if it is cached (no "
                   "exploration, which takes minutes the first time)")
    band_args(p)
    p.add_argument("--build", metavar="DEVICE",
                   help="build a diagnoser for DEVICE (a plant device, or the device a "
                   "diagnoser observes) from its plant model, fault models and the control "
                   "law, write it and compare it with the project's on the closed loop")
    p.add_argument("-o", "--out", metavar="FILE",
                   help="with --build: where to write the diagnoser (default: "
                   "DEVICE.built.yaml in the current folder)")
    p.add_argument("--every", type=duration, default=None, metavar="TIME",
                   help="with --build: the grid of the closed-loop comparison (default: "
                   "200ms; 10ms on the valve is every scan)")
    add_farm_args(p)

    p = sub.add_parser("campaign", help="inject every fault under three configurations and "
                       "classify the runs (000 Table 1)")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    add_farm_args(p)
    p.add_argument("--sweep", action="store_true",
                   help="inject each fault at every instant of a full cycle instead of the "
                   "scenarios' single instants")
    p.add_argument("--every", type=duration, default=None, metavar="TIME",
                   help="with --sweep: the grid of instants (default: every scan period)")
    p.add_argument("--faults", metavar="F1,F2,...",
                   help="with --sweep: only these faults (default: every fault of the plant)")
    band_args(p)


def band_args(p: argparse.ArgumentParser) -> None:
    """The options of a study over the declared tolerances."""
    p.add_argument("--nominal", action="store_true",
                   help="the project's own plant only, not its declared tolerances")
    p.add_argument("--samples", type=int, default=None, metavar="N",
                   help="seeded points of the band besides its corners (default: "
                   f"{BAND_SAMPLES})")
    p.add_argument("--seed", type=int, default=1, metavar="S",
                   help="seed of those points (default 1)")


BAND_SAMPLES = 4
CAMPAIGN_CORNERS = 64  # the campaign over the band: at most this many corners (seeded)


def _band_options(args: argparse.Namespace) -> tuple[bool, int, int]:
    samples = BAND_SAMPLES if args.samples is None else args.samples
    if not 0 <= samples <= 10_000:
        raise UsageError(f"--samples {samples}: expected 0 to 10000")
    if args.seed < 0:
        raise UsageError(f"--seed {args.seed}: expected a whole number from 0")
    if args.nominal and args.samples is not None:
        raise UsageError("--samples is about the declared tolerances; --nominal leaves them out")
    return not args.nominal, samples, args.seed


DEFAULT_POINTS = "0.5s,1s,1.5s,2s,2.5s,3s"  # plchmi sweep's starts and lengths


def add_sweep_parser(sub: Subparsers) -> None:
    p = sub.add_parser("sweep", help="stopwatch monitor vs plain watchdog over a sweep of "
                       "interruption starts and lengths")
    project_arg(p)
    p.add_argument("--task", metavar="NAME", help="the monitored task (default: the first)")
    p.add_argument("--fault", metavar="DEVICE.CODE",
                   help="the fault that interrupts it, e.g. C1.stop (default: the "
                   "interruption fault of the device driving the task's interruption signal)")
    p.add_argument("--starts", type=points, default=points(DEFAULT_POINTS), metavar="LIST",
                   help=f"interruption starts after the task's start (default {DEFAULT_POINTS})")
    p.add_argument("--lengths", type=points, default=points(DEFAULT_POINTS),
                   metavar="LIST", help=f"interruption lengths (default {DEFAULT_POINTS})")
    p.add_argument("--attempt", type=int, default=1, metavar="N",
                   help="interrupt the task's N-th start (default 1)")
    p.add_argument("--control", metavar="VARIANT", help="control law variant to run")


def points(text: str) -> tuple[int, ...]:
    try:
        values = tuple(parse_duration(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of durations, e.g. 0.5s,1s,2s") from None
    if not values:
        raise argparse.ArgumentTypeError("the list is empty")
    return values


def cmd_diagnose(args: argparse.Namespace) -> int:
    from hmi.studies.diag_report import diagnose_report
    project = load(args.project, getattr(args, "diagnoser", None))
    if args.build is not None:
        return _build(args, project)
    if args.out is not None:
        raise UsageError("--out needs --build")
    if args.every is not None:
        raise UsageError("--every needs --build (diagnose computes every instant exactly)")
    band, samples, seed = _band_options(args)
    with farm_of(args) as farm:
        report = diagnose_report(project, farm=farm, compute=not args.no_closed_loop,
                                 band=band, samples=samples, seed=seed)
    print_report(report, farm)
    return 0


def _build(args: argparse.Namespace, project: Project) -> int:
    from pathlib import Path

    from hmi.studies.loopstate import Unsupported
    from hmi.studies.synth_report import build_report
    from hmi.studies.synthesis import SynthesisError
    out = Path(args.out) if args.out else Path(f"{args.build}.built.yaml")
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise UsageError(f"--out {out}: a diagnosers file ends in .yaml (to load it with "
                         "--diagnoser FILE.yaml)")
    print(f"building the diagnoser of {args.build} (a few minutes: every fault at every scan "
          "of the cycle)...", file=sys.stderr)
    with farm_of(args) as farm:
        try:
            report, status = build_report(project, args.build, out, farm, args.every)
        except (SynthesisError, Unsupported) as exc:
            raise UsageError(f"--build {args.build}: {exc}") from None
    print_report(report, farm)
    return status


def cmd_campaign(args: argparse.Namespace) -> int:
    import json

    from hmi.project.campaign import campaign_of
    from hmi.studies.campaign import report_lines, run_campaign
    project = load(args.project, getattr(args, "diagnoser", None))
    spec = campaign_of(project)
    if spec is None:
        raise UsageError(f"project {project.name} has no 'campaign:' section")
    from hmi.studies.campaign import CONFIGS
    runs = len(spec.scenarios) * len(CONFIGS)
    scans = runs * (spec.length_us // project.scan_period_us + 1)
    if scans > MAX_RUN_SCANS:
        raise UsageError(f"the campaign is {runs} runs of {format_duration(spec.length_us)}: "
                         f"{scans:,} scans, more than the {MAX_RUN_SCANS:,} plchmi runs at once "
                         "(a shorter campaign length)")
    if args.sweep:
        return _campaign_sweep(args, project, spec)
    if args.every is not None or args.faults is not None:
        raise UsageError("--every and --faults need --sweep")

    band, samples, seed = _band_options(args)
    points: list[BandPoint] = []
    if band:
        from hmi.studies.band import band_of
        declared = band_of(project)
        corners, which = declared.some_corners(CAMPAIGN_CORNERS, seed)
        points = [*corners, *declared.sample(samples, seed)] if not declared.empty else []
        if scans * (1 + len(points)) > MAX_RUN_SCANS:
            raise UsageError(f"the campaign over the declared tolerances is {runs} runs at "
                             f"{len(points) + 1} plants: {scans * (1 + len(points)):,} scans, "
                             f"more than the {MAX_RUN_SCANS:,} plchmi runs at once "
                             "(--nominal, or fewer --samples)")

    def progress(done: int, total: int, run: RunResult) -> None:
        print(f"[{done:>2}/{total}] {run.scenario.name:<10} {run.config.title:<22} "
              f"{run.outcome}", file=sys.stderr, flush=True)

    variant = getattr(args, "diagnoser", None)
    over = None
    with farm_of(args) as farm:
        farm.progress = None  # a line per run instead
        result = run_campaign(project, spec, progress, farm=farm, variant=variant)
        if points:
            from hmi.cli.farm import progress_line
            from hmi.studies.campaign import run_campaign_band
            farm.progress = progress_line()
            over = run_campaign_band(project, spec, declared, points, farm, variant, which)
    if args.json:
        data = result.as_dict()
        if over is not None:
            data["band"] = over.as_dict()
        text = json.dumps(data, indent=2)
    else:
        lines = report_lines(result)
        if over is not None:
            from hmi.studies.campaign import band_report_lines
            lines += ["", *band_report_lines(result, over, samples, seed)]
        text = "\n".join(lines)
    print_report(text, farm)
    return 0


def _campaign_sweep(args: argparse.Namespace, project: Project, spec: CampaignSpec) -> int:
    import json

    from hmi.studies.loop_sweep import CAMPAIGN_CONFIGS, sweep
    from hmi.studies.loopstate import Unsupported
    from hmi.studies.sweep_report import as_dict, report_lines

    period = project.scan_period_us
    if args.every is not None and args.every % period and period % args.every:
        raise UsageError(f"--every must be a multiple of the scan period "
                         f"({format_duration(period)}) or divide it")
    band, samples, seed = _band_options(args)
    faults = _faults(args, project)
    over = None
    with farm_of(args) as farm:
        try:
            result = sweep(project, CAMPAIGN_CONFIGS, spec.counter, args.every, farm=farm,
                           cache=args.every is None, faults=faults, exact=args.every is None)
            assert result is not None  # None only when asked not to compute
            if band and args.every is None:
                from hmi.studies.band import exploration_band
                from hmi.studies.band_sweep import band_sweep, exploration_points
                explored = exploration_band(project)
                if not explored.empty:
                    over = band_sweep(project, explored, CAMPAIGN_CONFIGS, spec.counter,
                                      exploration_points(explored, samples, seed), faults,
                                      farm=farm)
        except Unsupported as exc:
            raise UsageError(f"campaign --sweep: {exc}") from None
    if args.json:
        data = as_dict(result, spec.scenarios)
        if over is not None:
            from hmi.studies.sweep_report import band_as_dict
            data["band"] = band_as_dict(over, spec.scenarios)
        text = json.dumps(data, indent=2)
    else:
        lines = report_lines(result, spec.scenarios, spec.paper, project.name)
        if over is not None:
            from hmi.studies.sweep_report import band_lines
            lines += ["", *band_lines(over, spec.scenarios, spec.paper, samples, seed)]
        text = "\n".join(lines)
    print_report(text, farm)
    return 0


def _faults(args: argparse.Namespace, project: Project) -> tuple[str, ...] | None:
    from hmi.studies.explore import faults_of
    if args.faults is None:
        return None
    known = faults_of(project)
    chosen = tuple(f.strip() for f in args.faults.split(",") if f.strip())
    unknown = [f for f in chosen if f not in known]
    if unknown or not chosen:
        raise UsageError(f"--faults {args.faults!r}: " + (f"unknown {', '.join(unknown)}; "
                         if unknown else "") + "the plant's faults are " + ", ".join(known))
    return chosen


def cmd_sweep(args: argparse.Namespace) -> int:
    from hmi.studies.monitor_sweep import cmd_sweep
    return cmd_sweep(args, load(args.project, getattr(args, "diagnoser", None)))

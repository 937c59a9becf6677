"""The `plchmi` command.

    plchmi PROJECT                 open the operator HMI (Textual)
    plchmi check PROJECT           load, validate and summarise a project
    plchmi run PROJECT --for 60s   headless run in virtual time (real time on a real plant)
    plchmi sweep PROJECT           stopwatch monitor vs watchdog over interruptions
    plchmi serve-plant PROJECT     the simulated plant as a Modbus TCP server
    plchmi diagnose PROJECT        the diagnosers' automata and their diagnosability
    plchmi campaign PROJECT        the fault campaign (000 Table 1)
    plchmi export PROJECT --format st|plcopen -o DIR
                                   the safety layer as IEC 61131-3 code for a PLC

Exit status: 0 success, 2 bad input (a project error, a bad argument), 1 a failure at run
time. Errors about a project name the file, line and column; there is never a traceback for
bad input.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from hmi.errors import OutputError, ProjectError, UsageError
from hmi.limits import MAX_JOBS, MAX_RUN_SCANS, MIN_SCAN_PERIOD_US
from hmi.timefmt import DURATION_HINT, DurationError, format_duration, parse_duration, seconds

MAX_ERRORS_SHOWN = 25
SUBCOMMANDS = ("check", "run", "sweep", "ui", "serve-plant", "bench", "journal",
               "diagnose", "campaign", "export", "opcua-passwd", "soak")


def _duration(text: str) -> int:
    try:
        us = parse_duration(text)
    except DurationError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} {exc.reason} (expected {DURATION_HINT})"
                                         ) from None
    if us <= 0:
        raise argparse.ArgumentTypeError("the duration must be longer than zero")
    return us


def _period(text: str) -> int:
    us = _duration(text)
    if us < MIN_SCAN_PERIOD_US:
        raise argparse.ArgumentTypeError(f"{text!r} is shorter than the shortest scan period "
                                         f"({format_duration(MIN_SCAN_PERIOD_US)})")
    return us


def _solver_budget(text: str) -> int:
    from hmi.project.model import MAX_SOLVER_BUDGET, MIN_SOLVER_BUDGET
    try:
        if not text.isascii():  # "１０００" is int() 1000: digits a reader would not see
            raise ValueError(text)
        value = int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of steps") from None
    if not MIN_SOLVER_BUDGET <= value <= MAX_SOLVER_BUDGET:
        raise argparse.ArgumentTypeError(
            f"{value} steps is out of range: between {MIN_SOLVER_BUDGET:,} and "
            f"{MAX_SOLVER_BUDGET:,}")
    return value


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plchmi",
        description="Operator HMI and soft-PLC runtime with a safety control filter. "
        "'plchmi PROJECT' opens the HMI.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def project_arg(p: argparse.ArgumentParser) -> None:
        p.add_argument("project", help="project folder (or its project.yaml)")

    def diagnoser_arg(p: argparse.ArgumentParser) -> None:
        p.add_argument("--diagnoser", metavar="VARIANT",
                       help="load this variant of the diagnosers (e.g. paper); default: "
                       "the first each declares")

    def engine_args(p: argparse.ArgumentParser) -> None:
        p.add_argument("--control", metavar="VARIANT",
                       help="control law variant to run (default: the project's first)")
        p.add_argument("--policy", choices=("monitor", "block", "correct"),
                       help="safety filter policy (default: the project's)")
        p.add_argument("--solver", choices=("exact", "paper"),
                       help="corrector search strategy (default: the project's, else exact)")
        p.add_argument("--solver-budget", type=_solver_budget, metavar="STEPS",
                       help="corrector search budget per scan, in steps; past it the safe "
                       "state is written (default: the project's, else half the scan period "
                       "in microseconds)")

    def plant_args(p: argparse.ArgumentParser, connect_default: str) -> None:
        p.add_argument("--plant", metavar="PLANT",
                       help="sim, modbus (the project's settings) or "
                       "modbus://HOST:PORT[/UNIT] (default: the project's plant)")
        p.add_argument("--read-only", action="store_true",
                       help="observe a real PLC over Modbus: read its inputs and outputs, "
                       "check the constraints on them, write nothing")
        p.add_argument("--connect-timeout", type=_duration, metavar="TIME",
                       help="give up if a Modbus plant does not answer within TIME "
                       f"(default: {connect_default})")
        p.add_argument("--allow-monitor", action="store_true",
                       help="permit the monitor policy (unsafe orders pass) on a real plant")

    p = sub.add_parser("check", help="load and validate a project, print a summary")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--closed-loop", action="store_true",
                   help="compute the diagnosability on the closed loop if it is not cached "
                   "(as plchmi diagnose does)")

    p = sub.add_parser("run", help="run headless in virtual time")
    project_arg(p)
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--for", dest="duration", type=_duration, metavar="TIME",
                   help="virtual time to run, e.g. 60s (default: the scenario's)")
    p.add_argument("--scenario", metavar="NAME",
                   help="inject the faults of a scenario the project declares")
    p.add_argument("--period", type=_period, metavar="TIME",
                   help="scan period (default: the project's)")
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="inject a fault into the simulated plant, e.g. F5@12s (repeatable)")
    p.add_argument("--trace", type=Path, metavar="FILE",
                   help="write every scan to FILE (.csv, or .jsonl for JSON Lines)")
    plant_args(p, "10s")
    p.add_argument("--diagnosis", choices=("ftc", "observe", "off"), default="ftc",
                   help="diagnosers: drive reconstruction and masking (ftc, the default), "
                   "run without effect (observe), or not run (off)")
    p.add_argument("--explain", action="store_true",
                   help="print the four levels of every alarm's explanation")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="journal file (default: the user's data folder, see plchmi journal)")
    from hmi.opcua.options import add_arguments as opcua_args
    opcua_args(p)

    p = sub.add_parser("diagnose", help="print the diagnosers' automata and diagnosability")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--no-closed-loop", action="store_true",
                   help="print the closed-loop diagnosability only if it is cached (no "
                   "exploration, which takes about a minute the first time)")

    p = sub.add_parser("campaign", help="inject every fault under three configurations and "
                       "classify the runs (000 Table 1)")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="worker processes (default: 2 if the machine has 2 cores or more)")
    p.add_argument("--sweep", action="store_true",
                   help="inject each fault at every instant of a full cycle instead of the "
                   "scenarios' single instants")
    p.add_argument("--every", type=_duration, default=None, metavar="TIME",
                   help="with --sweep: the grid of instants (default: every scan period)")
    p.add_argument("--faults", metavar="F1,F2,...",
                   help="with --sweep: only these faults (default: every fault of the plant)")

    p = sub.add_parser(
        "export", help="the safety filter, diagnosers and monitors as IEC 61131-3 code",
        description="Export the project's safety layer (filter, local diagnosers, stopwatch "
        "monitors) for a PLC: Structured Text (st) or PLCopen TC6 XML (plcopen, for CODESYS, "
        "TwinCAT and OpenPLC's editor). See docs/plc-export.md.")
    project_arg(p)
    p.add_argument("--format", choices=("st", "plcopen"), required=True,
                   help="st: one IEC 61131-3 file; plcopen: PLCopen TC6 XML")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR",
                   help="folder to write into (created if missing)")

    p = sub.add_parser(
        "journal", help="print or export a project's operator journal",
        description="Print or export a project's operator journal. A damaged line (an entry "
        "cut short by a killed process, or garbage) is skipped with a warning on stderr "
        "naming file:line and what is wrong; every readable entry is still printed and the "
        "exit status is 0. Exit status 1 only when there is no journal to read.")
    project_arg(p)
    p.add_argument("--since", metavar="WHEN",
                   help="only entries since WHEN: an ISO date/time, or a duration ago (2h)")
    p.add_argument("--csv", action="store_true", help="export as CSV")
    p.add_argument("--kind", action="append", default=[], metavar="KIND",
                   help="only entries of this kind (repeatable, or comma-separated): "
                   + ", ".join(JOURNAL_KINDS) + "; --kind alarm is the alarm history")
    p.add_argument("--path", type=Path, metavar="FILE", help="journal file to read")

    from hmi.sweep import add_sweep_parser
    add_sweep_parser(sub, project_arg)

    from hmi.soak.command import add_soak_parser
    add_soak_parser(sub, project_arg)

    p = sub.add_parser("bench", help="measure and print performance figures (never fails)")
    p.add_argument("sections", nargs="*", metavar="SECTION",
                   help="sections to run (default: all): " + ", ".join(_bench_sections()))
    p.add_argument("--quick", action="store_true", help="fewer samples, for a fast look")
    p.add_argument("--seed", type=int, default=1, help="random seed for generated problems")

    p = sub.add_parser("ui", help="open the operator HMI (the default command)")
    project_arg(p)
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="schedule a fault in the simulated plant")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="journal file (default: the user's data folder, see plchmi journal)")
    p.add_argument("--bell", action="store_true",
                   help="ring the terminal bell when a new unacknowledged P1 alarm appears")
    plant_args(p, "keep trying")
    opcua_args(p)

    p = sub.add_parser("opcua-passwd", help="add a user to an OPC UA password file",
                       description="Add (or replace) a user of a password file for "
                       "--opcua-users: the password is read from the terminal, or from "
                       "standard input with --stdin, and only a salted hash is stored.")
    p.add_argument("file", type=Path, help="the password file (created if missing)")
    p.add_argument("name", help="the user's name")
    p.add_argument("--stdin", action="store_true",
                   help="read the password from the first line of standard input")

    p = sub.add_parser("serve-plant", help="serve the simulated plant over Modbus TCP")
    project_arg(p)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (127.0.0.1)")
    p.add_argument("--port", type=_port, default=5020,
                   help="TCP port (5020; 0 picks a free one and prints it)")
    p.add_argument("--unit", type=_unit, help="Modbus unit id (default: the project's, or 1)")
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="a device fault (F5@12s) or a communication fault (busy@5s+2s, "
                   "mute@5s+2s), in time since the server started (repeatable)")
    p.add_argument("--delay", type=_duration, metavar="TIME",
                   help="answer every request TIME late (a slow server)")
    p.add_argument("--max-connections", type=_positive, default=16, metavar="N",
                   help="connections open at once; more are closed at once (16)")
    p.add_argument("--idle-timeout", type=_duration, default=60_000_000, metavar="TIME",
                   help="close a connection with no request for TIME (60s)")
    return parser


def _whole(text: str, most: int) -> int | None:
    """`text` as a whole number from 0 to `most`, ASCII digits only ("²".isdigit() is true)."""
    if not (text.isascii() and text.isdigit()) or len(text) > 6 or int(text) > most:
        return None
    return int(text)


def _port(text: str) -> int:
    port = _whole(text, 65535)
    if port is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (0 to 65535)")
    return port


def _unit(text: str) -> int:
    unit = _whole(text, 255)
    if unit is None:
        raise argparse.ArgumentTypeError(f"{text!r} is not a Modbus unit id (0 to 255)")
    return unit


def _positive(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 10_000:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number from 1 to 10000")
    return int(text)


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] not in SUBCOMMANDS and not args_list[0].startswith("-"):
        args_list.insert(0, "ui")
    parser = _parser()
    if not args_list:
        parser.print_help()
        return 2
    args = parser.parse_args(args_list)
    try:
        handler = COMMANDS.get(args.command)
        if handler is not None:
            return handler(args)
    except ProjectError as exc:
        print_project_error(exc)
        return 2
    except UsageError as exc:
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 2
    except RunFailure as exc:
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 1
    except OutputError as exc:  # a trace or journal that cannot be opened
        print(f"plchmi: error: {exc}", file=sys.stderr)
        return 2 if exc.bad_path else 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (plchmi ... | head): not an error; silence the final flush.
        import os
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except Exception as exc:  # a bug: say so plainly, keep the details for the developers
        from hmi.crash import write_crash_report
        report = write_crash_report(exc)
        print(f"plchmi: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        print(f"plchmi: the details are in {report}; please report it", file=sys.stderr)
        return 1
    parser.print_help()
    return 2


def _soak(args: argparse.Namespace) -> int:
    from hmi.soak.command import cmd_soak
    return cmd_soak(args)


def _sweep(args: argparse.Namespace) -> int:
    from hmi.sweep import cmd_sweep
    return cmd_sweep(args, load(args.project, getattr(args, "diagnoser", None)))


def print_project_error(exc: ProjectError) -> None:
    shown = exc.errors[:MAX_ERRORS_SHOWN]
    for diagnostic in shown:
        print(diagnostic, file=sys.stderr)
    if len(exc.errors) > len(shown):
        print(f"... and {len(exc.errors) - len(shown)} more errors", file=sys.stderr)
    count = len(exc.errors)
    print(f"plchmi: the project has {count} error{'s' if count != 1 else ''}; nothing was run",
          file=sys.stderr)


def load(path: str, diagnoser: str | None = None):
    from hmi.project.loader import load_project
    return load_project(path, diagnoser)


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
    print(check_report(project, sections))
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from hmi.diag_report import diagnose_report
    print(diagnose_report(load(args.project, getattr(args, "diagnoser", None)),
                          progress=_progress_bar(), compute=not args.no_closed_loop))
    return 0


def _progress_bar():
    """A one-line progress bar on stderr, for explorations of the closed loop."""
    import time
    started = time.monotonic()
    shown = [-1]

    def progress(done: int, total: int) -> None:
        percent = 100 * done // max(1, total)
        if percent == shown[0]:
            return
        shown[0] = percent
        bar = "#" * (percent // 4)
        end = "\n" if done >= total else ""
        print(f"\r[{bar:<25}] {percent:3d}%  {done:,}/{total:,} runs  "
              f"{time.monotonic() - started:5.1f} s", end=end, file=sys.stderr, flush=True)

    return progress


def cmd_campaign(args: argparse.Namespace) -> int:
    import json
    import os

    from hmi.engine.campaign import report_lines, run_campaign
    from hmi.project.campaign import campaign_of
    project = load(args.project, getattr(args, "diagnoser", None))
    spec = campaign_of(project)
    if spec is None:
        raise UsageError(f"project {project.name} has no 'campaign:' section")
    from hmi.engine.campaign import CONFIGS
    runs = len(spec.scenarios) * len(CONFIGS)
    scans = runs * (spec.length_us // project.scan_period_us + 1)
    if scans > MAX_RUN_SCANS:
        raise UsageError(f"the campaign is {runs} runs of {format_duration(spec.length_us)}: "
                         f"{scans:,} scans, more than the {MAX_RUN_SCANS:,} plchmi runs at once "
                         "(a shorter campaign length)")
    jobs = args.jobs if args.jobs is not None else min(2, os.cpu_count() or 1)
    if not 1 <= jobs <= MAX_JOBS:
        raise UsageError(f"--jobs {jobs}: expected 1 to {MAX_JOBS} worker processes")
    if args.sweep:
        return _campaign_sweep(args, project, spec, jobs)
    if args.every is not None or args.faults is not None:
        raise UsageError("--every and --faults need --sweep")

    def progress(done: int, total: int, run) -> None:
        print(f"[{done:>2}/{total}] {run.scenario.name:<10} {run.config.title:<22} "
              f"{run.outcome}", file=sys.stderr, flush=True)

    result = run_campaign(project, spec, progress, jobs=jobs)
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
    else:
        print("\n".join(report_lines(result)))
    return 0


def _campaign_sweep(args: argparse.Namespace, project, spec, jobs: int) -> int:
    import json

    from hmi.engine.loop_sweep import CAMPAIGN_CONFIGS, sweep
    from hmi.engine.loopstate import Unsupported
    from hmi.engine.sweep_report import as_dict, report_lines

    if args.every is not None and args.every % project.scan_period_us:
        raise UsageError(f"--every must be a multiple of the scan period "
                         f"({project.scan_period_us // 1000} ms)")
    try:
        result = sweep(project, CAMPAIGN_CONFIGS, spec.counter, args.every, jobs=jobs,
                       progress=_progress_bar(), cache=False, faults=_faults(args, project))
    except Unsupported as exc:
        raise UsageError(f"campaign --sweep: {exc}") from None
    if args.json:
        print(json.dumps(as_dict(result, spec.scenarios), indent=2))
    else:
        print("\n".join(report_lines(result, spec.scenarios, spec.paper, project.name)))
    return 0


def _faults(args: argparse.Namespace, project) -> tuple[str, ...] | None:
    from hmi.engine.explore import faults_of
    if args.faults is None:
        return None
    known = faults_of(project)
    chosen = tuple(f.strip() for f in args.faults.split(",") if f.strip())
    unknown = [f for f in chosen if f not in known]
    if unknown or not chosen:
        raise UsageError(f"--faults {args.faults!r}: " + (f"unknown {', '.join(unknown)}; "
                         if unknown else "") + "the plant's faults are " + ", ".join(known))
    return chosen


def make_engine(project, args: argparse.Namespace, extra_injections=()):
    """The engine for a command's --control/--policy/--inject/--plant options."""
    from hmi.engine.scan import Engine
    from hmi.plant.injection import parse_injection
    from hmi.plant.select import open_plant

    if args.control and args.control not in project.controls:
        raise UsageError(f"--control {args.control!r}: the project has "
                         + ", ".join(project.controls))
    injections = [*extra_injections,
                  *(parse_injection(text) for text in getattr(args, "inject", []))]
    read_only = getattr(args, "read_only", False)
    plant = open_plant(project, getattr(args, "plant", None), read_only, injections,
                       getattr(args, "period", None))
    # The engine refuses the monitor policy on a real plant unless --allow-monitor.
    engine = Engine(project, plant, control=args.control, policy=args.policy,
                    solver=args.solver, diagnosis=getattr(args, "diagnosis", None) or "ftc",
                    solver_budget=getattr(args, "solver_budget", None),
                    allow_monitor_policy=getattr(args, "allow_monitor", False))
    return engine, injections


def connect_plant(engine, timeout_us: int | None) -> None:
    """Connect a real plant before the first scan, saying what happens; exit 1 if it fails."""
    plant = engine.plant
    if not plant.is_real:
        return
    from hmi.plant.modbus.client import wait_connected

    def report(line: str) -> None:
        print(f"plchmi: {line}", file=sys.stderr, flush=True)
    timeout_s = None if timeout_us is None else timeout_us / 1e6
    if not wait_connected(plant, timeout_s, report):
        plant.close()
        raise RunFailure(f"no connection to the plant within {format_duration(timeout_us)}: "
                         f"{plant.message}")


class RunFailure(Exception):
    """A failure at run time (exit status 1), with a message for the operator."""


def cmd_run(args: argparse.Namespace) -> int:
    from hmi.report import run_summary
    from hmi.runio import RunOutputs
    from hmi.session.session import Session, settle_memory

    project = load(args.project, getattr(args, "diagnoser", None))
    scenario = None
    if args.scenario:
        from hmi.project.scenarios import find_scenario
        scenario = find_scenario(project, args.scenario)
    duration = args.duration or (scenario.duration_us if scenario else None)
    from hmi.opcua.options import check_arguments
    check_arguments(args)
    if duration is None and args.opcua is None:
        raise UsageError("--for TIME is required (or a --scenario that sets its length)")
    if duration is not None:
        run_length_notice(duration, args.period or project.scan_period_us)
    engine, injections = make_engine(project, args, scenario.injections if scenario else ())
    if engine.plant.is_real or args.opcua is not None:
        return run_real_time(engine, args, duration)
    controller = Session(engine, args.period)
    collector = RunCollector()
    outputs = RunOutputs(controller, args.trace, args.journal, "run")
    settle_memory()
    started = time.perf_counter()
    def on_scan(snap) -> None:
        collector.add(snap)
        if outputs.write(snap):
            raise _OutputFailed

    try:
        last = controller.run_for(duration, on_scan)
    except _OutputFailed:
        outputs.leave_safe()
        last = controller.last
    finally:
        outputs.close(ended_by(sys.exc_info()[1]))
    if outputs.failure is not None:
        raise RunFailure(outputs.failure_message())
    wall = time.perf_counter() - started
    if scenario:
        print(f"Scenario {scenario.name}: {scenario.description}")
    print(run_summary(engine, last, collector, injections, wall, trace=outputs.trace))
    print(alarm_summary(collector, args.explain))
    print(f"Journal: {outputs.recorder.journal.path}")
    return 0


class _OutputFailed(Exception):
    """Ends a headless run at the scan whose trace or journal could not be written."""


def run_length_notice(duration_us: int, period_us: int) -> None:
    """Refuse a run too long to finish; say so up front when one will take a while."""
    from hmi.runio import RunLengthError, check_run_length
    try:
        notice = check_run_length(duration_us, period_us)
    except RunLengthError as exc:
        raise UsageError(str(exc)) from None
    if notice:
        print(f"plchmi: {notice}", file=sys.stderr, flush=True)


def open_journal(controller, path: Path | None, source: str):
    from hmi.runio import open_journal as open_recorder
    return open_recorder(controller, path, source)


def alarm_summary(collector: RunCollector, explain: bool) -> str:
    from hmi.timefmt import seconds as secs
    if not collector.alarm_events:
        return "Alarms: none"
    raised = [e for e in collector.alarm_events if e.event in ("raised", "returned")]
    lines = [f"Alarms: {len(raised)} raised or returned, "
             f"{sum(1 for e in collector.alarm_events if e.event == 'chattering')} chattering"]
    shown = 0
    for event in collector.alarm_events:
        if event.event not in ("raised", "chattering") or shown >= 20:
            continue
        shown += 1
        what = "CHATTERING " if event.event == "chattering" else ""
        lines.append(f"  {secs(event.time_us)} s  [{event.severity}] {what}{event.text}")
    if explain:
        for key, explanation in collector.explanations.items():
            lines.append("")
            lines.append(f"Explanation of {key} (as last shown, since "
                         f"{secs(explanation.since_us)} s):")
            lines.append(explanation.render(4))
            if explanation.recommended:
                lines.append(f"  Recommended: {explanation.recommended.label}")
    return "\n".join(lines)


JOURNAL_KINDS = ("action", "alarm", "recovery", "plant", "session")


def cmd_journal(args: argparse.Namespace) -> int:
    import csv

    from hmi.explain.journal import (
        JournalError,
        JournalPathError,
        default_path,
        read,
        since_filter,
    )
    from hmi.project.loader import load_project
    path = args.path or default_path(load_project(args.project).name)
    since = parse_since(args.since) if args.since else None
    try:
        result = read(path)
    except JournalError as exc:
        print(f"plchmi: {exc}", file=sys.stderr)
        return 1
    except JournalPathError as exc:
        raise UsageError(f"--path {exc}" if args.path else str(exc)) from None
    kinds = {k.strip() for text in args.kind for k in text.split(",") if k.strip()}
    unknown = sorted(kinds - set(JOURNAL_KINDS))
    if unknown:
        raise UsageError(f"--kind {', '.join(unknown)}: expected "
                         + ", ".join(JOURNAL_KINDS))
    entries = [e for e in since_filter(result.entries, since)
               if not kinds or e.get("type") in kinds]
    columns = ("wall", "scan", "t", "type", "event", "key", "state", "severity", "text",
               "message", "by")
    if args.csv:
        writer = csv.writer(sys.stdout, lineterminator="\n")
        writer.writerow(columns)
        for entry in entries:
            writer.writerow([_printable(_field(entry, c)) for c in columns])
    else:
        for entry in entries:
            text = _field(entry, "text") or _field(entry, "message") or _field(entry, "project")
            key = f" {entry['key']}" if entry.get("key") else ""
            if isinstance(entry.get("by"), str):  # sent by an OPC UA client
                text = f"{text} [by {entry['by']}]"
            print(_printable(f"{_field(entry, 'wall')}  scan {_field(entry, 'scan'):>6}  "
                             f"t={_field(entry, 't')}  {_field(entry, 'type'):<7} "
                             f"{_field(entry, 'event')}{key}: {text}"))
    # Exit status 0 even with damaged lines: the readable entries are what the operator
    # needs; each damaged line is a warning on stderr (docs/journal.md).
    for bad in result.damaged:
        print(f"plchmi: warning: {path}:{bad.line}: damaged journal entry skipped: {bad.reason}",
              file=sys.stderr)
    if result.truncated:
        print(f"plchmi: the last entry of {path} was cut short (the process was killed while "
              "writing it); it is ignored", file=sys.stderr)
    return 0


def parse_since(text: str):
    """--since: a duration ago (2h) or an ISO date/time (local time unless it says its zone);
    anything else, or a time out of range, is a usage error."""
    from datetime import UTC, datetime, timedelta
    hint = "an ISO date/time (2026-11-22T15:00) or a duration ago (30m, 2h)"
    try:
        ago = parse_duration(text)
    except DurationError as exc:
        if "longer than" in exc.reason:
            raise UsageError(f"--since {text!r} {exc.reason}; give a date instead") from None
        ago = None
    if ago is not None:
        return datetime.now(UTC) - timedelta(microseconds=ago)
    try:
        if not text.isascii():
            raise ValueError(text)
        since = datetime.fromisoformat(text)
    except ValueError:
        raise UsageError(f"--since {text!r}: expected {hint}") from None
    if since.tzinfo is None:
        try:
            since = since.astimezone(UTC)  # as the operator's clock reads
        except (ValueError, OverflowError):  # at the very ends of the calendar
            since = since.replace(tzinfo=UTC)
    return since


def _field(entry: dict, name: str):
    """A field of a journal entry for display: "" when absent or null (the reader has checked
    the type of the fields it knows)."""
    value = entry.get(name)
    return "" if value is None else value


_CONTROL = str.maketrans({c: f"\\x{c:02x}" for c in [*range(0x20), *range(0x7f, 0xa0)]
                          if c != 0x09})


def _printable(value) -> str:
    """A journal field for the terminal: control characters (an ESC sequence written into a
    damaged or forged journal) shown as \\xNN, never sent to the terminal."""
    return str(value).translate(_CONTROL)


class RunCollector:
    """What a headless run remembers for its summary, without keeping every snapshot."""

    def __init__(self) -> None:
        self.scans = 0
        self.violations: dict[str, int] = {}
        self.corrections = 0
        self.safe_scans = 0
        self.unsafe_written = 0
        self.fallbacks = 0
        self.search_stops = 0  # fallbacks because the corrector's search used its budget
        self.first_latch: tuple[int, int, str] | None = None
        self.events = []
        self.step_changes = 0
        self.max_distance = 0
        from hmi.monitor_report import MonitorLog
        self.monitors = MonitorLog()
        self.alarm_events = []
        self.explanations = {}
        from hmi.diag_report import DiagnosisLog
        self.diagnosis = DiagnosisLog()

    def add(self, snap) -> None:
        self.scans += 1
        self.monitors.add(snap)
        self.diagnosis.add(snap)
        self.events.extend(snap.plant_events)
        if snap.alarm_events:
            self.alarm_events.extend(snap.alarm_events)
        for explanation in snap.explanations:
            if explanation.alarm:
                self.explanations[explanation.key] = explanation
        report = snap.filter
        if report is not None:
            for name in report.violated_names:
                self.violations[name] = self.violations.get(name, 0) + 1
            if report.safe_state:
                self.safe_scans += 1
            elif any(c.how != "masked" for c in report.changes):  # masks: diagnosers' lines
                self.corrections += 1
            if report.unsafe_written:
                self.unsafe_written += 1
            if report.fallback:
                self.fallbacks += 1
                self.search_stops += bool(getattr(report, "stopped", ""))
            self.max_distance = max(self.max_distance, report.distance)
        if snap.latched and self.first_latch is None:
            reason = snap.latched[0]
            self.first_latch = (reason.scan, reason.time_us, reason.detail)


def run_real_time(engine, args: argparse.Namespace, duration_us: int | None) -> int:
    """A headless run paced by the wall clock: against a real plant (scans stamped by the
    wall clock), or serving the cell over OPC UA (--opcua: a simulated plant runs in real
    time too). Without a duration it runs until interrupted (Ctrl-C, SIGTERM)."""
    from hmi.opcua.options import start_server
    from hmi.report import run_summary
    from hmi.runio import RunOutputs
    from hmi.session.live import WallClock, run_live_for
    from hmi.session.session import Session

    plant = engine.plant
    collector = RunCollector()
    controller = Session(engine, args.period, clock=WallClock() if plant.is_real else None)
    outputs = None
    server = None
    interrupted = False
    try:
        # The journal first, so that the connection attempts (and giving up) are in it.
        outputs = RunOutputs(controller, args.trace, args.journal, "run")
        server = start_server(controller, args)
        announce(server, engine.project.name)
        connect_plant(engine, args.connect_timeout or 10_000_000)

        def on_scan(snap) -> bool:
            collector.add(snap)
            if outputs.write(snap):
                outputs.leave_safe()
                return True
            return False
        started = time.perf_counter()
        try:
            with _terminate_as_interrupt():
                runner = run_live_for(controller, duration_us or MAX_SERVE_US, on_scan)
        except KeyboardInterrupt:
            interrupted = True
            runner = None
        wall = time.perf_counter() - started
        at_end = plant.status  # the link as the run ended, before the stop closes it
    finally:
        if server is not None:
            server.stop()
        stop_plant(engine)
        if outputs is not None:
            outputs.close(ended_by(sys.exc_info()[1]))
    if outputs.failure is not None:
        raise RunFailure(outputs.failure_message())
    last = controller.last
    if last is None:
        return 130 if interrupted else 0
    print(run_summary(engine, last, collector, [], wall, trace=outputs.trace,
                      time_kind="real"))
    print(alarm_summary(collector, args.explain))
    if plant.is_real:
        # After the stop: its write of the safe vector is counted like any other request.
        print(plant_report(plant, at_end, runner.overruns if runner else 0))
        print(f"Stopped: {plant.message}")
    print(f"Journal: {outputs.recorder.journal.path}")
    return 0


def ended_by(exc: BaseException | None) -> str | None:
    """Why a session is ending, for the journal's last entry (None: it ended as asked).
    Called in a `finally`, with the exception on its way out, if any."""
    if exc is None:
        return None
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted (SIGINT)"
    if isinstance(exc, RunFailure | UsageError):
        return str(exc)
    return f"internal error: {type(exc).__name__}: {exc}"


def announce(server, name: str) -> None:
    """Say where the cell is served (on stderr: a served run's stdout is its summary)."""
    if server is not None:
        print(f"plchmi: serving {name} over OPC UA at {server.url}"
              + (" (operator commands enabled)" if server.options.writable else ""),
              file=sys.stderr, flush=True)


MAX_SERVE_US = 10 * 365 * 24 * 3600 * 1_000_000  # "until interrupted": ten years


class _terminate_as_interrupt:
    """SIGTERM (a service manager stopping the cell) ends a served run like Ctrl-C: the
    outputs are left safe, the journal is closed and the summary printed."""

    def __enter__(self) -> None:
        import signal
        self.previous = signal.signal(signal.SIGTERM, self._raise)

    def __exit__(self, *exc) -> None:
        import signal
        signal.signal(signal.SIGTERM, self.previous)

    @staticmethod
    def _raise(signum, frame) -> None:
        raise KeyboardInterrupt


def stop_plant(engine) -> None:
    """At the end of a run on a real plant, leave its outputs safe, as a stopping PLC does."""
    safe = dict(zip(engine.layout.outputs, engine.safe_vector, strict=True))
    engine.plant.stop(engine.now, safe)


def plant_report(plant, at_end, overruns: int) -> str:
    """What a run against a Modbus plant saw of it: the link as it was when the run ended
    (`at_end`), and every request sent, the stop's included."""
    d = plant.status.details
    stop = f", of which {d['stop_writes']} at stop" if d["stop_writes"] else ""
    lines = [f"Plant {at_end.description}: "
             f"{'connected' if at_end.connected else 'NOT CONNECTED'} ({at_end.message})",
             f"  requests {d['requests']} (reads {d['reads']}, writes {d['writes']}{stop}), "
             f"exception responses {d['exceptions']}, timeouts {d['timeouts']}, "
             f"invalid answers {d['invalid']}, connections lost {d['losses']}, "
             f"connections made {d['connects']}"]
    io = plant.io_percentiles()
    if io:
        lines.append(f"  Modbus I/O per scan: p50 {io[0] / 1000:.2f} ms, p99 {io[1] / 1000:.2f} "
                     f"ms, max {d['max_io_ms']:.2f} ms; scans slower than the period "
                     f"{d['slow_scans']}; scan overruns {overruns}")
    return "\n".join(lines)


def _bench_sections() -> list[str]:
    from hmi.bench import NAMES
    return list(NAMES)


def cmd_bench(args: argparse.Namespace) -> int:
    from hmi.bench import sections
    available = sections()
    chosen = args.sections or list(available)
    unknown = [s for s in chosen if s not in available]
    if unknown:
        raise UsageError(f"unknown bench section {', '.join(unknown)}; sections: "
                         + ", ".join(available))
    for index, name in enumerate(chosen):
        if index:
            print()
        print(f"== bench {name}: {available[name].HELP}", flush=True)
        available[name].run(args)
    return 0


def cmd_ui(args: argparse.Namespace) -> int:
    from hmi.opcua.options import check_arguments, start_server
    from hmi.session.session import Session
    from hmi.ui.app import run_app
    check_arguments(args)
    project = load(args.project, getattr(args, "diagnoser", None))
    engine, injections = make_engine(project, args)
    clock = None
    if engine.plant.is_real:
        from hmi.session.live import WallClock
        clock = WallClock()
    controller = Session(engine, clock=clock)
    recorder = None
    end = None
    server = None
    try:
        recorder = open_journal(controller, args.journal, "hmi")
        server = start_server(controller, args, log_file=True)
        announce(server, project.name)
        if clock is not None:
            connect_plant(engine, args.connect_timeout)
        end = run_app(controller, injected=tuple(injections),
                      on_fault=recorder.on_ui_fault, bell=getattr(args, "bell", False))
        if end.reason is not None:
            print(f"plchmi: the HMI ended on an error: {end.reason}", file=sys.stderr)
        return end.status
    finally:
        if server is not None:
            server.stop()
        # a real plant: the safe outputs first, then the journal says how it ended
        if clock is not None:
            stop_plant(engine)
        if recorder is not None:
            if end is not None:
                recorder.close(end.reason, end.note)
            else:
                recorder.close(ended_by(sys.exc_info()[1]))


def cmd_serve_plant(args: argparse.Namespace) -> int:
    from hmi.plant.injection import parse_injection
    from hmi.plant.modbus.address_map import address_diagnostics
    from hmi.plant.modbus.server import COMM_FAULTS, run_server

    project = load(args.project, getattr(args, "diagnoser", None))
    errors = address_diagnostics(project, "serve-plant serves every input and output at its "
                                 "address")
    if errors:
        raise ProjectError(errors)
    if not project.plant.devices:
        raise UsageError("the project has no simulated devices to serve")
    injections = [parse_injection(text) for text in args.inject]
    unit = project.plant.unit if args.unit is None else args.unit
    check_host(args.host)
    try:
        return run_server(project, args.host, args.port, unit, injections, args.delay or 0,
                          args.max_connections, args.idle_timeout / 1e6)
    except UsageError as exc:
        if "unknown fault" in str(exc):
            raise UsageError(f"{exc}; communication faults: {', '.join(COMM_FAULTS)}"
                             ) from None
        raise


def check_host(host: str) -> None:
    """A --host that names no address is a usage error said as such (not "port in use")."""
    import socket
    try:
        socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise UsageError(f"--host {host!r}: no such host or address ({exc.strerror})") from None
    except (UnicodeError, ValueError) as exc:
        raise UsageError(f"--host {host!r} is not a host name or address ({exc})") from None


__all__ = ["format_duration", "main", "seconds"]


def cmd_export(args: argparse.Namespace) -> int:
    from hmi.export import export
    project = load(args.project)
    if args.output.exists() and not args.output.is_dir():
        raise UsageError(f"-o {args.output}: not a folder")
    try:
        written = export(project, args.format, args.output)
    except OSError as exc:
        raise UsageError(f"-o {args.output}: cannot write there ({exc.strerror})") from None
    print(f"Wrote {written.path}")
    for line in written.model.summary:
        print(f"  {line}")
    return 0


def cmd_opcua_passwd(args: argparse.Namespace) -> int:
    from hmi.opcua.users import write_user
    if args.stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        import getpass
        password = getpass.getpass(f"Password for {args.name}: ")
        if getpass.getpass("Again: ") != password:
            raise UsageError("the two passwords differ; nothing was written")
    new = write_user(args.file, args.name, password)
    print(f"{'Added' if new else 'Replaced'} user {args.name} in {args.file}")
    return 0


COMMANDS = {
    "check": cmd_check, "run": cmd_run, "sweep": _sweep, "ui": cmd_ui,
    "serve-plant": cmd_serve_plant, "bench": cmd_bench, "journal": cmd_journal,
    "diagnose": cmd_diagnose, "campaign": cmd_campaign, "export": cmd_export,
    "opcua-passwd": cmd_opcua_passwd, "soak": _soak,
}

if __name__ == "__main__":
    raise SystemExit(main())

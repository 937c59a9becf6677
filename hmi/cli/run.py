"""``plchmi run PROJECT``: a headless run, in virtual time on a simulated plant, in real time
on a real plant or when serving the cell over OPC UA."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure, ended_by, load
from hmi.cli.options import (
    diagnoser_arg,
    duration,
    engine_args,
    historian_args,
    journal_space_arg,
    period,
    plant_args,
    project_arg,
)
from hmi.cli.session import announce, connect_plant, make_engine, open_historian, stop_plant
from hmi.cli.summary import alarm_summary, plant_report
from hmi.errors import UsageError

if TYPE_CHECKING:
    from types import FrameType

    from hmi.cli.common import Subparsers
    from hmi.engine.scan import Engine
    from hmi.history.historian import Historian
    from hmi.session.view import CellView


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("run", help="run headless in virtual time")
    project_arg(p)
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--for", dest="duration", type=duration, metavar="TIME",
                   help="virtual time to run, e.g. 60s (default: the scenario's)")
    p.add_argument("--scenario", metavar="NAME",
                   help="inject the faults of a scenario the project declares")
    p.add_argument("--period", type=period, metavar="TIME",
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
    journal_space_arg(p)
    historian_args(p, "off for a run in virtual time; in real time (a real plant, "
                   "--opcua) a SQLite file in the data folder")
    from hmi.opcua.options import add_arguments as opcua_args
    opcua_args(p)


def cmd_run(args: argparse.Namespace) -> int:
    from hmi.session.run_report import RunCollector, run_summary
    from hmi.session.runio import RunOutputs
    from hmi.session.session import Session, settle_memory

    project = load(args.project, getattr(args, "diagnoser", None))
    scenario = None
    if args.scenario:
        from hmi.project.scenarios import find_scenario
        scenario = find_scenario(project, args.scenario)
    duration: int | None = args.duration or (scenario.duration_us if scenario else None)
    from hmi.opcua.options import check_arguments
    check_arguments(args)
    if duration is None and args.opcua is None:
        raise UsageError("--for TIME is required (or a --scenario that sets its length)")
    if duration is not None:
        run_length_notice(duration, args.period or project.scan_period_us)
    engine, injections = make_engine(project, args, scenario.injections if scenario else ())
    if engine.plant.is_real or args.opcua is not None:
        return run_real_time(engine, args, duration)
    assert duration is not None  # checked above: a run without one serves in real time
    session = Session(engine, args.period)
    collector = RunCollector()
    outputs = RunOutputs(session, args.trace, args.journal, "run")
    outputs.recorder.space(args.journal_space)
    try:
        historian = open_historian(session, args, outputs.recorder, "run",
                                   default_on=False, run_us=duration)
    except BaseException:
        outputs.close(ended_by(sys.exc_info()[1]))
        raise
    settle_memory()
    started = time.perf_counter()
    def on_scan(cell: CellView) -> None:
        collector.add(cell)
        if outputs.write(cell.snapshot):
            raise _OutputFailed

    # Without a trace, a quiet scan (nothing new: Session.run_for) is only counted.
    quiet = collector.quiet if outputs.writer is None else None
    try:
        last = session.run_for(duration, on_scan, quiet)
    except _OutputFailed:
        outputs.leave_safe()
        failed = session.last
        assert failed is not None  # set before the listener that raised ran
        last = failed
    finally:
        outputs.close(ended_by(sys.exc_info()[1]))
        if historian is not None:
            historian.close()
    if outputs.failure is not None:
        raise RunFailure(outputs.failure_message())
    wall = time.perf_counter() - started
    collector.finish(last)
    if scenario:
        print(f"Scenario {scenario.name}: {scenario.description}")
    print(run_summary(engine, last.snapshot, collector, injections, wall,
                      trace=outputs.trace))
    print(alarm_summary(collector, args.explain))
    print(f"Journal: {outputs.recorder.journal.path}")
    history_line(historian)
    return 0


def history_line(historian: Historian | None) -> None:
    """Where the run's history went, and how much of it (or why not all)."""
    if historian is None:
        return
    status = historian.status
    line = f"History: {historian.target.describe()} ({status.written:,} samples and events"
    if status.dropped:
        line += f"; {status.dropped:,} lost"
    if status.state == "failing" or status.waiting:
        line += f"; {status.waiting:,} could not be written: {status.error}"
    print(line + ")")


class _OutputFailed(Exception):
    """Ends a headless run at the scan whose trace or journal could not be written."""


def run_length_notice(duration_us: int, period_us: int) -> None:
    """Refuse a run too long to finish; say so up front when one will take a while."""
    from hmi.session.runio import RunLengthError, check_run_length
    try:
        notice = check_run_length(duration_us, period_us)
    except RunLengthError as exc:
        raise UsageError(str(exc)) from None
    if notice:
        print(f"plchmi: {notice}", file=sys.stderr, flush=True)


def run_real_time(engine: Engine, args: argparse.Namespace, duration_us: int | None) -> int:
    """A headless run paced by the wall clock: against a real plant (scans stamped by the
    wall clock), or serving the cell over OPC UA (--opcua: a simulated plant runs in real
    time too). Without a duration it runs until interrupted (Ctrl-C, SIGTERM)."""
    from hmi.opcua.options import start_server
    from hmi.session.live import WallClock, run_live_for
    from hmi.session.run_report import RunCollector, run_summary
    from hmi.session.runio import RunOutputs
    from hmi.session.session import Session

    plant = engine.plant
    collector = RunCollector()
    session = Session(engine, args.period, clock=WallClock() if plant.is_real else None)
    outputs = None
    historian = None
    server = None
    interrupted = False
    try:
        # The journal first, so that the connection attempts (and giving up) are in it.
        outputs = RunOutputs(session, args.trace, args.journal, "run")
        outputs.recorder.space(args.journal_space)
        historian = open_historian(session, args, outputs.recorder, "run", default_on=True)
        server = start_server(session, args, journal=outputs.recorder,
                              history=historian.target if historian else None)
        announce(server, engine.project.name)
        connect_plant(engine, args.connect_timeout or 10_000_000)

        def on_scan(cell: CellView) -> bool:
            collector.add(cell)
            if outputs.write(cell.snapshot):
                outputs.leave_safe()
                return True
            return False
        started = time.perf_counter()
        try:
            with _terminate_as_interrupt():
                runner = run_live_for(session, duration_us or MAX_SERVE_US, on_scan)
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
        if historian is not None:
            historian.close()
    if outputs.failure is not None:
        raise RunFailure(outputs.failure_message())
    last = session.last
    if last is None:
        return 130 if interrupted else 0
    print(run_summary(engine, last.snapshot, collector, [], wall, trace=outputs.trace,
                      time_kind="real"))
    print(alarm_summary(collector, args.explain))
    if plant.is_real:
        from hmi.plant.modbus.client import ModbusPlant
        assert isinstance(plant, ModbusPlant)  # the one real plant
        # After the stop: its write of the safe vector is counted like any other request.
        print(plant_report(plant, at_end, runner.overruns if runner else 0))
        print(f"Stopped: {plant.message}")
    print(f"Journal: {outputs.recorder.journal.path}")
    history_line(historian)
    return 0


MAX_SERVE_US = 10 * 365 * 24 * 3600 * 1_000_000  # "until interrupted": ten years


class _terminate_as_interrupt:
    """SIGTERM (a service manager stopping the cell) ends a served run like Ctrl-C: the
    outputs are left safe, the journal is closed and the summary printed."""

    def __enter__(self) -> None:
        import signal
        self.previous = signal.signal(signal.SIGTERM, self._raise)

    def __exit__(self, *exc: object) -> None:
        import signal
        signal.signal(signal.SIGTERM, self.previous)

    @staticmethod
    def _raise(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

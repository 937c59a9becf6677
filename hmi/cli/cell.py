"""``plchmi serve PROJECT`` (the cell's runtime: scans, plant, alarms, journal, and the
endpoint its screens attach to) and ``plchmi attach PROJECT [--view]`` (a screen of a
running cell). ``plchmi PROJECT`` (hmi.cli.ui) starts a runtime if none runs, then attaches.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure, ended_by, on_termination
from hmi.cli.options import diagnoser_arg, project_arg
from hmi.cli.screens import run_screen, runtime_args, users_file
from hmi.errors import UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers
    from hmi.runtime.place import Place
    from hmi.session.view import CellView


def add_parsers(sub: Subparsers) -> None:
    p = sub.add_parser("serve", help="run the cell: the runtime its screens attach to",
                       description="The cell's runtime: the scan, the plant, the alarms and "
                       "the journal, in a process of its own; operator screens attach to it "
                       "(plchmi attach PROJECT). Runs until the screen in control stops it, "
                       "or SIGTERM / Ctrl-C.")
    project_arg(p)
    runtime_args(p)
    p.add_argument("--virtual", action="store_true",
                   help="virtual time: scans run only when the screen in control says "
                   "(tests, the soak)")
    p.add_argument("--trace", type=Path, metavar="FILE",
                   help="write every scan to FILE (.csv or .jsonl), as plchmi run does")
    p.add_argument("--no-realtime", action="store_true",
                   help="do not ask for a real-time priority for the scan thread")
    from hmi.opcua.options import add_arguments as opcua_args
    opcua_args(p)  # served by a gateway process beside the runtime (plchmi gateway)

    p = sub.add_parser("attach", help="attach a screen to a running cell",
                       description="The operator HMI of a cell whose runtime runs "
                       "(plchmi serve, or plchmi PROJECT): any number of screens, one in "
                       "control at a time.")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--view", action="store_true",
                   help="attach to view: no command is sent, control is never taken")
    p.add_argument("--socket", type=Path, metavar="PATH",
                   help="the runtime's socket (default: the project's)")
    p.add_argument("--bell", action="store_true",
                   help="ring the terminal bell when a new unacknowledged P1 alarm appears")


# -- the runtime ---------------------------------------------------------------------------

def cmd_serve(args: argparse.Namespace) -> int:
    from hmi.cli.session import connect_plant, make_engine, open_historian, stop_plant
    from hmi.opcua.options import check_arguments
    from hmi.project.kept import TooBig, fingerprint, load
    from hmi.runtime.place import Held, RuntimeLock, place
    from hmi.runtime.runtime import Runtime
    from hmi.session.runio import RunOutputs
    from hmi.session.session import Session
    check_arguments(args)
    diagnoser = getattr(args, "diagnoser", None)
    project = load(args.project, diagnoser)
    try:
        print_ = fingerprint(args.project, diagnoser)
    except TooBig as exc:
        raise UsageError(f"the project's folder is too big to fingerprint ({exc})") from None
    if args.trace is not None and not args.virtual:
        raise UsageError("--trace needs --virtual (a trace of every scan in virtual time)")
    where = place(project.name, args.socket)
    try:
        lock = RuntimeLock(where)
    except Held as held:
        raise RunFailure(f"a runtime already runs {project.name}"
                         + (f" (pid {held.pid})" if held.pid else "")
                         + f": attach to it with plchmi attach {args.project}") from None
    engine = None
    outputs = None
    historian = None
    runtime = None
    gateway = None
    abnormal: str | None = None
    try:
        engine, _ = make_engine(project, args)
        clock = None
        if engine.plant.is_real:
            if args.virtual:
                raise UsageError("--virtual on a real plant: a real plant runs in real time")
            from hmi.session.live import WallClock
            clock = WallClock()
        session = Session(engine, clock=clock)
        outputs = RunOutputs(session, args.trace, args.journal, "runtime", background=True)
        outputs.recorder.space(args.journal_space)
        # the cell's history, beside the scans (its own thread writes it): the screens' trends
        historian = open_historian(session, args, outputs.recorder, "runtime",
                                   default_on=not args.virtual)
        connect_plant(engine, args.connect_timeout)
        if outputs.writer is not None:  # (before the runtime's first scan: it is traced too)
            def traced(cell: CellView) -> None:
                if outputs is not None and outputs.write(cell.snapshot):
                    outputs.leave_safe()
                    if runtime is not None:
                        runtime.end(f"the trace could not be written: {outputs.failure}")
            session.scan_listeners.append(traced)
        # who may attach: the users file the OPC UA door signs in against (one identity at
        # every door of this cell), else the machine's
        from hmi.runtime.admission import Admission
        runtime = Runtime(session, print_, where.socket, outputs.recorder,
                          virtual=args.virtual, realtime=not args.no_realtime,
                          admission=Admission(users_file(args)))
        with on_termination(runtime.end):  # (ended as asked: safe outputs, journal closed)
            runtime.start()
            scan = runtime.runner.realtime_state if runtime.runner else "virtual time"
            print(f"plchmi: {project.name} runs (pid {os.getpid()}; scan thread: {scan}); "
                  f"screens attach at {where.socket}", file=sys.stderr, flush=True)
            gateway = start_gateway(args, where)
            abnormal = runtime.wait()
        why = abnormal or runtime.why or "the runtime stops"
        runtime.stop(why)
    finally:
        if runtime is not None and not runtime.ended.is_set():
            runtime.stop("the runtime stops on an error")
        if gateway is not None:
            stop_gateway(gateway)
        if engine is not None and engine.plant.is_real:
            stop_plant(engine)  # the safe outputs first, then the journal says how it ended
        if outputs is not None:
            outputs.close(abnormal or ended_by(sys.exc_info()[1]))
        if historian is not None:  # after the journal's last entry, which it keeps too
            historian.close()
        lock.release()
    if outputs is not None and outputs.failure is not None:
        raise RunFailure(outputs.failure_message())
    if abnormal is not None:
        print(f"plchmi: the runtime ended on an error: {abnormal}", file=sys.stderr)
        return 1
    return 0


GATEWAY_END_S = 10.0  # a gateway told the runtime stops ends by itself within this


def start_gateway(args: argparse.Namespace, where: Place) -> subprocess.Popen[bytes] | None:
    """With --opcua: the OPC UA gateway (plchmi gateway), a process of its own attached to
    this runtime as a screen; its output in gateway.log beside the runtime's."""
    from hmi.opcua.options import passed_on
    options = passed_on(args)
    if not options:
        return None
    command = [sys.executable, "-m", "hmi.cli", "gateway", str(args.project), "--socket",
               str(where.socket), *options]
    if getattr(args, "diagnoser", None):
        command += ["--diagnoser", args.diagnoser]
    log_path = where.folder / "gateway.log"
    with open(log_path, "ab") as log:
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=log, stderr=log)
    print(f"plchmi: the OPC UA gateway starts (pid {process.pid}; its log: {log_path})",
          file=sys.stderr, flush=True)
    return process


def stop_gateway(process: subprocess.Popen[bytes]) -> None:
    """It ends by itself once the runtime closed its screens; else it is told to."""
    try:
        process.wait(GATEWAY_END_S)
    except subprocess.TimeoutExpired:
        process.terminate()
        try:
            process.wait(GATEWAY_END_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


# -- a screen --------------------------------------------------------------------------

def cmd_attach(args: argparse.Namespace) -> int:
    from hmi.project.kept import load
    from hmi.runtime.place import place, running

    project = load(args.project, getattr(args, "diagnoser", None))
    where = place(project.name, args.socket)
    if running(where) is None:
        raise RunFailure(f"no runtime runs {project.name}: start it with "
                         f"plchmi {args.project} (or plchmi serve {args.project})")
    return run_screen(args, project, where.socket, view=args.view)



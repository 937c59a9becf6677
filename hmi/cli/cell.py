"""``plchmi serve PROJECT`` (the cell's runtime: scans, plant, alarms, journal, and the
endpoint its screens attach to) and ``plchmi attach PROJECT [--view]`` (a screen of a
running cell). ``plchmi PROJECT`` (hmi.cli.ui) starts a runtime if none runs, then attaches.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from pathlib import Path

from hmi.cli.common import RunFailure, ended_by
from hmi.cli.options import diagnoser_arg, project_arg
from hmi.cli.screens import run_screen, runtime_args
from hmi.errors import UsageError


def add_parsers(sub) -> None:
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
    from hmi.project.kept import TooBig, fingerprint, load
    from hmi.runtime.place import Held, RuntimeLock, place
    from hmi.runtime.runtime import Runtime
    from hmi.session.runio import RunOutputs
    from hmi.session.session import Session

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
        # the cell's history, beside the scans (its own thread writes it): the screens' trends
        historian = open_historian(session, args, outputs.recorder, "runtime",
                                   default_on=not args.virtual)
        connect_plant(engine, args.connect_timeout)
        if outputs.writer is not None:  # (before the runtime's first scan: it is traced too)
            def traced(snap) -> None:
                if outputs is not None and outputs.write(snap):
                    outputs.leave_safe()
                    if runtime is not None:
                        runtime.end(f"the trace could not be written: {outputs.failure}")
            session.scan_listeners.append(traced)
        runtime = Runtime(session, print_, where.socket, outputs.recorder,
                          virtual=args.virtual, realtime=not args.no_realtime)
        with _ending(runtime):
            runtime.start()
            scan = runtime.runner.realtime_state if runtime.runner else "virtual time"
            print(f"plchmi: {project.name} runs (pid {os.getpid()}; scan thread: {scan}); "
                  f"screens attach at {where.socket}", file=sys.stderr, flush=True)
            abnormal = runtime.wait()
        why = abnormal or runtime.why or "the runtime stops"
        runtime.stop(why)
    finally:
        if runtime is not None and not runtime.ended.is_set():
            runtime.stop("the runtime stops on an error")
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


@contextlib.contextmanager
def _ending(runtime):
    """SIGTERM and SIGINT end the runtime as asked (safe outputs, the journal closed)."""
    def end(signum, frame) -> None:
        runtime.end(f"{signal.Signals(signum).name} received")
    previous = {s: signal.signal(s, end) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


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



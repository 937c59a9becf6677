"""``plchmi serve PROJECT`` (the cell's runtime: scans, plant, alarms, journal, and the
endpoint its screens attach to) and ``plchmi attach PROJECT [--view]`` (a screen of a
running cell). ``plchmi PROJECT`` (hmi.cli.ui) starts a runtime if none runs, then attaches.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from hmi.cli.common import RunFailure, ended_by
from hmi.cli.options import diagnoser_arg, engine_args, plant_args, project_arg
from hmi.errors import UsageError

START_S = 60.0  # a runtime starting (a real plant's connection included) is waited for


def runtime_args(p: argparse.ArgumentParser) -> None:
    """What the runtime is started with (also `plchmi PROJECT`'s, passed on to it)."""
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="schedule a fault in the simulated plant")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="journal file (default: the user's data folder, see plchmi journal)")
    p.add_argument("--socket", type=Path, metavar="PATH",
                   help="the runtime's socket (default: runtime.sock in the project's data "
                   "folder)")
    plant_args(p, "keep trying")


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
    from hmi.cli.session import connect_plant, make_engine, stop_plant
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


def run_screen(args: argparse.Namespace, project, socket: Path, view: bool = False) -> int:
    """The HMI attached to the runtime at `socket`; what its quit asked (stop the cell or
    leave it running) is done on the way out."""
    from hmi.link.base import local_operator
    from hmi.link.client import AttachError, SocketLink
    from hmi.project.kept import fingerprint
    from hmi.ui.app import PlcHmiApp, app_end

    identity = local_operator(role="viewer" if view else "operator")
    try:
        link = SocketLink(project, socket, fingerprint(args.project, args.diagnoser),
                          identity, want_control=not view)
    except AttachError as exc:
        raise RunFailure(str(exc)) from None
    app = PlcHmiApp(link, live=True, bell=getattr(args, "bell", False))
    app.containment.listeners.append(link.report_fault)  # the runtime journals them
    try:
        app.run()
    finally:
        link.leave(stop_cell=app.stop_cell)
    end = app_end(app)
    if end.reason is not None:
        print(f"plchmi: the HMI ended on an error: {end.reason}; the cell runs on "
              f"(plchmi attach {args.project})", file=sys.stderr)
    elif app.stop_cell:
        stopped = wait_stopped(socket.parent if args.socket else None, project.name)
        print(f"plchmi: {project.name} stopped" if stopped else
              f"plchmi: {project.name} was asked to stop and still runs", file=sys.stderr)
    elif link.lost is None or "left" in link.lost:
        print(f"plchmi: {project.name} keeps running (plchmi attach {args.project})",
              file=sys.stderr)
    return end.status


def wait_stopped(folder: Path | None, name: str, guard_s: float = 60.0) -> bool:
    """Until the runtime asked to stop has ended (its lock released: a real plant's outputs
    are safe by then), at most `guard_s`."""
    from hmi.runtime.place import Place, place, running
    where = Place(folder) if folder is not None else place(name)
    deadline = time.monotonic() + guard_s
    while running(where) is not None:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def start_runtime(args: argparse.Namespace, project, where) -> None:
    """Start `plchmi serve` for the project, detached (it outlives this screen), and wait
    until it accepts screens; RunFailure with its last words if it ends instead."""
    from hmi.link.client import AttachError, connect

    command = [sys.executable, "-m", "hmi.cli", "serve", str(args.project),
               *passed_on(args)]
    where.folder.mkdir(parents=True, exist_ok=True)
    with open(where.log, "ab") as log:
        log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {' '.join(command)}\n".encode())
        log.flush()
        process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=log,
                                   stderr=log, start_new_session=True)
    print(f"plchmi: starting {project.name}'s runtime (pid {process.pid}; its log: "
          f"{where.log})", file=sys.stderr, flush=True)
    deadline = time.monotonic() + START_S + (args.connect_timeout or 0) / 1e6
    while time.monotonic() < deadline:
        status = process.poll()
        if status is not None:
            raise RunFailure(f"the runtime ended (exit status {status}) before accepting "
                             f"screens: {last_words(where.log)}")
        with contextlib.suppress(AttachError):
            connect(where.socket, 1.0).close()
            return
        time.sleep(0.02)
    raise RunFailure(f"the runtime did not accept screens within {START_S:g} s; its log: "
                     f"{where.log}")


def passed_on(args: argparse.Namespace) -> list[str]:
    """`plchmi PROJECT`'s options that are the runtime's, as `plchmi serve` takes them."""
    out: list[str] = []
    for option, name in (("--diagnoser", "diagnoser"), ("--control", "control"),
                         ("--policy", "policy"), ("--solver", "solver"),
                         ("--solver-budget", "solver_budget"), ("--journal", "journal"),
                         ("--socket", "socket"), ("--plant", "plant")):
        value = getattr(args, name, None)
        if value is not None:
            out += [option, str(value)]
    for text in getattr(args, "inject", []):
        out += ["--inject", text]
    if getattr(args, "connect_timeout", None) is not None:
        from hmi.timefmt import format_duration
        out += ["--connect-timeout", format_duration(args.connect_timeout)]
    for flag, name in (("--read-only", "read_only"), ("--allow-monitor", "allow_monitor")):
        if getattr(args, name, False):
            out.append(flag)
    return out


def given_runtime_options(args: argparse.Namespace) -> list[str]:
    """The runtime's options given to `plchmi PROJECT` (they cannot change a running one)."""
    return [o for o in passed_on(args) if o.startswith("--") and o != "--socket"]


def last_words(log: Path, lines: int = 6) -> str:
    try:
        text = log.read_text(errors="replace").strip().splitlines()
    except OSError:
        return "(its log cannot be read)"
    return " / ".join(text[-lines:]) or "(nothing in its log)"

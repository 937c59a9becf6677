"""What the commands that show a running cell share: the options the cell's runtime is
started with, starting one detached (``plchmi PROJECT``), and a screen attached to it (the
HMI over its socket) until the operator quits — stopping the cell or leaving it running."""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure
from hmi.cli.options import (
    diagnoser_arg,
    engine_args,
    historian_args,
    journal_space_arg,
    plant_args,
)

if TYPE_CHECKING:
    from hmi.link.base import Identity
    from hmi.link.client import SocketLink
    from hmi.project.model import Project
    from hmi.runtime.place import Place

START_S = 60.0  # a runtime starting (a real plant's connection included) is waited for


def runtime_args(p: argparse.ArgumentParser) -> None:
    """What the runtime is started with (also `plchmi PROJECT`'s, passed on to it)."""
    diagnoser_arg(p)
    engine_args(p)
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="schedule a fault in the simulated plant")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="journal file (default: the user's data folder, see plchmi journal)")
    journal_space_arg(p)
    p.add_argument("--socket", type=Path, metavar="PATH",
                   help="the runtime's socket (default: runtime.sock in the project's data "
                   "folder)")
    plant_args(p, "keep trying")
    historian_args(p, "a SQLite file in the data folder, beside the journal")


def run_screen(args: argparse.Namespace, project: Project, socket: Path,
               view: bool = False) -> int:
    """The HMI attached to the runtime at `socket`; what its quit asked (stop the cell or
    leave it running) is done on the way out."""
    from hmi.link.base import Identity, local_operator
    from hmi.link.client import AttachError, SocketLink
    from hmi.project.kept import fingerprint
    from hmi.ui.app import PlcHmiApp, app_end

    identity = local_operator(role="viewer" if view else "operator")
    print_ = fingerprint(args.project, args.diagnoser)
    ticket = os.environ.pop("PLCHMI_TICKET", "")  # a browser tab's (hmi.web.server)
    if ticket:
        identity = Identity("browser", identity.role, "browser", identity.session)
    path = users_file(args)
    try:
        if ticket or not signs_in(path):
            try:
                link = SocketLink(project, socket, print_, identity, want_control=not view,
                                  ticket=ticket)
            except AttachError as exc:
                # the runtime has users this screen did not know of (started with
                # --opcua-users FILE): the terminal asks who is there, as it would have
                if ticket or "sign in first" not in str(exc):
                    raise
                link = signed_in(project, socket, print_, identity, view, None)
        else:
            link = signed_in(project, socket, print_, identity, view, path)
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


SIGN_IN_TRIES = 3


def users_file(args: argparse.Namespace) -> Path:
    """The users file of the cell's doors: ``--opcua-users FILE`` where given (the OPC UA
    door's users are the terminal's and the runtime's too), else the machine's."""
    from hmi.access import users
    return getattr(args, "opcua_users", None) or users.default_path()


def signs_in(path: Path) -> bool:
    """Whether this terminal asks who is there: a users file exists and does not give the
    local terminal a role of its own (local-terminal = ROLE)."""
    from hmi.access import users
    found = users.read(path)
    return found is not None and found.settings.local_terminal == "sign-in"


def signed_in(project: Project, socket: Path, print_: str, identity: Identity, view: bool,
              path: Path | None) -> SocketLink:
    """The terminal's sign-in: a name and a password (not echoed), checked by the runtime
    against its users file (`path`, where this screen knows it: its banner is shown); a
    few tries, then the screen ends."""
    import getpass
    from dataclasses import replace

    from hmi.access import users
    from hmi.link.client import AttachError, SocketLink
    found = users.read(path) if path is not None else None
    banner = found.settings.banner if found is not None else ""
    whose = f"the users of {path}" if path is not None else "a user of the cell's runtime"
    print(f"{project.name}: sign in ({whose})", file=sys.stderr)
    if banner:
        print(banner, file=sys.stderr)
    why = ""
    for _ in range(SIGN_IN_TRIES):
        try:
            name = input(f"User name [{identity.user}]: ").strip() or identity.user
            password = getpass.getpass("Password: ")
        except EOFError:
            raise AttachError("sign-in ended (no input)") from None
        try:
            return SocketLink(project, socket, print_, replace(identity, user=name),
                              want_control=not view, password=password)
        except AttachError as exc:
            why = str(exc)
            if not why.startswith("not signed in"):
                raise
            print(f"plchmi: {why}", file=sys.stderr)
    raise AttachError(f"{why} ({SIGN_IN_TRIES} tries)")


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


def start_runtime(args: argparse.Namespace, project: Project, where: Place) -> None:
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
                         ("--socket", "socket"), ("--plant", "plant"),
                         ("--historian", "historian")):
        value = getattr(args, name, None)
        if value is not None:
            out += [option, str(value)]
    for text in getattr(args, "inject", []):
        out += ["--inject", text]
    from hmi.timefmt import format_duration
    if getattr(args, "connect_timeout", None) is not None:
        out += ["--connect-timeout", format_duration(args.connect_timeout)]
    if getattr(args, "journal_space", 1 << 30) != 1 << 30:  # (bytes: the default's type)
        out += ["--journal-space", f"{max(1000, args.journal_space // 1000)}kB"]
    if getattr(args, "history_retention", None) is not None:  # (a length: whole seconds)
        out += ["--history-retention", f"{max(1, args.history_retention // 1_000_000)}s"]
    for flag, name in (("--read-only", "read_only"), ("--allow-monitor", "allow_monitor")):
        if getattr(args, name, False):
            out.append(flag)
    from hmi.opcua.options import passed_on as opcua_options
    return out + opcua_options(args)


def given_runtime_options(args: argparse.Namespace) -> list[str]:
    """The runtime's options given to `plchmi PROJECT` (they cannot change a running one)."""
    return [o for o in passed_on(args) if o.startswith("--") and o != "--socket"]


def last_words(log: Path, lines: int = 6) -> str:
    try:
        text = log.read_text(errors="replace").strip().splitlines()
    except OSError:
        return "(its log cannot be read)"
    return " / ".join(text[-lines:]) or "(nothing in its log)"

"""``plchmi gateway PROJECT --opcua URL``: the cell's OPC UA server, a process of its own
attached to the cell's runtime as one of its screens (door ``opcua``).

Whatever an OPC UA client does — a HEL claiming gigabytes, a flood of reads — costs this
process, never the scan's: the runtime only sees one more screen, whose frames it drops if
it falls behind. The gateway serves what its frames carry (every scan's alarm transitions
included, so Part 9 events are not skipped) and sends its users' commands on their behalf;
the runtime journals them with the OPC UA user, and refuses them unless the gateway is in
control (with --opcua-writable it takes control at attaching if nobody holds it).

It reports its state to the runtime (the screens show it, the journal records each change)
and ends when the runtime ends (its clients then lose the server: never stale values shown
as live), on SIGTERM or Ctrl-C. ``plchmi serve --opcua`` starts one beside the runtime.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure, on_termination
from hmi.cli.options import diagnoser_arg, project_arg

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers

LOOK_S = 0.25  # how often the gateway looks at its server and its link (a change is told)


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("gateway", help="serve a running cell over OPC UA (a process of its "
                       "own, attached to the cell's runtime)",
                       description="The cell's OPC UA server as a gateway process attached "
                       "to the cell's runtime (plchmi serve PROJECT): no OPC UA client can "
                       "slow the scan. plchmi serve --opcua starts one.")
    project_arg(p)
    diagnoser_arg(p)
    p.add_argument("--socket", type=Path, metavar="PATH",
                   help="the runtime's socket (default: the project's)")
    from hmi.opcua.options import add_arguments
    add_arguments(p)


def cmd_gateway(args: argparse.Namespace) -> int:
    from hmi.link.client import AttachError, SocketLink
    from hmi.opcua.options import DEFAULT_URL, check_arguments, start_server, status_words
    from hmi.opcua.source import LinkSource
    from hmi.project.kept import fingerprint, load
    from hmi.runtime.place import place, running
    from hmi.session.session import settle_memory
    from hmi.wire import messages as m

    if args.opcua is None:
        args.opcua = DEFAULT_URL
    check_arguments(args)
    diagnoser = getattr(args, "diagnoser", None)
    project = load(args.project, diagnoser)
    where = place(project.name, args.socket)
    if running(where) is None:
        raise RunFailure(f"no runtime runs {project.name}: start it with "
                         f"plchmi serve {args.project} (or plchmi {args.project})")
    identity = m.local_operator(role="operator" if args.opcua_writable else "viewer",
                                door="opcua")
    try:
        link = SocketLink(project, where.socket, fingerprint(args.project, diagnoser),
                          identity, want_control=args.opcua_writable)
    except AttachError as exc:
        raise RunFailure(str(exc)) from None
    server = None
    stop = threading.Event()
    why = "stopped (SIGTERM or Ctrl-C)"
    failed = False
    try:
        link.first_frame.wait(30.0)
        server = start_server(LinkSource(link), args, refused=link.report_refusal)
        assert server is not None
        # the address space is built and stays: out of the collector's sight, or each full
        # collection re-walks its ~480,000 objects (0.2-0.6 s, a HistoryRead's worst case)
        settle_memory()
        print(f"plchmi: serving {project.name} over OPC UA at {server.url} (gateway pid "
              f"{os.getpid()}, screen {link.client} of the runtime)", file=sys.stderr,
              flush=True)
        told = None
        with on_termination(lambda why: stop.set()):
            while True:  # the server's state told at once, then at every change
                status = server.status()
                said = m.ServiceStatus("opcua", status.state, status_words(status),
                                       status.sessions)
                if said != told:
                    link.report(said)
                    told = said
                if link.lost is not None:
                    why = f"the runtime is gone: {link.lost}"
                    failed = "the runtime stopped:" not in link.lost
                    break
                if not status.up:
                    why, failed = status_words(status), True
                    break
                if stop.wait(LOOK_S):
                    break
    finally:
        if server is not None:
            server.stop()
            final = server.status()
            link.report(m.ServiceStatus("opcua", final.state, status_words(final), 0))
        link.leave()
    print(f"plchmi: the OPC UA gateway ended: {why}", file=sys.stderr)
    return 1 if failed else 0


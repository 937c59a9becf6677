"""The serving commands: ``plchmi serve-plant`` (the simulated plant as a Modbus TCP server)
and ``plchmi opcua-passwd`` (the users of the OPC UA server)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hmi.cli.common import load
from hmi.cli.options import duration, positive, project_arg, tcp_port, unit_id
from hmi.errors import ProjectError, UsageError


def add_parsers(sub) -> None:
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
    p.add_argument("--port", type=tcp_port, default=5020,
                   help="TCP port (5020; 0 picks a free one and prints it)")
    p.add_argument("--unit", type=unit_id,
                   help="Modbus unit id (default: the project's, or 1)")
    p.add_argument("--inject", action="append", default=[], metavar="FAULT@TIME",
                   help="a device fault (F5@12s) or a communication fault (busy@5s+2s, "
                   "mute@5s+2s), in time since the server started (repeatable)")
    p.add_argument("--delay", type=duration, metavar="TIME",
                   help="answer every request TIME late (a slow server)")
    p.add_argument("--max-connections", type=positive, default=16, metavar="N",
                   help="connections open at once; more are closed at once (16)")
    p.add_argument("--watchdog", type=duration, metavar="TIME",
                   help="a coupler's communication watchdog: no request for TIME sets every "
                   "order to its safe value")
    p.add_argument("--idle-timeout", type=duration, default=60_000_000, metavar="TIME",
                   help="close a connection with no request for TIME (60s)")


def cmd_serve_plant(args: argparse.Namespace) -> int:
    from hmi.plant.modbus.address_map import address_diagnostics
    from hmi.plant.modbus.server import COMM_FAULTS, run_server
    from hmi.project.injection import parse_injection

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
                          args.max_connections, args.idle_timeout / 1e6, args.watchdog)
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

"""The serving commands: ``plchmi serve-plant`` (the simulated plant as a Modbus TCP server)
and ``plchmi opcua trust`` (the client applications the OPC UA server trusts)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import load
from hmi.cli.options import duration, positive, project_arg, tcp_port, unit_id
from hmi.errors import ProjectError, UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers


def add_parsers(sub: Subparsers) -> None:
    p = sub.add_parser("opcua", help="the OPC UA server's trust list (docs/opcua.md)",
                       description="The client applications (certificates) the OPC UA "
                       "servers of this machine trust: an unknown one is refused and kept "
                       "in the rejected folder for review. Users sign in with the users "
                       "file (plchmi users).")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    trust = actions.add_parser("trust", help="trust a client application's certificate")
    trust.add_argument("cert", type=Path, help="its certificate (DER or PEM), e.g. one from "
                       "the rejected folder")
    actions.add_parser("list", help="the trusted and the rejected certificates")

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


def cmd_opcua(args: argparse.Namespace) -> int:
    from hmi.opcua.users import TrustList, certificate_der, thumbprint
    trust = TrustList()
    if args.action == "trust":
        target = trust.trust(args.cert)
        print(f"Trusted {args.cert} ({target.stem}) in {trust.trusted_folder}")
        return 0
    for title, folder in (("trusted", trust.trusted_folder),
                          ("rejected (for review)", trust.rejected_folder)):
        names = sorted(folder.glob("*")) if folder.is_dir() else []
        print(f"{title}: {folder}" + ("" if names else " (none)"))
        for path in names:
            try:
                print(f"  {thumbprint(certificate_der(path, ''))}  {path.name}")
            except UsageError:
                print(f"  (not a certificate)  {path.name}")
    return 0

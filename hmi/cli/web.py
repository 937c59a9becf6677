"""``plchmi web PROJECT [--bind HOST:PORT] [--cert FILE --key FILE]``: the operator HMI in a
browser, behind a sign-in page (hmi/web, docs/security.md). Each browser tab is a screen of
the cell's one runtime (plchmi serve PROJECT, or plchmi PROJECT left running)."""

from __future__ import annotations

import argparse
import ipaddress
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.cli.common import RunFailure
from hmi.cli.options import project_arg
from hmi.errors import UsageError

if TYPE_CHECKING:
    from hmi.cli.common import Subparsers

DEFAULT_BIND = "127.0.0.1:8080"


def add_parser(sub: Subparsers) -> None:
    p = sub.add_parser("web", help="the operator HMI in a browser, behind a sign-in page",
                       description="Serve the operator HMI to browsers: a sign-in page "
                       "against the users file (plchmi users add), then the same screens as "
                       "the terminal, each tab attached to the cell's running runtime. "
                       "Listens on this machine only unless --bind says otherwise; HTTPS "
                       "with --cert and --key.")
    project_arg(p)
    p.add_argument("--bind", default=DEFAULT_BIND, metavar="HOST:PORT",
                   help=f"address and port to listen on (default {DEFAULT_BIND}: this "
                   "machine only; port 0 picks a free one)")
    p.add_argument("--cert", type=Path, metavar="FILE",
                   help="TLS certificate (PEM; with --key): serve HTTPS")
    p.add_argument("--key", type=Path, metavar="FILE", help="the certificate's private key")
    p.add_argument("--socket", type=Path, metavar="PATH",
                   help="the runtime's socket (default: the project's)")
    p.add_argument("--journal", type=Path, metavar="FILE",
                   help="the cell's journal, where refused sign-ins are written (default: "
                   "the project's, as plchmi serve's)")


def parse_bind(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise UsageError(f"--bind {text!r}: expected HOST:PORT (e.g. {DEFAULT_BIND}, or "
                         "0.0.0.0:8443 for every address)")
    return host, int(port)


def loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cmd_web(args: argparse.Namespace) -> int:
    import asyncio

    from hmi.access import users
    from hmi.project.kept import load
    from hmi.runtime.place import place, running
    try:
        from hmi.web.server import WebDoor, serve, tls_context
    except ImportError as exc:
        raise UsageError(f"plchmi web needs {exc.name or 'textual-serve'}: pip install "
                         "'plchmi[web]'") from None

    host, port = parse_bind(args.bind)
    if (args.cert is None) != (args.key is None):
        raise UsageError("--cert and --key go together (the certificate and its key)")
    users_path = users.default_path()  # the runtime's too: one identity everywhere
    if users.read(users_path) is None:
        raise UsageError(f"{users_path}: no users file, so nobody could sign in: add one "
                         "first (plchmi users add NAME --role operator)")
    context = None
    if args.cert is not None:
        for path in (args.cert, args.key):
            if not path.is_file():
                raise UsageError(f"{path}: no such file")
        import ssl
        try:
            context = tls_context(args.cert, args.key)
        except (ssl.SSLError, OSError) as exc:
            raise UsageError(f"{args.cert}, {args.key}: not a certificate and its key "
                             f"({exc})") from None
    project = load(args.project, None)
    where = place(project.name, args.socket)
    if running(where) is None:
        raise RunFailure(f"no runtime runs {project.name}: start it with plchmi serve "
                         f"{args.project} (or plchmi {args.project}, left running)")
    if not loopback(host) and context is None:
        print(f"plchmi: warning: serving {host} without TLS: passwords and the screens "
              "cross the network in clear text (give --cert and --key)", file=sys.stderr)
    from hmi.explain.journal import default_path
    door = WebDoor(str(args.project), project.name, users_path, args.socket,
                   tls=context is not None,
                   journal=args.journal or default_path(project.name))

    def ready(url: str) -> None:
        print(f"plchmi: {project.name}'s operator screens at {url} (sign in with a user "
              f"of {users_path})", file=sys.stderr, flush=True)

    try:
        asyncio.run(serve(door, host, port, context, ready))
    except OSError as exc:
        raise RunFailure(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    return 0

"""--opcua and its companions: from the command line to a running server.

Kept apart from server.py so that the command line can check every option (and say how to
install asyncua) before anything imports asyncua or opens a plant.
"""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.errors import UsageError
from hmi.opcua import NEEDS_USERS

if TYPE_CHECKING:
    from hmi.access.audit import SignInRefusal
    from hmi.history.target import Target
    from hmi.opcua.server import CellServer
    from hmi.opcua.source import CellSource
    from hmi.opcua.status import ServingStatus
    from hmi.session.journal_recorder import JournalRecorder
    from hmi.session.session import Session

DEFAULT_URL = "opc.tcp://127.0.0.1:4840"
_URL = re.compile(r"^opc\.tcp://(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+)(?::(?P<port>[0-9]{1,5}))?/?$")
MAX_TRUSTED = 100


@dataclass(frozen=True)
class Endpoint:
    host: str
    port: int


def parse_endpoint(text: str) -> Endpoint:
    """`opc.tcp://HOST[:PORT]` (port 4840 by default)."""
    match = _URL.match(text)
    if match is None:
        raise UsageError(f"--opcua {text!r}: expected opc.tcp://HOST:PORT, e.g. {DEFAULT_URL}")
    port = int(match["port"]) if match["port"] else 4840
    if not 1 <= port <= 65535:
        raise UsageError(f"--opcua {text!r}: port {port} is not a TCP port (1 to 65535)")
    host = match["host"].strip("[]")
    return Endpoint(host, port)


def add_arguments(p: argparse.ArgumentParser) -> None:
    group = p.add_argument_group("OPC UA server (docs/opcua.md; needs pip install "
                                 "'plchmi[opcua]')")
    group.add_argument("--opcua", nargs="?", const=DEFAULT_URL, metavar="opc.tcp://HOST:PORT",
                       help=f"serve the cell over OPC UA (default address {DEFAULT_URL}; "
                       "another host is explicit)")
    group.add_argument("--opcua-writable", action="store_true",
                       help="expose the operator commands as methods (acknowledge, fault "
                       "reset, manual requests, policy); needs --opcua-users or "
                       "--opcua-trust")
    group.add_argument("--opcua-users", type=Path, metavar="FILE",
                       help="the users file clients sign in against (default: the "
                       "machine's, $PLCHMI_DATA/users; plchmi users add NAME --role ROLE)")
    group.add_argument("--opcua-trust", action="append", type=Path, default=[],
                       metavar="CERT", help="trust this client certificate (DER or PEM) as "
                       "a user named after its file (repeatable)")
    group.add_argument("--opcua-allow-real-plant", action="store_true",
                       help="permit --opcua-writable on a real plant")
    group.add_argument("--opcua-interval", metavar="TIME",
                       help="publishing interval (default: every scan)")
    group.add_argument("--opcua-cert", type=Path, metavar="CERT",
                       help="the server's certificate (DER); with --opcua-key. Default with "
                       "users: a self-signed one kept in the data folder")
    group.add_argument("--opcua-key", type=Path, metavar="KEY",
                       help="the server's private key (PEM)")


def passed_on(args: argparse.Namespace) -> list[str]:
    """The --opcua options given, as ``plchmi gateway`` takes them (paths made absolute:
    the gateway may run elsewhere)."""
    if getattr(args, "opcua", None) is None:
        return []
    out = ["--opcua", args.opcua]
    for flag, name in (("--opcua-writable", "opcua_writable"),
                       ("--opcua-allow-real-plant", "opcua_allow_real_plant")):
        if getattr(args, name, False):
            out.append(flag)
    for option, name in (("--opcua-users", "opcua_users"), ("--opcua-cert", "opcua_cert"),
                         ("--opcua-key", "opcua_key")):
        value = getattr(args, name, None)
        if value is not None:
            out += [option, str(Path(value).absolute())]
    for path in getattr(args, "opcua_trust", []):
        out += ["--opcua-trust", str(Path(path).absolute())]
    if getattr(args, "opcua_interval", None):
        out += ["--opcua-interval", args.opcua_interval]
    return out


def check_arguments(args: argparse.Namespace) -> None:
    """Options that need --opcua, or each other, before anything starts."""
    url = getattr(args, "opcua", None)
    companions = [name for name, given in (
        ("--opcua-writable", args.opcua_writable), ("--opcua-users", args.opcua_users),
        ("--opcua-trust", args.opcua_trust),
        ("--opcua-allow-real-plant", args.opcua_allow_real_plant),
        ("--opcua-interval", args.opcua_interval), ("--opcua-cert", args.opcua_cert),
        ("--opcua-key", args.opcua_key)) if given]
    if url is None:
        if companions:
            raise UsageError(f"{', '.join(companions)} without --opcua")
        return
    parse_endpoint(url)
    if (args.opcua_cert is None) != (args.opcua_key is None):
        raise UsageError("--opcua-cert and --opcua-key go together")
    if args.opcua_writable and not args.opcua_trust:
        from hmi.access.users import default_path, read
        found = read(args.opcua_users or default_path())
        if found is None or not found.users:
            raise UsageError(NEEDS_USERS)
    elif args.opcua_users is not None:
        from hmi.access.users import read
        if read(args.opcua_users) is None:
            raise UsageError(f"--opcua-users {args.opcua_users}: no such users file (plchmi "
                             f"users --file {args.opcua_users} add NAME --role ROLE)")
    if len(args.opcua_trust) > MAX_TRUSTED:
        raise UsageError(f"--opcua-trust: at most {MAX_TRUSTED} certificates")
    from hmi.opcua import require
    require()


def start_server(cell: Session | CellSource, args: argparse.Namespace, log_file: bool = False,
                 journal: JournalRecorder | None = None,
                 history: Target | None = None,
                 refused: Callable[[SignInRefusal], None] | None = None
                 ) -> CellServer | None:
    """The cell's OPC UA server, started, if --opcua was given (None otherwise).

    asyncua's own log is silenced (its notices are for its developers). The server's
    failures go to stderr, or with `log_file` (the HMI: stderr is the screen) to
    opcua/server.log in the project's data folder. With `journal`, the journal says when
    the server starts serving, stops, or fails, and each sign-in it refuses (or `refused`
    hears those: the gateway sends them to the runtime's journal). With `history` (the
    cell's historian's store), clients can read the variables' and the alarms' history
    (Part 11). `cell`: the runtime through a link (the gateway), or a session in this
    process."""
    if getattr(args, "opcua", None) is None:
        return None
    name = cell.project.name
    log_path = _route_logs(name, log_file)
    from hmi.access.signin import Authenticator
    from hmi.access.users import default_path, read
    from hmi.opcua.server import CellServer, ServeOptions
    from hmi.opcua.users import Users, certificate_der
    from hmi.timefmt import DURATION_HINT, DurationError, parse_duration

    endpoint = parse_endpoint(args.opcua)
    interval = None
    if args.opcua_interval:
        try:
            interval = parse_duration(args.opcua_interval)
        except DurationError as exc:
            raise UsageError(f"--opcua-interval {args.opcua_interval!r} {exc.reason} "
                             f"(expected {DURATION_HINT})") from None
        if interval <= 0:
            raise UsageError("--opcua-interval must be longer than zero")
    users_path = args.opcua_users or default_path()
    found = read(users_path)
    authenticator = Authenticator(users_path) if found is not None else None
    certificates = {path.stem: certificate_der(path, "--opcua-trust")
                    for path in args.opcua_trust}
    users = Users(authenticator, certificates)
    cert, key = args.opcua_cert, args.opcua_key
    if cert is None and users.any:
        from hmi.explain.journal import safe_file_name
        from hmi.paths import data_folder
        folder = data_folder() / safe_file_name(name) / "opcua"
        cert, key = server_certificate(folder, name, endpoint.host)
    options = ServeOptions(host=endpoint.host, port=endpoint.port,
                           writable=args.opcua_writable,
                           users=users, sessions_per_user=(
                               found.settings.sessions_per_user if found else 3),
                           allow_real_plant=args.opcua_allow_real_plant,
                           interval_us=interval, certificate=cert, private_key=key)
    server = CellServer(cell, options, history=history)
    server.log_file = str(log_path or "")
    if journal is not None:
        server.listeners.append(journal_listener(journal))
        server.refusal_listeners.append(journal_refusals(journal))
    if refused is not None:
        server.refusal_listeners.append(refused)
    server.start()
    return server


def journal_listener(journal: JournalRecorder) -> Callable[[ServingStatus], None]:
    """Journals each change of the server's state: serving (where, read-only or not),
    stopped, failed (why, and where the details are)."""
    def told(status: ServingStatus) -> None:
        journal.on_service(f"opcua-{'serving' if status.up else status.state}",
                           status_words(status))
    return told


def journal_refusals(journal: JournalRecorder) -> Callable[[SignInRefusal], None]:
    """Journals each sign-in the server refused: the name tried, the client's address, why;
    the attempt that locked the account as account-locked."""
    def told(refused: SignInRefusal) -> None:
        journal.on_service(refused.event, refused.message, **refused.fields())
    return told


def status_words(status: ServingStatus) -> str:
    """The server's state in the journal's words (and the gateway's report to the runtime,
    which journals it)."""
    if status.up:
        return (f"serving over OPC UA at {status.url}, "
                + ("operator commands enabled" if status.writable else "read only"))
    if status.failed:
        return (f"the OPC UA server at {status.url} failed: {status.error}; the SCADA no "
                "longer sees this cell" + (f"; details in {status.log}" if status.log else ""))
    return f"the OPC UA server at {status.url} stopped"


def _route_logs(project_name: str, log_file: bool) -> Path | None:
    import logging

    from hmi.explain.journal import safe_file_name
    from hmi.paths import data_folder
    library = logging.getLogger("asyncua")
    library.propagate = False
    ours = logging.getLogger("hmi.opcua")
    ours.propagate = False
    for logger in (library, ours):  # once per process, whatever ran before
        for old in list(logger.handlers):
            logger.removeHandler(old)
    library.addHandler(logging.NullHandler())
    ours.setLevel(logging.WARNING)
    path = None
    if log_file:
        folder = data_folder() / safe_file_name(project_name) / "opcua"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            handler: logging.Handler = logging.FileHandler(folder / "server.log",
                                                           encoding="utf-8")
            path = folder / "server.log"
        except OSError:
            handler = logging.NullHandler()
    else:
        handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(asctime)s plchmi opcua: %(message)s"))
    ours.addHandler(handler)
    return path


def server_certificate(folder: Path, project_name: str, host: str) -> tuple[Path, Path]:
    """The server's self-signed certificate and key, made once and kept in `folder` (the
    data folder: clients trust it once): with it, clients encrypt passwords on the way."""
    import asyncio

    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.chmod(folder, 0o700)
    except OSError as exc:
        raise UsageError(f"{folder}: cannot keep the server's certificate there "
                         f"({exc.strerror})") from None
    key, cert = folder / "server-key.pem", folder / "server-cert.der"
    asyncio.run(setup_self_signed_certificate(
        key, cert, f"urn:plchmi:{project_name}", host if host != "0.0.0.0" else "localhost",
        [ExtendedKeyUsageOID.SERVER_AUTH], {"commonName": f"plchmi {project_name}"}))
    os.chmod(key, 0o600)
    return cert, key

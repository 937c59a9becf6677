"""Shared by the OPC UA tests: a served valve cell on a port of its own.

Under pytest-xdist several workers start servers at once, and other tests open loopback
connections whose ephemeral ports come from the same range: a port found free may be taken
before the server binds it. `serve` then tries another one instead of failing the test.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Sequence
from pathlib import Path

from hmi.access.audit import SignInRefusal
from hmi.engine.scan import Engine
from hmi.errors import UsageError
from hmi.history.target import Target
from hmi.opcua.server import CellServer, ServeOptions
from hmi.opcua.source import CellSource
from hmi.opcua.status import ServingStatus
from hmi.opcua.users import TrustList, Users
from hmi.plant.select import open_plant
from hmi.project.injection import parse_injection
from hmi.project.loader import load_project
from hmi.session.session import Session

ROOT = Path(__file__).resolve().parent.parent
TRIES = 5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(session: Session | CellSource, options: Callable[[int], ServeOptions],
          listeners: Sequence[Callable[[ServingStatus], None]] = (),
          history: Target | None = None,
          refused: Callable[[SignInRefusal], None] | None = None) -> CellServer:
    """A started server for `session` (or a source: the runtime through a link), with the
    options `options(port)` on a free port; `listeners` hear its changes of state from the
    start; `history`: the cell's history, for HistoryRead; `refused` hears each refused
    sign-in."""
    for attempt in range(TRIES):
        server = CellServer(session, options(free_port()), history=history)
        server.listeners.extend(listeners)
        if refused is not None:
            server.refusal_listeners.append(refused)
        try:
            server.start()
        except UsageError as exc:  # taken between the look and the bind: another port
            if "cannot listen there" not in str(exc) or attempt == TRIES - 1:
                raise
            continue
        return server
    raise AssertionError("unreachable")


def users(folder: Path, roles: dict[str, str], password: str,
          certificates: dict[str, bytes] | None = None) -> Users:
    """A real users file in `folder` (each user `password`, with their role), as the server
    reads it."""
    from hmi.access import users as users_file
    from hmi.access.signin import Authenticator
    path = folder / "users"
    for name, role in roles.items():
        users_file.add(path, name, role, password)
    return Users(Authenticator(path), certificates)


def trust_list(folder: Path) -> TrustList:
    """A trust list of its own (never the machine's data folder)."""
    return TrustList(folder / "pki-trust")


def valve_session(faults: tuple[str, ...] = ("F5@8.2s",)) -> Session:
    """The CISPI valve on its simulated plant, with `faults` scheduled (F5: stuck)."""
    project = load_project(ROOT / "projects" / "cispi_valve")
    plant = open_plant(project, None, False, [parse_injection(f) for f in faults], None)
    return Session(Engine(project, plant))

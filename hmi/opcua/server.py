"""The OPC UA server of one cell (asyncua), fed by a cell source's snapshots.

The source (hmi.opcua.source) is the cell's runtime seen through its socket — the OPC UA
gateway, a process of its own, so that no OPC UA client can slow the scan — or a session in
this process (a headless ``plchmi run --opcua``). The server runs in a thread of its own with
its own event loop: the source only keeps the newest snapshot (and the alarm events of each
scan, so none is lost when the publisher skips a snapshot) and wakes the publisher, which
writes the variables whose value changed, stamped with the scan's time (SourceTimestamp),
then sends the condition events.

Operator commands from OPC UA clients (only with ``writable``) are methods that go through
the source's door from a worker thread — the runtime's, where the journal listens — with the
client's identity as who sent it; the engine checks them as it checks the HMI's (manual
orders still go through the filter).
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import copy
import logging
import socket
import threading
import time
import uuid
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.common.node import Node
from asyncua.crypto.permission_rules import SimpleRoleRuleset, User, UserRole
from asyncua.server.internal_server import InternalServer
from asyncua.server.internal_session import SessionState
from asyncua.server.server import Server
from asyncua.server.user_managers import UserManager
from asyncua.ua.attribute_ids import AttributeIds
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes

from hmi.access.audit import SignInRefusal
from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommandResult,
    CommentAlarm,
    FaultReset,
    ManualOutput,
    SetMode,
    SetPolicy,
    Shelve,
    Unshelve,
)
from hmi.errors import UsageError
from hmi.explain.alarms import ACTIVE_UNACK, CLEARED_UNACK, MAX_SHELVE_US
from hmi.history.target import Target
from hmi.opcua import NEEDS_USERS
from hmi.opcua.conditions import (
    HMI_USER,
    ONE_SHOT,
    TIMED,
    UNSHELVED,
    ConditionTracker,
    ConditionView,
)
from hmi.opcua.doors import apply_limits, install, make_gate, verdict
from hmi.opcua.model import BOOL, DOUBLE, STRING, STRINGS, UINT, AddressModel, build_model
from hmi.opcua.source import CellSource, SessionSource
from hmi.opcua.status import FAILED, SERVING, STARTING, STOPPED, OpcClient, ServingStatus
from hmi.opcua.users import ANONYMOUS, Identity, TrustList, Users
from hmi.session.session import Session
from hmi.session.view import CellView

if TYPE_CHECKING:
    from hmi.opcua.history import CellHistory

log = logging.getLogger("hmi.opcua")


def _id(identifier: int | str, namespace: int = 0) -> ua.NodeId:
    """A node id from a plain number or string: asyncua types its fields with its own
    subclasses of int and str (Int32, String, Int16), which encode the same."""
    return ua.NodeId(ua.Int32(identifier) if isinstance(identifier, int)
                     else ua.String(identifier), ua.Int16(namespace))


def _status(code: int) -> ua.StatusCode:
    """A status code from one of asyncua's StatusCodes constants (plain ints)."""
    return ua.StatusCode(ua.UInt32(code))


VARIANT = {BOOL: ua.VariantType.Boolean, STRING: ua.VariantType.String,
           STRINGS: ua.VariantType.String, DOUBLE: ua.VariantType.Double,
           UINT: ua.VariantType.UInt64}
DEFAULT = {BOOL: False, STRING: "", STRINGS: [], DOUBLE: 0.0, UINT: 0}
# UNECE codes (OPC UA Part 8, EUInformation.UnitId) of the units the model uses.
UNITS = {"s": (5457219, "s", "second"), "ms": (4405047, "ms", "millisecond")}
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"
# Part 9 shelving, optional in AlarmConditionType (asyncua's event object lacks it).
SHELVING_FIELDS = {"ShelvingState": ua.VariantType.LocalizedText,
                   "ShelvingState/CurrentState": ua.VariantType.LocalizedText,
                   "ShelvingState/CurrentState/Id": ua.VariantType.NodeId,
                   "ShelvingState/UnshelveTime": ua.VariantType.Double}
SHELVING_IDS = {UNSHELVED: ObjectIds.ShelvedStateMachineType_Unshelved,
                TIMED: ObjectIds.ShelvedStateMachineType_TimedShelved,
                ONE_SHOT: ObjectIds.ShelvedStateMachineType_OneShotShelved}
BUILT_IN = {_id(ObjectIds.UtcTime): ua.VariantType.DateTime,
            _id(ObjectIds.Duration): ua.VariantType.Double}

IDLE_S = 0.25  # the publisher's longest sleep without a scan
_EPOCH = ua.DateTime(1970, 1, 1, tzinfo=UTC)

# The identity of the client whose request is being served: set by the permission check
# that asyncua runs before each request, read by the method callbacks it then awaits.
_caller: contextvars.ContextVar[User | None] = contextvars.ContextVar("opcua_caller",
                                                                       default=None)


@dataclass(frozen=True)
class ServeOptions:
    host: str = "127.0.0.1"
    port: int = 4840
    writable: bool = False
    users: Users = field(default_factory=Users)
    trust: TrustList | None = None  # client applications (None: the machine's trust list)
    sessions_per_user: int = 3
    allow_real_plant: bool = False
    interval_us: int | None = None  # publishing interval (None: the scan period)
    certificate: Path | None = None  # the server's own certificate and key (DER / PEM)
    private_key: Path | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"opc.tcp://{host}:{self.port}"


# asyncua's SimpleRoleRuleset has no annotations: its two methods, typed as we use them.
_simple_rules: Callable[[SimpleRoleRuleset], None] = SimpleRoleRuleset.__init__
_simple_check: Callable[[SimpleRoleRuleset, User, ua.NodeId, object], bool] = \
    SimpleRoleRuleset.check_validity


class _Rules(SimpleRoleRuleset):
    """asyncua's role rules, plus: remember who sent the request being served."""

    def __init__(self) -> None:
        _simple_rules(self)

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: object) -> bool:
        _caller.set(user)
        return _simple_check(self, user, action_type_id, body)


@dataclass
class _CellUser(User):
    """asyncua's user of a session, with who they are for the journal."""

    identity: Identity = field(default_factory=lambda: ANONYMOUS)


class _UserManager(UserManager):
    """asyncua asks it at activation: it only reads what the look before activation
    decided (hmi.opcua.doors: the password checked off the loop). No verdict: refused."""

    def get_user(self, iserver: InternalServer, username: str | None = None,
                 password: str | None = None, certificate: Any = None) -> User | None:
        decided = verdict()
        if decided is None or decided[0] is None:
            return None
        identity = decided[0]
        return _CellUser(role=UserRole.User, name=identity.name, identity=identity)


def _identity(user: User | None) -> Identity:
    return user.identity if isinstance(user, _CellUser) else ANONYMOUS


class CellServer:
    """One cell as an OPC UA server. `start()` returns once it listens (or raises)."""

    def __init__(self, cell: Session | CellSource, options: ServeOptions,
                 history: Target | None = None):
        self.source: CellSource = SessionSource(cell) if isinstance(cell, Session) else cell
        source = self.source
        self.options = options
        self.history = history  # the cell's history, for HistoryRead (None: none kept)
        self.storage: CellHistory | None = None  # what answers HistoryRead (with history)
        self.recorded: dict[str, str] = {}  # the historian's signal of each record
        if options.writable and source.is_real and not options.allow_real_plant:
            raise UsageError("--opcua-writable on a real plant: OPC UA clients could then "
                             "drive it; refused unless --opcua-allow-real-plant says so")
        if options.writable and not options.users.any:
            raise UsageError(NEEDS_USERS)
        self.model: AddressModel = build_model(source.project, source.layout)
        self.interval_s = (options.interval_us or source.period_us) / 1e6
        self._latest: CellView | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._wake: asyncio.Event | None = None
        self._due = 0.0  # monotonic time from which the next scan wakes the publisher
        self._ready = threading.Event()
        self._failure: BaseException | None = None
        self.tracker = ConditionTracker()
        self.published = 0  # snapshots published (for tests and the bench)
        self.published_scan = -1  # the scan of the last snapshot published
        self.events_sent = 0
        self.errors = 0  # publishes that failed
        # What the operator's screen shows (hmi.opcua.status): replaced, never changed, so
        # that the UI thread reads a consistent one; `listeners` hear each change of state
        # (serving, stopped, failed), in the server's thread (the journal).
        users = options.users
        security = ["None"]
        if options.certificate and options.private_key:
            security += ["Basic256Sha256 Sign", "Basic256Sha256 SignAndEncrypt"]
        self.log_file = ""  # where the server's errors are written (hmi.opcua.options)
        self._status = ServingStatus(options.url, STARTING, tuple(security), options.writable,
                                     users.count())
        self._actions: deque[tuple[str, str, str]] = deque()  # comments: key, user, text
        source.listen(self.on_command)
        self.listeners: list[Callable[[ServingStatus], None]] = []
        # each sign-in refused at the door (the journal), in the server's thread
        self.refusal_listeners: list[Callable[[SignInRefusal], None]] = []
        self._clients_due = 0.0  # monotonic time of the next look at the connections

    # -- the source's side (a scan thread in this process): cheap, never waits ---------------

    def _poke(self) -> None:
        # Wake the publisher right after a scan, when the scan thread has the most of a
        # period ahead of it: the two then rarely want the GIL at the same moment.
        now = time.monotonic()
        if now >= self._due and self._loop is not None and self._wake is not None:
            self._due = now + self.interval_s * 0.9
            with contextlib.suppress(RuntimeError):  # the loop is closing
                self._loop.call_soon_threadsafe(self._wake.set)

    # -- life cycle ---------------------------------------------------------------------------

    def start(self, timeout: float = 60.0) -> None:
        self._thread = threading.Thread(target=self._run, name="plchmi-opcua", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError(f"the OPC UA server did not start within {timeout:g} s")
        if self._failure is not None:
            raise self._failure
        self.source.start(self._poke)

    def stop(self, timeout: float = 10.0) -> None:
        self.source.stop()
        loop, stop, wake = self._loop, self._stop, self._wake
        if loop is not None and stop is not None and wake is not None:
            with contextlib.suppress(RuntimeError):  # the loop already ended
                loop.call_soon_threadsafe(stop.set)
                loop.call_soon_threadsafe(wake.set)
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def url(self) -> str:
        return self.options.url

    def status(self) -> ServingStatus:
        """What the server is doing now (the latest; a new object when anything changed)."""
        return self._status

    def _set_status(self, **changes: Any) -> None:
        old = self._status
        new = replace(old, log=self.log_file, **changes)
        if new == old:
            return
        self._status = new
        if new.state != old.state:
            for listener in list(self.listeners):
                try:
                    listener(new)
                except Exception:  # a listener's failure is not the server's
                    log.exception("an OPC UA status listener failed")

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to start(), or logged once running
            if not self._ready.is_set():  # it never served: start() raises it
                self._failure = exc
                self._ready.set()
                return
            log.exception("the OPC UA server stopped on an error")
            self._set_status(state=FAILED, clients=(),
                             error=f"{type(exc).__name__}: {exc}" if str(exc)
                             else type(exc).__name__)
            return
        self._set_status(state=STOPPED, clients=())

    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        self._wake = asyncio.Event()
        self._check_address()
        server = await self._build()
        try:
            await server.start()
        except OSError as exc:
            raise self._cannot_listen(exc) from None
        self._set_status(state=SERVING)  # journalled before start() returns
        self._ready.set()
        try:
            await self._serve()
        finally:
            await server.stop()

    def _cannot_listen(self, exc: OSError) -> UsageError:
        return UsageError(f"--opcua {self.url}: cannot listen there ({exc.strerror or exc})")

    def _check_address(self) -> None:
        """Say at once that the address is taken (another server on the port) or not this
        machine's, not after building the address space (~2 s of CPU): each address is
        bound as asyncio's server binds it (SO_REUSEADDR, IPv6 only for IPv6), then let go.
        server.start() still reports whatever this cannot see (the port taken since)."""
        if self.options.port == 0:
            return
        try:
            found = socket.getaddrinfo(self.options.host, self.options.port,
                                       type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        except OSError:
            return  # not resolved: start() says so, as before
        for family, kind, proto, _, address in found:
            with socket.socket(family, kind, proto) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                if family == socket.AF_INET6:
                    probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
                try:
                    probe.bind(address)
                except OSError as exc:
                    raise self._cannot_listen(exc) from None

    async def _serve(self) -> None:
        """Publish until stop() is called."""
        assert self._stop is not None and self._wake is not None
        while not self._stop.is_set():
            # Woken by a scan (on_scan), by stop(), or at least every IDLE_S to follow
            # the run state of a cell that makes no scan (paused).
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), IDLE_S)
            self._wake.clear()
            try:
                await self.publish()
            except Exception:  # one bad publish must not end the server
                self.errors += 1
                if self.errors == 1:
                    log.exception("publishing to OPC UA failed (further failures are "
                                  "counted, not logged)")
            now = time.monotonic()
            if now >= self._clients_due:
                self._clients_due = now + IDLE_S
                self._set_status(clients=self._clients(), published=self.published,
                                 events=self.events_sent, errors=self.errors)

    def _clients(self) -> tuple[OpcClient, ...]:
        """The clients connected now, with their session's user and their channel's
        security (read from asyncua's connection objects)."""
        binary = getattr(self.server, "bserver", None)
        found = []
        for connection in list(getattr(binary, "clients", ())):
            processor = connection.processor
            peer = connection.peer_name
            where = (f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) and len(peer) >= 2
                     else str(peer))
            user = ""
            security = "None"
            if processor is not None:
                session = processor.session
                if session is not None and session.state == SessionState.Activated:
                    user = _identity(session.user).name or "anonymous"
                policy = processor._connection.security_policy
                mode = policy.Mode
                if mode != ua.MessageSecurityMode.None_:
                    security = f"{policy.URI.rsplit('#', 1)[-1]} {mode.name}"
            found.append(OpcClient(where, user, security))
        return tuple(found)

    def _refused(self, refused: SignInRefusal) -> None:
        for listener in list(self.refusal_listeners):
            try:
                listener(refused)
            except Exception:  # the journal's trouble is told where it happens
                log.exception("a refused sign-in could not be journalled")

    # -- the address space --------------------------------------------------------------------

    async def _build(self) -> Server:
        users = self.options.users
        sessions = None
        if users.authenticator is not None:
            from hmi.access.sessions import SessionTable
            sessions = SessionTable(users.authenticator.path)
        install(make_gate(users, sessions, self.options.sessions_per_user, self._refused),
                sessions.close if sessions is not None else (lambda ticket: None),
                self.options.trust or TrustList())
        self.server = server = Server(user_manager=_UserManager())
        server.iserver.bind_condition_methods = True  # ConditionRefresh replays our alarms
        if self.history is not None:  # HistoryRead from the cell's history (Part 11)
            from hmi.history.catalogue import catalogue
            from hmi.opcua.history import CellHistory
            self.storage = CellHistory(self.history, self.model.cell)
            self.recorded = catalogue(self.source.project, self.source.layout).origin
            server.iserver.history_manager.set_storage(self.storage)
        await server.init()
        apply_limits(server, self.interval_s * 1000)
        server.set_server_name(f"plchmi {self.model.cell}")
        server.set_endpoint(self.url)
        await server.set_application_uri(f"urn:plchmi:{self.model.cell}")
        policies = [ua.SecurityPolicyType.NoSecurity]
        if self.options.certificate and self.options.private_key:
            await server.load_certificate(str(self.options.certificate))
            await server.load_private_key(str(self.options.private_key))
            policies += [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
                         ua.SecurityPolicyType.Basic256Sha256_Sign]
        server.set_security_policy(policies, permission_ruleset=_Rules())
        tokens: list[type] = [ua.AnonymousIdentityToken]
        if self.options.users.passwords and self.options.certificate:
            tokens.append(ua.UserNameIdentityToken)  # only with a key to encrypt it with
        if self.options.users.certificates:
            tokens.append(ua.X509IdentityToken)
        server.set_identity_tokens(tokens)
        self.ns = await server.register_namespace(f"urn:plchmi:{self.model.cell}")
        await self._build_nodes(server)
        await self._build_alarms(server)
        if self.storage is not None:
            self.storage.alarm_type = self.alarm_type.nodeid
            self.storage.event_sources.add(server.nodes.server.nodeid)
            await server.nodes.server.set_attr_bit(AttributeIds.EventNotifier,
                                                   ua.EventNotifier.HistoryRead)
        if self.options.writable:
            await self._build_commands(server)
        return server

    async def _historize(self, node: Node, origin: str, vtype: ua.VariantType) -> None:
        """A variable the historian records: HistoryRead answered from the cell's history."""
        signal = self.recorded.get(origin) if origin and self.storage is not None else None
        if signal is None or self.storage is None:
            return
        from hmi.opcua.history import Historized
        self.storage.nodes[node.nodeid] = Historized(signal, vtype)
        for attribute in (AttributeIds.AccessLevel, AttributeIds.UserAccessLevel):
            await node.set_attr_bit(attribute, ua.AccessLevel.HistoryRead)
        await node.write_attribute(AttributeIds.Historizing, ua.DataValue(
            ua.Variant(True, ua.VariantType.Boolean)))

    def _nodeid(self, path: tuple[str, ...]) -> ua.NodeId:
        return _id(".".join((self.model.cell, *path)), self.ns)

    async def _build_nodes(self, server: Server) -> None:
        ns = self.ns
        self.cell = await server.nodes.objects.add_object(self._nodeid(()),
                                                          ua.QualifiedName(self.model.cell, ns))
        await self.cell.write_attribute(AttributeIds.Description, ua.DataValue(
            ua.Variant(ua.LocalizedText(self.model.description), ua.VariantType.LocalizedText)))
        self.objects: dict[tuple[str, ...], Node] = {(): self.cell}
        for folder in self.model.folders:
            parent = self.objects[folder.path[:-1]]
            node = await parent.add_object(self._nodeid(folder.path),
                                           ua.QualifiedName(folder.path[-1], ns))
            await _describe(node, folder.description)
            self.objects[folder.path] = node
        self.points: list[_Variable] = []
        waiting = _status(StatusCodes.BadWaitingForInitialData)
        for point in self.model.points:
            parent = self.objects[point.path[:-1]]
            vtype = VARIANT[point.kind]
            node = await parent.add_variable(
                self._nodeid(point.path), ua.QualifiedName(point.name, ns),
                ua.Variant(DEFAULT[point.kind], vtype), datatype=_id(vtype.value))
            if point.kind == STRINGS:
                await node.write_value_rank(1)
                # an array of any length (asyncua's write_array_dimensions takes one int)
                await node.write_attribute(AttributeIds.ArrayDimensions, ua.DataValue(
                    ua.Variant([0], ua.VariantType.UInt32)))
            await _describe(node, point.description)
            if point.unit:
                code, short, long_name = UNITS[point.unit]
                await node.add_property(
                    self._nodeid((*point.path, "EngineeringUnits")),
                    ua.QualifiedName("EngineeringUnits", 0),
                    ua.EUInformation(NamespaceUri=UNECE_URI, UnitId=code,
                                     DisplayName=ua.LocalizedText(short),
                                     Description=ua.LocalizedText(long_name)))
            await server.write_attribute_value(node.nodeid, ua.DataValue(StatusCode=waiting))
            self.points.append(_Variable(node.nodeid, point.read, vtype, point.from_plant))
            await self._historize(node, point.history, vtype)
        # The run state is the session's, not a scan's: a paused cell makes no snapshot, and
        # a SCADA must still learn that its values stopped moving.
        status = self.objects[("Status",)]
        self.run_state = await status.add_variable(
            self._nodeid(("Status", "RunState")), ua.QualifiedName("RunState", ns),
            self.source.run_state(), datatype=_id(ua.VariantType.String.value))
        await _describe(self.run_state, "running, paused or stepping (a paused cell's values "
                        "stay as the last scan left them)")
        self._run_state = self.source.run_state()

    # -- publishing ---------------------------------------------------------------------------

    async def publish(self) -> None:
        """Write what changed since the last publish, then send the condition events."""
        cell, batches = self.source.take()
        state = self.source.run_state()
        if state != self._run_state:
            self._run_state = state
            now = ua.DateTime.now(UTC)
            await self.server.iserver.aspace.write_attribute_value(
                self.run_state.nodeid, AttributeIds.Value,
                ua.DataValue(ua.Variant(state, ua.VariantType.String), SourceTimestamp=now,
                             ServerTimestamp=now))
        if cell is None:
            return
        self._latest = cell
        snapshot = cell.snapshot
        if cell is not self._published:
            self._published = cell
            stamp = self._stamp(snapshot.time_us)
            now = ua.DateTime.now(UTC)
            write = self.server.iserver.aspace.write_attribute_value
            connected = snapshot.plant.connected
            for variable in self.points:
                try:
                    value = variable.read(cell)
                except Exception:  # a value this run does not have (diagnosis off, ...)
                    value = _BAD
                stale = variable.from_plant and not connected
                if (value, stale) == variable.last:
                    continue
                variable.last = (value, stale)
                if value is _BAD:
                    dv = ua.DataValue(StatusCode=_status(StatusCodes.BadNoData),
                                      SourceTimestamp=stamp, ServerTimestamp=now)
                else:
                    # A plant that does not answer: the last value read, marked uncertain.
                    dv = ua.DataValue(ua.Variant(value, variable.vtype),
                                      StatusCode=_STALE if stale else _GOOD,
                                      SourceTimestamp=stamp, ServerTimestamp=now)
                await write(variable.nodeid, AttributeIds.Value, dv)
            self.published += 1
            self.published_scan = snapshot.scan
        for view in self.tracker.update(batches, cell.alarms, snapshot.time_us, cell.shelved):
            await self._send(view)
        while self._actions:  # comments: Part 9 sends each as an event of its condition
            key, user, text = self._actions.popleft()
            for view in self.tracker.commented(key, user, text):
                await self._send(view)

    _published: CellView | None = None
    @property
    def epoch(self) -> datetime:
        """The wall time of the run's time 0 (what SourceTimestamps count from)."""
        return self._stamp(0)

    def _stamp(self, time_us: int) -> ua.DateTime:
        """The wall time of a scan: the session's (Session.wall_us: the wall clock of a
        real plant, a simulation's time counted from its start), the time the historian
        stamps the same scan with."""
        return _EPOCH + timedelta(microseconds=self.source.wall_us(time_us))

    # -- alarms as Part 9 conditions ----------------------------------------------------------

    async def _build_alarms(self, server: Server) -> None:
        ns = self.ns
        self.alarm_type = await server.create_custom_event_type(
            ns, "PlchmiAlarmType", ObjectIds.AlarmConditionType,
            [("Why", ua.VariantType.String), ("Consequences", ua.VariantType.String),
             ("Policies", ua.VariantType.String), ("Detail", ua.VariantType.String),
             ("Priority", ua.VariantType.String),
             ("AlarmKind", ua.VariantType.String), ("Transition", ua.VariantType.String),
             ("Returns", ua.VariantType.UInt32), ("Chattering", ua.VariantType.Boolean),
             ("LatchedUntilReset", ua.VariantType.Boolean)])
        await _describe(self.alarm_type, "A plchmi alarm (ISA-18.2): Message is level 1 of "
                        "its explanation; Why, Consequences, Policies and Detail the other levels")
        generator = await server.get_event_generator(self.alarm_type,
                                                      server.nodes.server.nodeid)
        self._template = generator.event
        for name, vtype in SHELVING_FIELDS.items():  # optional in AlarmConditionType
            self._template.add_property(name, None, vtype)
        # key -> the condition's event object (its fields are added at run time by
        # asyncua's add_property: asyncua types it Any too)
        self.conditions: dict[str, Any] = {}
        self.condition_keys: dict[ua.NodeId, str] = {}
        self.shelving_keys: dict[ua.NodeId, str] = {}  # a condition's ShelvingState -> key
        self.event_ids: dict[str, deque[bytes]] = {}
        self.alarms_folder = await self.cell.add_object(self._nodeid(("Alarms",)),
                                                        ua.QualifiedName("Alarms", ns))
        await _describe(self.alarms_folder, "One condition per alarm the cell has raised; "
                        "events come from the Server object")
        server.iserver.isession.add_method_callback(
            _id(ObjectIds.AcknowledgeableConditionType_Acknowledge), self._acknowledge)
        # Part 9 shelving (on each condition's ShelvingState) and comments: the HMI's
        # shelving and comments, through the same door.
        session = server.iserver.isession
        session.add_method_callback(_id(ObjectIds.ShelvedStateMachineType_TimedShelve),
                                    self._timed_shelve)
        session.add_method_callback(
            _id(ObjectIds.ShelvedStateMachineType_OneShotShelve), self._one_shot_shelve)
        session.add_method_callback(_id(ObjectIds.ShelvedStateMachineType_Unshelve),
                                    self._unshelve)
        session.add_method_callback(_id(ObjectIds.ConditionType_AddComment),
                                    self._add_comment)

    async def _condition(self, view: ConditionView) -> Any:
        event = self.conditions.get(view.key)
        if event is not None:
            return event
        node = await self.alarms_folder.add_object(
            self._nodeid(("Alarms", view.key)), ua.QualifiedName(view.key, self.ns))
        await _describe(node, view.message)
        event = copy.copy(self._template)
        # asyncua types some fields by a data type's NodeId (UtcTime, Duration), which its
        # Variant cannot encode once the field has a value: use the built-in types.
        event.data_types = {name: BUILT_IN.get(t, t) if isinstance(t, ua.NodeId) else t
                            for name, t in self._template.data_types.items()}
        event.NodeId = node.nodeid
        source = self.objects.get(self.model.device_path(view.device), self.cell)
        event.SourceNode = source.nodeid
        event.SourceName = view.device or self.model.cell
        event.ConditionName = view.key
        event.ConditionClassId = _id(ObjectIds.ProcessConditionClassType)
        event.ConditionClassName = ua.LocalizedText("Process")
        event.BranchId = ua.NodeId()
        self.conditions[view.key] = event
        self.condition_keys[node.nodeid] = view.key
        self.event_ids[view.key] = deque(maxlen=16)
        shelving = await node.add_object(self._nodeid(("Alarms", view.key, "ShelvingState")),
                                         ua.QualifiedName("ShelvingState", 0))
        await _describe(shelving, "shelve this alarm (TimedShelve, OneShotShelve) or bring "
                        "it back (Unshelve): the methods of ShelvedStateMachineType")
        self.shelving_keys[shelving.nodeid] = view.key
        return event

    async def _send(self, view: ConditionView) -> None:
        event = await self._condition(view)
        stamp = self._stamp(view.time_us)
        event.EventId = uuid.uuid4().bytes
        self.event_ids[view.key].append(event.EventId)
        event.Time = stamp
        event.ReceiveTime = ua.DateTime.now(UTC)
        event.Message = ua.LocalizedText(view.message)
        event.Severity = view.severity
        event.Retain = view.retain
        event.Quality = ua.StatusCode()
        event.Comment = ua.LocalizedText(view.comment)
        event.ClientUserId = view.user
        _two_state(event, "EnabledState", True, "Enabled", "Disabled", stamp)
        _two_state(event, "ActiveState", view.active, "Active", "Inactive", stamp)
        _two_state(event, "AckedState", view.acked, "Acknowledged", "Unacknowledged", stamp)
        shelving = ua.LocalizedText(view.shelving)
        event.ShelvingState = shelving
        setattr(event, "ShelvingState/CurrentState", shelving)
        setattr(event, "ShelvingState/CurrentState/Id", _id(SHELVING_IDS[view.shelving]))
        setattr(event, "ShelvingState/UnshelveTime", view.unshelve_ms)
        event.SuppressedOrShelved = view.shelved
        event.MaxTimeShelved = MAX_SHELVE_US / 1000
        for name, value in (("Why", view.why), ("Consequences", view.consequences),
                            ("Policies", view.policies), ("Detail", view.detail),
                            ("Priority", view.priority),
                            ("AlarmKind", view.kind), ("Transition", view.transition),
                            ("Returns", view.returns), ("Chattering", view.chattering),
                            ("LatchedUntilReset", view.latched)):
            setattr(event, name, value)
        await self.server.iserver.subscription_service.trigger_event(event)
        self.events_sent += 1

    async def _acknowledge(self, parent: ua.NodeId, event_id: ua.Variant,
                           comment: ua.Variant) -> ua.StatusCode:
        """Part 9 Acknowledge on a condition: the session's Acknowledge, journalled with the
        client's identity."""
        found = self._condition_call(parent, event_id, Acknowledge(""))
        if isinstance(found, ua.StatusCode):
            return found
        who, key = found
        note = _comment_text(comment)
        self.tracker.acknowledged_by(key, who.name or "", note or "")
        result = await self._command(Acknowledge(key), who, note or "")
        if not result.accepted:
            self.tracker.acks.pop(key, None)
            if self.source.refused_for_control(result):
                return _status(StatusCodes.BadUserAccessDenied)
            return _status(StatusCodes.BadConditionBranchAlreadyAcked)
        return ua.StatusCode()  # the acknowledged state goes out with the next scan

    async def _timed_shelve(self, parent: ua.NodeId, shelving_time: ua.Variant
                            ) -> ua.StatusCode:
        """Part 9 TimedShelve: ShelvingTime in milliseconds (a Duration)."""
        ms = _value(shelving_time)
        if not isinstance(ms, int | float) or not 0 < ms * 1000 <= MAX_SHELVE_US:
            return _status(StatusCodes.BadShelvingTimeOutOfRange)
        return await self._shelving(parent, lambda key: Shelve(key, int(ms * 1000)))

    async def _one_shot_shelve(self, parent: ua.NodeId) -> ua.StatusCode:
        return await self._shelving(parent, lambda key: Shelve(key, None))

    async def _unshelve(self, parent: ua.NodeId) -> ua.StatusCode:
        return await self._shelving(parent, Unshelve)

    async def _shelving(self, parent: ua.NodeId, make: Callable[[str], Command]
                        ) -> ua.StatusCode:
        who = _identity(_caller.get())
        key = self.shelving_keys.get(parent)
        command = make(key or "")
        denied = self._denied(who, command)
        if denied is not None:
            return denied
        if key is None:
            return _status(StatusCodes.BadNodeIdUnknown)
        self.tracker.acted(key, who.name or "")
        result = await self._command(command, who)
        if result.accepted:
            return ua.StatusCode()
        if self.source.refused_for_control(result):
            return _status(StatusCodes.BadUserAccessDenied)
        if isinstance(command, Unshelve):
            return _status(StatusCodes.BadConditionNotShelved)
        if "already shelved" in result.message:
            return _status(StatusCodes.BadConditionAlreadyShelved)
        return _status(StatusCodes.BadInvalidState)  # latched, or already clear

    async def _add_comment(self, parent: ua.NodeId, event_id: ua.Variant,
                           comment: ua.Variant) -> ua.StatusCode:
        """Part 9 AddComment: the HMI's comment on an alarm, journalled with the user."""
        found = self._condition_call(parent, event_id, CommentAlarm("", ""))
        if isinstance(found, ua.StatusCode):
            return found
        who, key = found
        result = await self._command(CommentAlarm(key, _comment_text(comment)), who)
        return ua.StatusCode() if result.accepted else _status(StatusCodes.BadInvalidArgument)

    def _condition_call(self, parent: ua.NodeId, event_id: ua.Variant, kind: Command
                        ) -> tuple[Identity, str] | ua.StatusCode:
        """The caller and the alarm a Part 9 method on a condition names, or the refusal:
        Acknowledge and AddComment check the same user, role, condition and event id."""
        who = _identity(_caller.get())
        denied = self._denied(who, kind)
        if denied is not None:
            return denied
        key = self.condition_keys.get(parent)
        if key is None:
            return _status(StatusCodes.BadNodeIdUnknown)
        if _value(event_id) not in self.event_ids.get(key, ()):
            return _status(StatusCodes.BadEventIdUnknown)
        return who, key

    def _denied(self, who: Identity, command: Command | None = None
                ) -> ua.StatusCode | None:
        """Refused unless commands are on, the caller is named and their role may send
        it (hmi.access.roles: fail closed)."""
        from hmi.access.roles import may
        if not self.options.writable or who.name is None:
            return _status(StatusCodes.BadUserAccessDenied)
        if command is not None and not may(who.role, command):
            return _status(StatusCodes.BadUserAccessDenied)
        return None

    def on_command(self, command: Command, result: CommandResult, origin: str) -> None:
        """The commands the source hears (a session: every door's, in its thread; the
        gateway: its own users'), only noted here: who shelved or commented names the
        condition's next event; a comment is an event itself."""
        if not result.accepted:
            return
        user = (origin[6:].split(" (", 1)[0] if origin.startswith("opcua:")
                else origin or HMI_USER)
        if isinstance(command, CommentAlarm):
            self._actions.append((command.key, user, command.text))
        elif isinstance(command, Shelve | Unshelve):
            self.tracker.acted(command.key, user)

    async def _command(self, command: Command, who: Identity, comment: str = ""
                       ) -> CommandResult:
        return await asyncio.to_thread(self.source.command, command, who, comment)

    # -- operator commands as methods (writable only) -----------------------------------------

    async def _build_commands(self, server: Server) -> None:
        ns = self.ns
        folder = await self.cell.add_object(self._nodeid(("Commands",)),
                                            ua.QualifiedName("Commands", ns))
        await _describe(folder, "Operator commands, as the HMI sends them (journalled with "
                        "the OPC UA user); they need a user, and the filter still applies")
        out = [_arg("Accepted", ua.VariantType.Boolean, "the command was carried out"),
               _arg("Message", ua.VariantType.String, "what happened, in words")]
        specs: list[tuple[str, str, list[ua.Argument], Callable[..., Command]]] = [
            ("Acknowledge", "acknowledge one alarm by key, or all with an empty key",
             [_arg("Key", ua.VariantType.String, "the alarm's key (empty: all)")],
             lambda key: Acknowledge(key or None)),
            ("FaultReset", "fault reset: clear the latch and the diagnosers' decisions",
             [], lambda: FaultReset()),
            ("SetMode", "enter (true) or leave (false) manual mode",
             [_arg("Manual", ua.VariantType.Boolean, "true: manual mode")],
             lambda manual: SetMode(bool(manual))),
            ("ManualOutput", "manual mode: request an output on or off (the filter still "
             "applies), or release the request",
             [_arg("Output", ua.VariantType.String, "the output's name"),
              _arg("Request", ua.VariantType.String, "on, off or release")],
             _manual_output),
            ("SetPolicy", "the safety filter's policy: block or correct (monitor only where "
             "the engine allows it)",
             [_arg("Policy", ua.VariantType.String, "monitor, block or correct")],
             lambda policy: SetPolicy(str(policy))),
            ("ChoosePolicy", "carry out a policy an alarm's explanation offers",
             [_arg("Key", ua.VariantType.String, "the alarm's key"),
              _arg("Policy", ua.VariantType.String, "the policy's id")],
             lambda key, policy: ChoosePolicy(str(key), str(policy))),
            ("Shelve", "shelve an alarm: out of the list for a time (at most 8 h), or with "
             "0 once, until its condition clears; still journalled",
             [_arg("Key", ua.VariantType.String, "the alarm's key"),
              _arg("Seconds", ua.VariantType.Double, "how long (0: until it clears)")],
             _shelve),
            ("Unshelve", "bring a shelved alarm back into the list",
             [_arg("Key", ua.VariantType.String, "the alarm's key")],
             lambda key: Unshelve(str(key))),
            ("Comment", "a comment on an alarm, journalled",
             [_arg("Key", ua.VariantType.String, "the alarm's key"),
              _arg("Text", ua.VariantType.String, "the comment")],
             lambda key, text: CommentAlarm(str(key), str(text))),
        ]
        for name, text, inputs, make in specs:
            node = await folder.add_method(self._nodeid(("Commands", name)),
                                           ua.QualifiedName(name, ns), self._method(make),
                                           inputs, out)
            await _describe(node, text)

    def _method(self, make: Callable[..., Command]
                ) -> Callable[..., Awaitable[ua.StatusCode | list[ua.Variant]]]:
        async def call(parent: ua.NodeId, *args: ua.Variant
                       ) -> ua.StatusCode | list[ua.Variant]:
            who = _identity(_caller.get())
            denied = self._denied(who)
            if denied is not None:
                return denied
            try:
                command = make(*(_value(a) for a in args))
            except (TypeError, ValueError) as exc:  # refused in words, like the engine does
                return [ua.Variant(False, ua.VariantType.Boolean),
                        ua.Variant(str(exc), ua.VariantType.String)]
            if self._denied(who, command) is not None:
                from hmi.access.roles import refusal
                return [ua.Variant(False, ua.VariantType.Boolean),
                        ua.Variant(refusal(who.role, command), ua.VariantType.String)]
            named = self._name_acknowledger(command, who)
            result = await self._command(command, who)
            if not result.accepted:
                for key in named:
                    self.tracker.acks.pop(key, None)
            return [ua.Variant(result.accepted, ua.VariantType.Boolean),
                    ua.Variant(result.message, ua.VariantType.String)]
        return call

    def _name_acknowledger(self, command: Command, who: Identity) -> list[str]:
        """The condition events of an acknowledgement sent as a command name its sender
        too: the alarms it concerns that wait for one (all of them for an empty key)."""
        if not isinstance(command, Acknowledge) or self._latest is None:
            return []
        keys = [a.key for a in self._latest.alarms
                if a.state in (ACTIVE_UNACK, CLEARED_UNACK)
                and (command.key is None or a.key == command.key)]
        for key in keys:
            self.tracker.acknowledged_by(key, who.name or "", "")
        return keys


_UNSET = object()


@dataclass(slots=True)
class _Variable:
    """A published variable: how to read it from a scan, and what was last written
    (value, stale) so that only changes are written."""

    nodeid: ua.NodeId
    read: Callable[[CellView], Any]
    vtype: ua.VariantType
    from_plant: bool
    last: object = _UNSET
_BAD = object()
_GOOD = ua.StatusCode()
_STALE = _status(StatusCodes.UncertainNoCommunicationLastUsableValue)


def _shelve(key: Any, seconds: Any) -> Shelve:
    if not isinstance(seconds, int | float) or seconds < 0:
        raise ValueError(f"shelving time {seconds!r}: expected seconds, 0 until it clears")
    return Shelve(str(key), None if seconds == 0 else round(seconds * 1_000_000))


def _manual_output(name: Any, request: Any) -> ManualOutput:
    value = {"on": True, "off": False, "release": None}.get(str(request).lower(), "?")
    if value == "?":
        raise ValueError(f"request {request!r}: expected on, off or release")
    return ManualOutput(str(name), value)  # type: ignore[arg-type]


def _value(variant: Any) -> Any:
    return variant.Value if isinstance(variant, ua.Variant) else variant


def _arg(name: str, vtype: ua.VariantType, text: str) -> ua.Argument:
    return ua.Argument(Name=name, DataType=_id(vtype.value), ValueRank=-1,
                       Description=ua.LocalizedText(text))


async def _describe(node: Node, text: str) -> None:
    await node.write_attribute(AttributeIds.Description, ua.DataValue(
        ua.Variant(ua.LocalizedText(text), ua.VariantType.LocalizedText)))


def _two_state(event: Any, name: str, value: bool, true: str, false: str,
               stamp: ua.DateTime) -> None:
    changed = getattr(event, f"{name}/Id", None) != value
    setattr(event, name, ua.LocalizedText(true if value else false))
    setattr(event, f"{name}/Id", value)
    if changed and f"{name}/TransitionTime" in event.data_types:
        setattr(event, f"{name}/TransitionTime", stamp)


def _comment_text(comment: ua.Variant) -> str:
    """The text of a Part 9 method's LocalizedText comment ('' when none was given)."""
    text = _value(comment)
    return (text.Text or "") if isinstance(text, ua.LocalizedText) else ""

"""The runtime's side of its screens: who is attached, who is in control, what each is sent.

The hub sits beside the session (the scans never wait for it): it records every scan
(:class:`~hmi.session.recorder.ScanRecorder`), builds each screen's frame when that screen
can take one — the latest scan with everything recorded since the screen's last frame, so a
screen that falls behind loses frames, never edges — and carries out what screens send:
commands (with who sent them, into the journal), control requests, virtual time.

Control: at most one screen is *in control*. The first screen that wants control gets it if
nobody holds it; another asks (the holder is asked in its frames, and hands it over or keeps
it), or takes it over (its operator confirmed that first). A command from a screen not in
control is refused with the reason, and journalled like every command.

Transport-free: the socket server (hmi.runtime.server) and the in-process link
(hmi.link.local) hand it decoded messages and send what it returns.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hmi.access import audit, roles
from hmi.access.audit import SignInRefusal
from hmi.engine.commands import ChoosePolicy, Command, CommandResult, StepScans, describe
from hmi.errors import UsageError
from hmi.runtime.admission import GATEWAY_DOORS, LOCAL, Admission
from hmi.session.journal_recorder import JournalRecorder
from hmi.session.live import LiveRunner
from hmi.session.recorder import Cursor, ScanRecorder
from hmi.session.reset_guard import command_as_shown
from hmi.session.session import Session
from hmi.wire import messages as m
from hmi.wire.codec import Codec

MAX_STEPS = 100_000  # scans one StepScans may ask for (the step dialog asks far fewer)
MAX_ADVANCE_US = 3600 * 1_000_000  # virtual time one Advance may ask for
MAX_REASON = 500  # characters of a reason given with a command
REASON_DOORS = ("terminal", "browser")  # doors whose screens ask their person for a reason
TICK_S = 1.0  # a screen hears from the runtime at least this often (a Tick if nothing new)


def cell_facts(session: Session) -> m.CellFacts:
    """What a screen needs to know of the cell once: read from the session's engine."""
    engine = session.engine
    plant = engine.plant
    return m.CellFacts(
        project=engine.project.name, control=engine.control_name, layout=engine.layout,
        safe_vector=tuple(bool(v) for v in engine.safe_vector),
        devices={device: tuple(outputs) for device, outputs in engine.devices.items()},
        plant=m.PlantFacts(
            kind=plant.kind, description=plant.status.description, is_real=plant.is_real,
            can_inject=plant.can_inject, can_repair=plant.can_repair,
            can_set_inputs=plant.can_set_inputs, free_inputs=tuple(plant.free_inputs),
            faults=tuple((d, c, t) for d, c, t in plant.faults())),
        period_us=session.period_us, history=session.history, epoch_us=session.epoch_us)


def run_info(session: Session) -> m.RunInfo:
    state = session.state
    return m.RunInfo(state.label, state.running, state.speed)


@dataclass
class Client:
    """A screen attached to the hub, as the hub keeps it."""

    id: str
    identity: m.Identity
    since_us: int
    cursor: Cursor | None = None  # what its last frame told it
    seq: int = 0
    shown: tuple[Any, ...] | None = None  # what its last frame showed (nothing new: no frame)
    sent_at: float = 0.0  # monotonic time of the last frame or tick
    frames: int = 0
    dropped: int = 0  # frames it could not take (a later one went instead)
    table_id: str = ""  # its sign-in's entry in the users' session table
    locked: bool = False  # left untouched (idle-lock): its commands refused until unlocked
    signed_in: bool = True  # its person gave a password or a ticket (not local-terminal)
    info: m.ClientInfo = field(init=False)

    def __post_init__(self) -> None:
        self.info = m.ClientInfo(self.id, self.identity, self.since_us)


class Hub:
    def __init__(self, session: Session, fingerprint: str, runtime: m.RuntimeInfo,
                 journal: JournalRecorder | None = None, runner: LiveRunner | None = None,
                 admission: Admission | None = None):
        self.session = session
        # who may attach, as whom (None: as the screen says: an in-process link's tests)
        self.admission = admission
        self.fingerprint = fingerprint
        self.runtime = runtime
        self.journal = journal
        self.runner = runner
        self.recorder = ScanRecorder(session.engine.layout)
        session.scan_listeners.append(self._record)
        self.recorder_errors = 0
        if session.last is None:
            session.scan_once()
        else:
            self._record(session.last)
        self.facts = cell_facts(session)
        self.codec: Codec = m.codec(memo=True)  # one snapshot, walked once for all screens
        self.schema = m.schema_digest()
        self.lock = threading.RLock()
        self.clients: dict[str, Client] = {}
        self.holder: str | None = None
        self.asked_by: str | None = None
        self.services: dict[str, m.ServiceStatus] = {}
        self._reporters: dict[str, str] = {}  # service -> the screen that reports it
        self._control_version = 0
        self._ids = itertools.count(1)
        self.frames_sent = 0
        # the cell is asked to stop (by the screen in control): why; told to `on_stop`
        self.stop_reason: str | None = None
        self.on_stop: list[Callable[[str], None]] = []
        # the transport's: the most unsent bytes of any screen (the socket server's)
        self.backlog: Callable[[], int] = lambda: 0

    def _record(self, snapshot: Any) -> None:
        """Every scan, in the scan thread: a failure of the recorder is the screens' (their
        history misses a scan), never the scan's."""
        try:
            self.recorder.on_scan(snapshot)
        except Exception:
            self.recorder_errors += 1

    # -- attaching ---------------------------------------------------------------------------
    def attach(self, hello: m.Hello) -> tuple[Client | None, m.Welcome | m.Refused]:
        if hello.protocol != m.PROTOCOL or hello.schema != self.schema:
            return None, m.Refused(
                f"this runtime speaks protocol {m.PROTOCOL} (schema {self.schema}), the screen "
                f"{hello.protocol} (schema {hello.schema}): they are different versions of "
                "plchmi; stop the runtime and start it again with this one")
        if hello.fingerprint != self.fingerprint:
            return None, m.Refused(
                f"this runtime runs {self.facts.project} from other files than the screen "
                "loaded (the project changed since the runtime started, or another project "
                "of the same name): stop the runtime and start it again")
        identity = hello.identity
        if identity.role not in m.ROLES or identity.door not in m.DOORS:
            return None, m.Refused(f"unknown role {identity.role!r} or door {identity.door!r}")
        table_id, signed_in = "", True
        if self.admission is not None:
            admitted = self.admission.admit(hello)
            if isinstance(admitted, SignInRefusal):
                self.journal_refusal(admitted, identity.session)
                return None, m.Refused(f"not signed in: {admitted.reason}")
            identity, table_id = admitted.identity, admitted.table_id
            signed_in = admitted.signed_in
        with self.lock:
            client = Client(f"c{next(self._ids)}", identity, self.session.engine.now,
                            table_id=table_id, signed_in=signed_in)
            self.clients[client.id] = client
            self._journal("client-attached", f"{client.info} attached", client)
            if hello.want_control and identity.may_command and self.holder is None:
                self._grant(client, "control-granted", f"{client.info} is in control")
            self._control_version += 1
        # (the facts as they are now: a historian may have placed the run's time 0 since)
        lock_us, warning_us = self._idle_settings(identity) if signed_in else (0, 0)
        return client, m.Welcome(m.PROTOCOL, client.id, cell_facts(self.session), self.runtime,
                                 identity, self._accountable(identity), lock_us, warning_us)

    def detach(self, client: Client, event: str, why: str) -> None:
        """A screen left (`client-left`: as asked), or was lost (`client-lost`: its
        connection broke, it sent something malformed, it stopped reading)."""
        with self.lock:
            if self.clients.pop(client.id, None) is None:
                return
            if self.admission is not None and client.table_id:
                self.admission.table.close(client.table_id)
            self._journal(event, f"{client.info} {why}", client)
            if self.asked_by == client.id:
                self.asked_by = None
            if self.holder == client.id:
                self.holder = None
                self.asked_by = None
                self._journal("control-free", f"nobody is in control: {client.info} {why}",
                              client)
            self._control_version += 1
            for name, reporter in list(self._reporters.items()):
                status = self.services[name]
                if reporter == client.id and status.state in ("starting", "serving"):
                    # its gateway gone, the service is not up any more: the screens say so
                    gone = m.ServiceStatus(
                        name, "stopped" if event == "client-left" else "failed",
                        f"the {name} gateway ({client.info}) {why}", 0)
                    self.services[name] = gone
                    self._journal_service(client, gone)

    def journal_refusal(self, refused: SignInRefusal, client: str = "") -> None:
        """A sign-in refused at a door: the name tried, from where, why (never the
        password); the attempt that locked the account as ``account-locked``."""
        if self.journal is not None:
            self.journal.on_service(refused.event, refused.message, **refused.fields(),
                                    client=client)

    def _journal(self, event: str, message: str, client: Client) -> None:
        if self.journal is not None:
            identity = client.identity
            self.journal.on_service(event, message, by=identity.by, role=identity.role,
                                    client=f"{client.id}/{identity.session}")

    # -- what a screen is sent ---------------------------------------------------------------
    def control(self) -> m.ControlInfo:
        with self.lock:
            holder = self.clients.get(self.holder) if self.holder else None
            asked = self.clients.get(self.asked_by) if self.asked_by else None
            return m.ControlInfo(holder.info if holder else None,
                                 asked.info if asked else None,
                                 tuple(c.info for c in self.clients.values()))

    def frame(self, client: Client, force: bool = False) -> bytes | None:
        """The screen's next frame, encoded, if anything changed since its last one (else a
        Tick once a second, else None). Called when the screen can take it: its cursor moves
        on, so what this frame carries is never sent again."""
        changes_ = self.recorder.since(client.cursor)
        cell = changes_.cell
        if cell is None:
            return None
        run = run_info(self.session)
        overruns = self.runner.overruns if self.runner is not None else 0
        services = tuple(self.services.values())
        key = (id(cell), cell.snapshot.scan, run, overruns, self._control_version, services)
        now = time.monotonic()
        if key == client.shown and not force and not changes_.edges and not changes_.events:
            if now - client.sent_at < TICK_S:
                return None
            client.sent_at = now
            return self.encode(m.Tick(client.seq))
        client.seq += 1
        delta = m.HistoryDelta(
            changes_.full, changes_.edges, changes_.events, changes_.event_count,
            changes_.damage_count, changes_.constraints,
            tuple(m.AlarmBatch(e, a) for e, a in changes_.batches), changes_.batches_lost)
        data = self.encode(m.Frame(client.seq, cell, run, overruns, delta, self.control(),
                                   services))
        client.cursor = changes_.cursor
        client.shown = key
        client.sent_at = now
        client.frames += 1
        self.frames_sent += 1
        return data

    def encode(self, message: m.RuntimeMessage) -> bytes:
        return self.codec.dumps(message, m.RuntimeMessage)

    # -- what a screen sends -------------------------------------------------------------------
    def handle(self, client: Client, message: m.ClientMessage) -> m.RuntimeMessage | None:
        """Carry out one message of a screen; its answer (None: none is due)."""
        match message:
            case m.Send():
                return self._send(client, message)
            case m.RequestControl(id=ident):
                return m.Reply(ident, self._request(client))
            case m.TakeControl(id=ident):
                return m.Reply(ident, self._take(client))
            case m.ReleaseControl(id=ident):
                return m.Reply(ident, self._release(client))
            case m.HandOver(id=ident, to=to):
                return m.Reply(ident, self._hand_over(client, to))
            case m.Advance(id=ident, duration_us=duration):
                return m.Reply(ident, self._advance(client, duration))
            case m.Query(id=ident):
                return self.stats(ident)
            case m.Report(status=status):
                with self.lock:
                    before = self.services.get(status.name)
                    self.services[status.name] = status
                    self._reporters[status.name] = client.id
                if before is None or before.state != status.state:
                    self._journal_service(client, status)
                return None
            case m.Idle(id=ident, event=event, password=password):
                return m.Reply(ident, self._idle(client, event, password))
            case m.SignInRefused(refused=refused):
                if client.identity.door not in GATEWAY_DOORS:
                    raise ValueError("a sign-in refusal from a screen that is no gateway")
                self.journal_refusal(refused, f"{client.id}/{client.identity.session}")
                return None
            case m.Fault():
                if self.journal is not None:
                    identity = client.identity
                    with self.session.lock:
                        self.journal.on_ui_fault(message, by=identity.by, role=identity.role,
                                                 client=f"{client.id}/{identity.session}")
                return None
            case m.Bye(stop=stop):
                if stop:
                    refusal = self._refusal(client)
                    if refusal is None:
                        self.request_stop(f"stopped by {client.info}")
                return None
            case m.Hello():
                raise ValueError("a second Hello")
        raise ValueError(f"unexpected {type(message).__name__}")

    def _journal_service(self, client: Client, status: m.ServiceStatus) -> None:
        """A gateway's change of state (the OPC UA server serving, stopped, failed), in the
        journal with who reported it; a server starting is journalled once it serves."""
        if status.state != "starting":
            self._journal(f"{status.name}-{status.state}", status.text, client)

    def _refusal(self, client: Client) -> str | None:
        """Why this screen may not command the cell now (None: it may)."""
        identity = client.identity
        if not identity.may_command:
            return "a viewer does not send commands (attached to view)"
        if client.locked:
            return "this screen is locked (left untouched): sign in again on it first"
        if self.holder == client.id:
            return None
        holder = self.clients.get(self.holder) if self.holder else None
        if holder is None:
            return "nobody is in control: request control first"
        return (f"not in control: {holder.info} is; request control (or take it over) "
                "first")

    def _send(self, client: Client, message: m.Send) -> m.Reply:
        reply = self._carry_out(client, message)
        if self.journal is not None:
            self.journal.sync()  # the answer goes once the action is on disk
        return reply

    def _carry_out(self, client: Client, message: m.Send) -> m.Reply:
        session = self.session
        who = client.identity
        if message.on_behalf is not None:
            if who.door not in GATEWAY_DOORS:
                raise ValueError("on_behalf from a screen that is no gateway")
            who = message.on_behalf
        vouched: m.Identity | str = who
        if message.on_behalf is not None and self.admission is not None:
            vouched = self.admission.vouch(who)  # the users file's word, not the gateway's
        if isinstance(vouched, m.Identity):
            who = vouched
        origin = who.by + (f" ({message.note})" if message.note else "")
        details = {"user": who.user, "role": who.role, "door": who.door,
                   "client": f"{client.id}/{client.identity.session}"}
        if message.reason.strip():
            details["reason"] = message.reason.strip()[:MAX_REASON]
        command = message.command
        # roles are the users file's: without one nobody signed in, and the terminal does
        # what it always did (a viewer still sends nothing: _refusal)
        enforced = self.admission is not None and self.admission.enforced()
        with self.lock:
            refusal = (self._refusal(client) or (vouched if isinstance(vouched, str) else None)
                       or (self._role_refusal(who, command) if enforced else None)
                       or self._bounds(command))
        if refusal is None:
            # (off the hub's lock: a password check)
            refusal = self._accounted(who, message, client.signed_in
                                      or message.on_behalf is not None)
        if refusal is not None:
            return m.Reply(message.id, session.decline(command, refusal, origin, details))
        guard = message.guard
        if guard is None:
            return m.Reply(message.id, session.command(command, origin, details))
        result, declined = command_as_shown(session, command, guard.shown, guard.seen_scan,
                                            origin, details)
        return m.Reply(message.id, result, declined=declined)

    def _accountable(self, who: m.Identity) -> bool:
        """Whether a reason (and for the riskiest, the password) is asked of `who`: a person
        signed in at a screen that can ask (the terminal, a browser). An OPC UA client's
        methods carry no reason (its comment is journalled when it gives one)."""
        return (who.door in REASON_DOORS and self.admission is not None
                and self.admission.enforced())

    def _idle_settings(self, who: m.Identity) -> tuple[int, int]:
        """When a signed-in screen locks untouched, and warns before (the users file's)."""
        if not self._accountable(who) or self.admission is None:
            return 0, 0
        try:
            found = self.admission.auth.users()
        except UsageError:
            return 0, 0
        if found is None:
            return 0, 0
        return found.settings.idle_lock_us, found.settings.idle_warning_us

    def _idle(self, client: Client, event: str, password: str) -> CommandResult:
        """A screen locked untouched, or its person back with their password."""
        if event == "locked":
            with self.lock:
                client.locked = True
            self._journal("session-locked", f"{client.info} locked: nobody touched it for "
                          "the users file's idle-lock; the cell runs on", client)
            return CommandResult.ok("locked")
        if event != "unlock":
            raise ValueError(f"unknown idle event {event!r}")
        if not client.locked:
            return CommandResult.ok("not locked")
        who = client.identity
        if self.admission is None:
            return CommandResult.refused("nobody signs in here")
        result = self.admission.auth.submit(who.user, password).result()
        if not result.accepted:
            self.journal_refusal(audit.refusal(who.user, who.door, LOCAL, result.reason,
                                               result.locked_now),
                                 f"{client.id}/{who.session}")
            return CommandResult.refused(result.reason)
        with self.lock:
            client.locked = False
        self._journal("session-unlocked", f"{client.info} unlocked with the password", client)
        return CommandResult.ok("unlocked")

    def _accounted(self, who: m.Identity, message: m.Send,
                   signed_in: bool = True) -> str | None:
        """Why the command may not go without more from its sender: no reason given where
        one is asked, or the password asked again and wrong (counted towards the lockout
        like any wrong password). Blocking: an argon2 check (a worker thread's)."""
        command = message.command
        if len(message.reason) > MAX_REASON:
            return f"refused: a reason of at most {MAX_REASON} characters"
        if not self._accountable(who):
            return None
        if isinstance(command, ChoosePolicy):  # an explanation's policy: what it carries out
            command = self.session.policy_command(command.key, command.policy) or command
        if roles.needs_reason(command) and not message.reason.strip():
            return (f"refused: {describe(command)} needs a reason (it goes to the journal "
                    "with your name)")
        if roles.needs_password(command):
            if self.admission is None:
                return None
            if not signed_in:
                return (f"refused: {describe(command)} asks for your password again, and "
                        "this terminal did not sign in (local-terminal): attach with a name "
                        "and password to do this")
            result = self.admission.auth.submit(who.user, message.password).result()
            if result.locked_now:
                self.journal_refusal(audit.refusal(who.user, who.door, LOCAL, result.reason,
                                                   True), who.session)
            if not result.accepted:
                return (f"refused: {describe(command)} asks for your password again: "
                        f"{result.reason}")
        return None

    @staticmethod
    def _role_refusal(who: m.Identity, command: Command) -> str | None:
        """The role's rights (hmi.access.roles: an unknown command or role is refused)."""
        return None if roles.may(who.role, command) else roles.refusal(who.role, command)

    @staticmethod
    def _bounds(command: Command) -> str | None:
        if isinstance(command, StepScans) and command.count > MAX_STEPS:
            return f"at most {MAX_STEPS:,} scans at a time"
        return None

    def _grant(self, client: Client, event: str, message: str) -> None:
        self.holder = client.id
        self.asked_by = None
        self._control_version += 1
        self._journal(event, message, client)

    def _request(self, client: Client) -> CommandResult:
        with self.lock:
            if not client.identity.may_command:
                return CommandResult.refused("a viewer cannot take control (attached to view)")
            if self.holder == client.id:
                return CommandResult.ok("you are in control")
            holder = self.clients.get(self.holder) if self.holder else None
            if holder is None:
                self._grant(client, "control-granted", f"{client.info} is in control")
                return CommandResult.ok("you are in control")
            self.asked_by = client.id
            self._control_version += 1
            self._journal("control-requested", f"{client.info} asks {holder.info} for "
                          "control", client)
            return CommandResult.ok(f"asked {holder.info} to hand control over")

    def _take(self, client: Client) -> CommandResult:
        with self.lock:
            if not client.identity.may_command:
                return CommandResult.refused("a viewer cannot take control (attached to view)")
            holder = self.clients.get(self.holder) if self.holder else None
            if holder is client:
                return CommandResult.ok("you are in control")
            taken = f", taken over from {holder.info}" if holder else ""
            self._grant(client, "control-taken", f"{client.info} is in control{taken}")
            return CommandResult.ok(f"you are in control{taken}")

    def _release(self, client: Client) -> CommandResult:
        with self.lock:
            if self.holder != client.id:
                return CommandResult.refused("you are not in control")
            self.holder = None
            self._control_version += 1
            self._journal("control-released", f"{client.info} released control: "
                          "nobody is in control", client)
            return CommandResult.ok("nobody is in control now")

    def _hand_over(self, client: Client, to: str) -> CommandResult:
        with self.lock:
            if self.holder != client.id:
                return CommandResult.refused("you are not in control")
            if not to:
                asked = self.clients.get(self.asked_by) if self.asked_by else None
                self.asked_by = None
                self._control_version += 1
                if asked is not None:
                    self._journal("control-kept", f"{client.info} keeps control "
                                  f"(asked by {asked.info})", client)
                return CommandResult.ok("you keep control")
            other = self.clients.get(to)
            if other is None or not other.identity.may_command:
                return CommandResult.refused(f"no screen {to} that may take control")
            self._grant(other, "control-handed-over",
                        f"{client.info} handed control over to {other.info}")
            return CommandResult.ok(f"control handed over to {other.info}")

    def _advance(self, client: Client, duration_us: int) -> CommandResult:
        if not self.runtime.virtual:
            return CommandResult.refused("this runtime runs on the wall clock")
        with self.lock:
            refusal = self._refusal(client)
        if refusal is not None:
            return CommandResult.refused(refusal)
        if not 0 < duration_us <= MAX_ADVANCE_US:
            return CommandResult.refused(f"virtual time to run: 1 µs to {MAX_ADVANCE_US} µs")
        session = self.session
        count = 0
        if session.state.running:
            end = session.engine.now + duration_us
            while session.state.running and session.next_time <= end:
                session.scan_once()
                count += 1
        return CommandResult.ok(f"{count} scans")

    def request_stop(self, why: str) -> None:
        if self.stop_reason is None:
            self.stop_reason = why
            for listener in list(self.on_stop):
                listener(why)

    # -- the runtime's own figures -------------------------------------------------------
    def stats(self, ident: int = 0) -> m.Stats:
        runner = self.runner
        lateness = runner.lateness if runner is not None else None
        with self.lock:
            dropped = sum(c.dropped for c in self.clients.values())
            clients = len(self.clients)
        return m.Stats(ident, self.session.engine.scan, runner.overruns if runner else 0,
                       lateness.percentile(0.5) if lateness else 0.0,
                       lateness.percentile(0.99) if lateness else 0.0,
                       lateness.most if lateness else 0.0,
                       lateness.count if lateness else 0,
                       rss_kb(), clients, self.frames_sent, dropped, self.backlog(),
                       self.runtime.realtime)


def rss_kb() -> int:
    """This process's resident memory (Linux: /proc/self/statm), 0 where unknown."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") // 1024
    except (OSError, ValueError, IndexError):
        return 0

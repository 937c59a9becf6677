"""The OPC UA server's doors: who may open a session, and how much a client may ask.

asyncua activates a session synchronously, on the loop that also publishes the cell: a
password check there (argon2, ~50 ms) would freeze publishing for every client while
anyone guesses. So each ActivateSession request is looked at *before* asyncua handles it
(:class:`CellProcessor`, asyncua's per-connection processor with one method more): the
identity token is decrypted and checked in the sign-in threads (hmi.access.signin), and
asyncua's own activation then only reads the verdict (:func:`verdict`). The same look
refuses what the token policy forbids: a password that comes in clear text on a channel
that does not encrypt (asyncua would take it), an untrusted user certificate (asyncua would
open an anonymous session), a user who already has the sessions the users file allows.

The limits (:func:`apply_limits`): connections and sessions at once, the time a connection
may stay without an activated session (a socket that never says HEL included), the
subscriptions, and the shortest publishing interval granted (the cell's own: faster brings
nothing and costs the server). And the bytes a connection may have the server hold
(:class:`BoundedProtocol`): no message chunk is larger than the server's receive buffer, so
a header that claims more (a HEL claiming 2 GiB) closes the connection at once instead of
being buffered while its data streams in; and no request, all its chunks together, is larger
than :data:`MAX_REQUEST_BYTES` (an ERR message, then the connection closed).
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from asyncua import ua
from asyncua.common.connection import TransportLimits
from asyncua.server import binary_server_asyncio
from asyncua.server.binary_server_asyncio import OPCUAProtocol
from asyncua.server.internal_session import InternalSession
from asyncua.server.server import Server
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary

from hmi.access.audit import SignInRefusal, refusal
from hmi.access.sessions import SessionTable
from hmi.opcua.users import ANONYMOUS, Identity, TrustList, Users

log = logging.getLogger("hmi.opcua")

MAX_CONNECTIONS = 32  # TCP connections at once, sessions or not
MAX_SESSIONS = 16  # activated sessions at once
ACTIVATION_S = 10.0  # a connection without an activated session after this is closed
MAX_SUBSCRIPTIONS = 64
MAX_MESSAGES_QUEUED = 64  # parsed requests waiting per connection
# The largest request a client may send, all its chunks together. asyncua's own is 100 MB,
# held in memory until the last chunk: any client with a channel (anonymous ones too) could
# have the gateway hold 32 x 100 MB. What a client of the cell asks (reads, browses, a
# method's arguments, history reads) is a few kilobytes.
MAX_REQUEST_BYTES = 1 << 20
CHUNK_BYTES = 65535  # the receive and send buffers (asyncua's, and the spec's usual)

# (identity or None, why not): what the look before activation decided, for get_user.
_verdict: contextvars.ContextVar[tuple[Identity | None, str] | None] = \
    contextvars.ContextVar("opcua_verdict", default=None)

_ACTIVATE = ua.NodeId(ua.Int32(ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary))
_CLOSE = ua.NodeId(ua.Int32(ObjectIds.CloseSessionRequest_Encoding_DefaultBinary))
_CREATE = ua.NodeId(ua.Int32(ObjectIds.CreateSessionRequest_Encoding_DefaultBinary))
ENCRYPTED = ua.MessageSecurityMode.SignAndEncrypt

Gate = Callable[["CellProcessor", ua.ActivateSessionParameters],
                Awaitable[tuple[Identity | None, str]]]


def verdict() -> tuple[Identity | None, str] | None:
    return _verdict.get()


class CellProcessor(UaProcessor):
    """asyncua's processor of one connection, which looks at ActivateSession first."""

    gate: Gate | None = None  # set by the server (one per process: one server per process)
    trust: TrustList | None = None  # the client applications trusted on a secured channel
    released: Callable[[str], None] | None = None  # a session's user gave it up
    ticket: str | None = None  # this connection's entry in the sessions table

    async def process_message(self, seqhdr: Any, body: Any) -> Any:
        handle: Callable[[Any, Any], Awaitable[Any]] = super().process_message
        gate = type(self).gate
        if gate is None:
            return await handle(seqhdr, body)
        peek = body.copy()
        typeid = nodeid_from_binary(peek)
        if typeid == _CREATE and not self._trusted():
            header = struct_from_binary(ua.RequestHeader, peek)
            fault = ua.ServiceFault()
            fault.ResponseHeader.ServiceResult = ua.StatusCode(
                ua.UInt32(StatusCodes.BadCertificateUntrusted))
            send: Callable[[Any, Any, Any], None] = self.send_response
            send(header.RequestHandle, seqhdr, fault)
            return True
        if typeid == _ACTIVATE:
            struct_from_binary(ua.RequestHeader, peek)
            params = struct_from_binary(ua.ActivateSessionParameters, peek)
            token = _verdict.set(await gate(self, params))
            try:
                return await handle(seqhdr, body)
            finally:
                _verdict.reset(token)
        if typeid == _CLOSE:
            self.release()
        return await handle(seqhdr, body)

    def _trusted(self) -> bool:
        """A secured channel's client application must be in the trust list (on a None
        channel its certificate proves nothing and is not looked at, as Part 4 says)."""
        policy = self._connection.security_policy
        trust = type(self).trust
        if trust is None or policy.Mode == ua.MessageSecurityMode.None_:
            return True
        der = policy.peer_certificate
        if der and trust.check(bytes(der)):
            return True
        log.warning("OPC UA client refused: its application certificate is not trusted (kept "
                    "in %s for review; plchmi opcua trust FILE trusts it)",
                    trust.rejected_folder)
        return False

    def release(self) -> None:
        ticket, self.ticket = self.ticket, None
        if ticket is not None and type(self).released is not None:
            type(self).released(ticket)  # type: ignore[misc]

    async def close(self) -> None:
        self.release()
        close: Callable[[], Awaitable[None]] = super().close
        await close()


CHUNK_HEADER = 8  # bytes of a chunk's header up to and with its size (Part 6, 7.1.2)


class BoundedProtocol(OPCUAProtocol):
    """asyncua's connection, which never holds more than one chunk of unparsed bytes.

    asyncua buffers whatever a header says is coming: a HEL claiming 2 GiB and the data
    streamed after it stayed in memory (+78 MB in 10 s in the gateway) until the activation
    limit closed the socket. Part 6 bounds every chunk by the receiver's buffer size
    (``ReceiveBufferSize``; asyncua checks it only once a whole chunk has arrived), and the
    one a client may negotiate is never larger than the server's own: a chunk that claims
    more, or unparsed bytes beyond it, close the connection."""

    def data_received(self, data: bytes) -> None:
        transport = self.transport
        if transport is None or transport.is_closing():
            self._buffer = b""  # (closed for its size: what still arrives is dropped)
            return
        super().data_received(data)
        pending = self._buffer
        most = self.limits.max_recv_buffer
        claimed = (int.from_bytes(pending[4:CHUNK_HEADER], "little")
                   if len(pending) >= CHUNK_HEADER else 0)
        if claimed > most or len(pending) > most:
            log.warning("OPC UA connection from %s closed: a message chunk of %d bytes "
                        "claimed, at most %d accepted", peer_name(self.peer_name),
                        max(claimed, len(pending)), most)
            self._buffer = b""
            transport.close()

    def connection_lost(self, exc: BaseException | None) -> None:
        """asyncua keeps each closed connection's closing task, and with it the connection's
        processor, buffers and session, in a list it empties every 10 s: a flood of short
        connections (thousands a second) held tens of megabytes that way. The task is
        forgotten as soon as it has finished."""
        tasks = self.closing_tasks
        before = len(tasks)
        super().connection_lost(exc)
        if len(tasks) > before:
            tasks[-1].add_done_callback(lambda task: _forget(tasks, task))


def _forget(tasks: list[asyncio.Task[Any]], task: asyncio.Task[Any]) -> None:
    """A finished closing task out of asyncua's list; its error logged here, as asyncua
    would have when it emptied the list."""
    if task not in tasks:
        return  # (asyncua took it first and reports it)
    tasks.remove(task)
    if not task.cancelled() and task.exception() is not None:
        log.error("OPC UA: a closed connection's session could not be closed: %r",
                  task.exception())


def install(gate: Gate, released: Callable[[str], None], trust: TrustList) -> None:
    """Every new connection of the process's OPC UA server gets a CellProcessor, and a
    BoundedProtocol."""
    CellProcessor.gate = gate
    CellProcessor.released = released
    CellProcessor.trust = trust
    setattr(binary_server_asyncio, "UaProcessor", CellProcessor)  # noqa: B010
    setattr(binary_server_asyncio, "OPCUAProtocol", BoundedProtocol)  # noqa: B010


def peer(processor: UaProcessor) -> str:
    """The client's address as the journal writes it (HOST:PORT)."""
    return peer_name(processor.name)


def peer_name(name: Any) -> str:
    if isinstance(name, tuple) and len(name) >= 2:
        return f"[{name[0]}]:{name[1]}" if ":" in str(name[0]) else f"{name[0]}:{name[1]}"
    return str(name or "")


def make_gate(users: Users, sessions: SessionTable | None, per_user: int,
              refused: Callable[[SignInRefusal], None] = lambda r: None) -> Gate:
    """The look before activation; each refusal of a named user or a certificate is told
    to `refused` (the journal), with the name tried and the client's address."""
    async def gate(processor: CellProcessor, params: ua.ActivateSessionParameters
                   ) -> tuple[Identity | None, str]:
        token = params.UserIdentityToken
        tried, why, locked = "", "", False
        found = await _look(processor, token)
        if isinstance(found, tuple):
            tried, why, locked = found
        elif found.name is not None and sessions is not None and processor.ticket is None:
            tried = found.name
            opened, why = sessions.open(found.name, "opcua", per_user)
            if opened is not None:
                processor.ticket = opened.id
        if why:
            log.warning("OPC UA session refused: %s", why)
            refused(refusal(tried, "opcua", peer(processor), why, locked))
            return None, why
        assert not isinstance(found, tuple)
        return found, ""

    async def _look(processor: CellProcessor, token: Any
                    ) -> Identity | tuple[str, str, bool]:
        """Who the token names, or (the name tried, why not, whether it locked)."""
        mode = processor._connection.security_policy.Mode
        if isinstance(token, ua.UserNameIdentityToken):
            if not token.EncryptionAlgorithm and mode != ENCRYPTED:
                return str(token.UserName or ""), (
                    "a password sent in clear text on a channel that does not encrypt: "
                    "refused (the token policy asks for it encrypted with the server's "
                    "certificate)"), False
            session = processor.session
            if session is None:
                return str(token.UserName or ""), "no session to activate", False
            try:
                name, password = processor.iserver.decrypt_user_token(session, token)
            except Exception:
                return str(token.UserName or ""), "the password could not be decrypted", False
            found, why, locked = await users.check_password(str(name or ""),
                                                            str(password or ""))
            return found if found is not None else (str(name or ""), why, locked)
        if isinstance(token, ua.X509IdentityToken):
            found, why = users.check_certificate(bytes(token.CertificateData or b""))
            return found if found is not None else ("(a user certificate)", why, False)
        return ANONYMOUS
    return gate


def apply_limits(server: Server, min_interval_ms: float) -> None:
    """Before the server starts: its transport limits are given to each connection then."""
    server.limits = TransportLimits(
        max_recv_buffer=CHUNK_BYTES, max_send_buffer=CHUNK_BYTES,
        max_chunk_count=-(-MAX_REQUEST_BYTES // CHUNK_BYTES),
        max_message_size=MAX_REQUEST_BYTES)
    iserver = server.iserver
    iserver.max_connections = MAX_CONNECTIONS
    iserver.max_pending_activation_seconds = ACTIVATION_S
    iserver.max_subscriptions = MAX_SUBSCRIPTIONS
    iserver.max_pending_messages_per_connection = MAX_MESSAGES_QUEUED
    InternalSession.max_connections = MAX_SESSIONS
    service = iserver.subscription_service
    create = service.create_subscription

    async def create_subscription(params: ua.CreateSubscriptionParameters, *args: Any,
                                  **kwargs: Any) -> ua.CreateSubscriptionResult:
        if not params.RequestedPublishingInterval >= min_interval_ms:  # NaN too
            params.RequestedPublishingInterval = min_interval_ms
        return await create(params, *args, **kwargs)

    service.create_subscription = create_subscription  # type: ignore[method-assign]

"""What the cell's OPC UA server is doing, as plain data for the operator's screen.

The HMI shows it (status bar, the palette's server page, a banner when the server stops)
without importing asyncua or anything of the server: the server thread builds a new
:class:`ServingStatus` when something changes and the UI reads the latest one.
"""

from __future__ import annotations

from dataclasses import dataclass

STARTING, SERVING, STOPPED, FAILED = "starting", "serving", "stopped", "failed"


@dataclass(frozen=True)
class OpcClient:
    """One connection of an OPC UA client to the server."""

    peer: str  # host:port of the client
    user: str  # the session's user: a name, "anonymous", or "" before a session exists
    security: str  # the secure channel: "None", "Basic256Sha256 Sign", "... SignAndEncrypt"

    @property
    def in_session(self) -> bool:
        return bool(self.user)


@dataclass(frozen=True)
class ServingStatus:
    url: str  # the endpoint, opc.tcp://HOST:PORT
    state: str  # STARTING, SERVING, STOPPED (as asked) or FAILED (with `error`)
    security: tuple[str, ...] = ("None",)  # the security policies offered
    writable: bool = False  # operator commands exposed as methods (--opcua-writable)
    users: int = 0  # users allowed to send commands (password file and certificates)
    clients: tuple[OpcClient, ...] = ()
    published: int = 0  # snapshots published
    events: int = 0  # alarm condition events sent
    errors: int = 0  # publishes that failed
    error: str = ""  # why it failed (FAILED)
    log: str = ""  # where the server writes its errors ("" if nowhere)

    @property
    def sessions(self) -> int:
        """Clients with a session: what a SCADA connected and reading counts as."""
        return sum(1 for c in self.clients if c.in_session)

    @property
    def local_only(self) -> bool:
        return "://127." in self.url or "://localhost" in self.url or "://[::1]" in self.url

    @property
    def up(self) -> bool:
        return self.state in (STARTING, SERVING)

    @property
    def failed(self) -> bool:
        return self.state == FAILED

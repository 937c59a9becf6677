"""The cell's OPC UA server as the operator sees it: a status bar field, a banner when it
stops, and the server page of the command palette (endpoint, clients, security).

The app reads the server's :class:`~hmi.opcua.status.ServingStatus` at each frame; nothing
here imports the server or asyncua (the HMI without ``--opcua`` never loads them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from rich.text import Text

from hmi.ui.style import MUTED, Level, banner, tag

if TYPE_CHECKING:
    from hmi.opcua.status import ServingStatus
    from hmi.wire.messages import ServiceStatus


class Served(Protocol):
    """What the HMI needs of a server: its latest status (hmi.opcua.server.CellServer)."""

    def status(self) -> ServingStatus: ...


def clients_text(count: int) -> str:
    return f"{count or 'no'} client{'' if count == 1 else 's'}"


def serving_field(status: ServingStatus) -> tuple[Text, int]:
    """The status bar's OPC UA field and its priority (hmi.ui.status.Field): on a narrow
    screen it stays longer than the scan number and time to its right (same priority: the
    rightmost drops first), never longer than the mode and the policy (priority 0)."""
    if status.up:
        return Text(f"OPC UA: {clients_text(status.sessions)}"), 1
    word = "FAILED" if status.failed else "STOPPED"
    return tag(f"OPC UA {word}", Level.ATTENTION), 1


def serving_banner(status: ServingStatus) -> Text | None:
    """The banner once the server is down while the HMI runs: the SCADA no longer sees the
    cell, but the cell itself goes on."""
    if status.up:
        return None
    line = banner("OPC UA STOPPED" if not status.failed else "OPC UA FAILED", Level.ATTENTION)
    why = f": {status.error}" if status.error else ""
    line.append(f" {status.url}{why} · the SCADA no longer sees this cell; the cell runs on"
                + (f" · details: {status.log}" if status.log else ""))
    return line


def serving_lines(status: ServingStatus) -> list[Text]:
    """The palette's server page: where it serves, to whom, how securely, what it sent."""
    lines: list[Text] = []
    if status.up:
        where = "this machine only" if status.local_only else "the network"
        lines.append(Text(f"Serving at {status.url} ({where})", style="bold"))
    else:
        state = tag("FAILED" if status.failed else "STOPPED", Level.ATTENTION)
        state.append(f" was serving at {status.url}")
        if status.error:
            state.append(f": {status.error}")
        lines.append(state)
    lines.append(Text(f"Security: {', '.join(status.security)}"))
    if status.writable:
        lines.append(Text(f"Operator commands: on, for {status.users} user"
                          f"{'' if status.users == 1 else 's'} (acknowledge, fault reset, "
                          "manual, policy, shelving; filtered as the HMI's)"))
    else:
        lines.append(Text("Operator commands: off (read only: clients browse, read and "
                          "receive alarms)"))
    lines.append(Text(f"{clients_text(status.sessions)} in session"
                      + (f", {len(status.clients)} connection"
                         f"{'' if len(status.clients) == 1 else 's'}"
                         if len(status.clients) != status.sessions else "")
                      + (":" if status.clients else "")))
    for client in status.clients:
        who = client.user or "no session yet"
        lines.append(Text(f"  {client.peer}  {who}  security {client.security}"))
    counts = Text(f"Published {status.published} scans, {status.events} alarm events",
                  style=MUTED)
    if status.errors:
        counts.append_text(tag(f" {status.errors} publishing errors", Level.ATTENTION))
    lines.append(counts)
    if status.log:
        lines.append(Text(f"Server log: {status.log}", style=MUTED))
    return lines


# -- a gateway's server, as the runtime's frames tell it (hmi.cli.gateway) -----------------

def gateway_field(status: ServiceStatus) -> tuple[Text, int]:
    """The status bar's OPC UA field for the runtime's gateway (its clients with a
    session, or that it is down), priority as serving_field's."""
    if status.state in ("starting", "serving"):
        return Text(f"OPC UA: {clients_text(status.clients)}"), 1
    return tag(f"OPC UA {status.state.upper()}", Level.ATTENTION), 1


def gateway_banner(status: ServiceStatus) -> Text | None:
    if status.state in ("starting", "serving"):
        return None
    line = banner(f"OPC UA {status.state.upper()}", Level.ATTENTION)
    line.append(f" {status.text} · the SCADA no longer sees this cell; the cell runs on")
    return line


def gateway_lines(status: ServiceStatus) -> list[Text]:
    """The palette's page for the gateway: what it reported last."""
    lines = [Text(status.text, style="bold")]
    if status.state in ("starting", "serving"):
        lines.append(Text(f"{clients_text(status.clients)} with a session"))
    lines.append(Text("served by the OPC UA gateway, a process attached to the cell's "
                      "runtime (plchmi gateway): its own log is gateway.log beside the "
                      "runtime's", style=MUTED))
    return lines

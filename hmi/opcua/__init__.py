"""Each plchmi as an OPC UA server, for a plant-wide SCADA (docs/opcua.md).

    model.py       the address space as plain data: objects, variables, how each is read
                   from a snapshot (no asyncua)
    conditions.py  plchmi's ISA-18.2 alarms as Part 9 AlarmConditionType events (no asyncua)
    users.py       who a client is: the users file, trusted certificates, the trust list
    doors.py       who may open a session (checked off the loop), and the limits
    server.py      the asyncua server in its own thread, fed by a cell source's snapshots
    source.py      the cell it serves: the runtime through its socket (the gateway:
                   hmi.cli.gateway) or a session in this process (a headless run)
    options.py     --opcua and its companions, from the command line to ServeOptions

asyncua is an optional extra (``pip install 'plchmi[opcua]'``): nothing here imports it
until a server is asked for, and :func:`require` says how to install it if it is missing.
"""

from __future__ import annotations

from hmi.errors import UsageError

INSTALL_HINT = ("OPC UA needs the optional extra: pip install 'plchmi[opcua]' "
                "(from a checkout: pip install -e '.[opcua]')")
NEEDS_USERS = ("--opcua-writable needs users: plchmi users add NAME --role operator (the "
               "users file; --opcua-users FILE names another) or --opcua-trust CERT")


def require() -> None:
    """Raise a usage error saying how to install asyncua, if it is not installed."""
    try:
        import asyncua  # noqa: F401
    except ImportError:
        raise UsageError(f"--opcua: asyncua is not installed. {INSTALL_HINT}") from None

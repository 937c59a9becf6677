"""Tickets: a door that signed a person in hands that sign-in to the screen it starts.

The browser door checks a password once (its sign-in page), then starts one screen process
per browser tab; each screen attaches to the cell's runtime, which must know who is there
without ever seeing the password. The door writes a ticket — a random name in the tickets
folder beside the users file (mode 0700), holding the user, the door and an expiry a few
seconds ahead — and gives its name to the screen it starts (in that process's environment,
never on a command line). The runtime redeems it: the file is claimed by renaming it (two
screens can never both redeem one ticket), read, deleted; an expired or unknown ticket is
refused. The user's role is then read from the users file as it is now (a user locked or
demoted since the sign-in gets nothing more than the file says).

Whoever can write the tickets folder can write the users file too: the folder adds no way in
for a local account that did not have one (docs/security.md, the local trust boundary).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .users import write_atomically

TICKET_S = 30.0  # a ticket is redeemed within this (the screen process's start)
_NAME = re.compile(r"^[0-9a-f]{32}$")


@dataclass(frozen=True)
class Ticket:
    user: str
    door: str
    web_session: str  # the door's own session (a browser's sign-in), for the journal


def folder(users_path: Path) -> Path:
    return users_path.with_name(users_path.name + ".tickets")


def issue(users_path: Path, user: str, door: str, web_session: str = "",
          clock: Callable[[], float] = time.time) -> str:
    """A new ticket's name (32 hex digits)."""
    where = folder(users_path)
    where.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(where, 0o700)
    name = os.urandom(16).hex()
    write_atomically(where / name, json.dumps({
        "user": user, "door": door, "web_session": web_session,
        "expires": clock() + TICKET_S}))
    return name


def redeem(users_path: Path, name: str,
           clock: Callable[[], float] = time.time) -> tuple[Ticket | None, str]:
    """The ticket, used up; or None and why not."""
    if not _NAME.match(name):
        return None, "not a ticket"
    where = folder(users_path)
    claimed = where / f".{name}.{os.getpid()}.claimed"
    try:
        os.rename(where / name, claimed)
    except OSError:
        return None, "no such ticket (used already, or never issued): sign in again"
    try:
        data = json.loads(claimed.read_text(encoding="utf-8"))
        ticket = Ticket(str(data["user"]), str(data["door"]), str(data.get("web_session", "")))
        expires = float(data["expires"])
    except (OSError, ValueError, TypeError, KeyError):
        return None, "a damaged ticket: sign in again"
    finally:
        with contextlib.suppress(OSError):
            claimed.unlink()
    if clock() > expires:
        return None, "the sign-in expired before the screen attached: sign in again"
    return ticket, ""


def sweep(users_path: Path, clock: Callable[[], float] = time.time) -> int:
    """Expired tickets removed (a screen that never started leaves its ticket); how many."""
    removed = 0
    where = folder(users_path)
    with contextlib.suppress(OSError):
        for entry in where.iterdir():
            with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
                if clock() > float(json.loads(entry.read_text(encoding="utf-8"))["expires"]):
                    entry.unlink()
                    removed += 1
    return removed

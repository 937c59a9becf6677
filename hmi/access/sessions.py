"""Signed-in sessions: how many one user has open, and when an untouched one locks.

:class:`SessionTable` keeps the sessions open now, every door and process together, in
``FILE.sessions`` beside the users file, under its lock: a session belongs to the process
that opened it, and one whose process is gone (killed, crashed) no longer counts. A user may
have ``sessions-per-user`` open at once; one more is refused with the list of those open.

:class:`IdleTimer` is a door's clock of the last thing its person did: a warning
``idle-warning`` before ``idle-lock``, then locked (the door covers the screen and asks the
password again; the cell runs on).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from .users import locked, write_atomically


@dataclass(frozen=True)
class OpenSession:
    id: str
    user: str
    door: str
    pid: int
    since: float  # wall seconds

    def describe(self) -> str:
        return f"{self.door} since {datetime.fromtimestamp(self.since):%H:%M}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class SessionTable:
    def __init__(self, users_path: Path, clock: Callable[[], float] = time.time):
        self.users_path = users_path
        self.path = users_path.with_name(users_path.name + ".sessions")
        self.clock = clock

    def _load(self) -> list[OpenSession]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            sessions = [OpenSession(str(d["id"]), str(d["user"]), str(d["door"]),
                                    int(d["pid"]), float(d["since"])) for d in data]
        except (OSError, ValueError, TypeError, KeyError):
            return []
        return [s for s in sessions if _alive(s.pid)]

    def _save(self, sessions: list[OpenSession]) -> None:
        write_atomically(self.path, json.dumps([s.__dict__ for s in sessions]))

    def open(self, user: str, door: str, limit: int,
             pid: int | None = None) -> tuple[OpenSession | None, str]:
        """A new session for `user`, or None and why not (the limit, and those open)."""
        with locked(self.users_path):
            sessions = self._load()
            mine = [s for s in sessions if s.user == user]
            if len(mine) >= limit:
                return None, (f"{user} has {len(mine)} sessions open already (at most "
                              f"{limit}: {', '.join(s.describe() for s in mine)}); close one "
                              "first")
            session = OpenSession(os.urandom(8).hex(), user, door, pid or os.getpid(),
                                  self.clock())
            sessions.append(session)
            self._save(sessions)
        return session, ""

    def close(self, session_id: str) -> None:
        with locked(self.users_path):
            sessions = self._load()
            kept = [s for s in sessions if s.id != session_id]
            if len(kept) != len(sessions):
                self._save(kept)

    def list(self) -> list[OpenSession]:
        with locked(self.users_path):
            return self._load()


class IdleTimer:
    """When a door's person last did something; the state the door shows (seconds from
    `clock`, a monotonic clock by default: a changed wall clock neither locks nor extends)."""

    def __init__(self, lock_after_s: float, warn_before_s: float,
                 clock: Callable[[], float] = time.monotonic):
        self.lock_after_s = lock_after_s
        self.warn_before_s = warn_before_s
        self.clock = clock
        self.last = clock()

    def touch(self) -> None:
        self.last = self.clock()

    def left(self) -> float:
        """Seconds until the session locks (0 or less: locked)."""
        return self.lock_after_s - (self.clock() - self.last)

    def state(self) -> str:
        left = self.left()
        if left <= 0:
            return "locked"
        return "warning" if left <= self.warn_before_s else "active"

"""What happened to the link with a real plant, as journal entries, without flooding.

The plant produces these entries where things happen (the connection attempt, the request
that got an exception response), stamped with the wall time they happened at; the journal
recorder drains them at the next scan or when it closes. Things that repeat at the scan rate
are never one entry each: an outage (failed attempts, connections lost, answers that break
the protocol) is its first problem, then counts, then its end (see :class:`LinkLog`);
exception responses and scan overruns are their first occurrence and then counts (see
:class:`Burst`).
Entry types are documented in docs/journal.md.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

WINDOW_S = 60.0  # one count entry per minute at most while a burst lasts

Entry = dict[str, Any]


def wall_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


class Burst:
    """Something that can happen every scan: the first occurrence of an episode becomes an
    entry at once, further ones only a count, written once per `window_s` while they go on
    and when the episode ends (`end`, or a whole window with none, seen by `tick`)."""

    def __init__(self, first: str, counted: str, what: str, window_s: float = WINDOW_S):
        self.first, self.counted, self.what, self.window_s = first, counted, what, window_s
        self.active = False
        self.count = 0  # since the last count entry
        self.total = 0  # in this episode
        self.window_start = 0.0
        self.last_hit = 0.0

    def hit(self, now: float, **fields: Any) -> list[Entry]:
        self.last_hit = now
        if not self.active:
            self.active, self.total, self.count, self.window_start = True, 1, 0, now
            return [{"event": self.first, **fields}]
        self.total += 1
        self.count += 1
        return self.tick(now)

    def tick(self, now: float) -> list[Entry]:
        if not self.active or now - self.window_start < self.window_s:
            return []
        if now - self.last_hit >= self.window_s:
            return self.end(now)
        out = self._count_entry(now, ended=False)
        self.window_start, self.count = now, 0
        return out

    def end(self, now: float) -> list[Entry]:
        if not self.active:
            return []
        out = self._count_entry(now, ended=True) if self.count else []
        self.active = False
        return out

    def _count_entry(self, now: float, ended: bool) -> list[Entry]:
        span = max(now if not ended else self.last_hit, self.window_start) - self.window_start
        tail = "; episode over" if ended else "; still going on"
        return [{"event": self.counted, "count": self.count, "episode_total": self.total,
                 "message": f"{self.count} more {self.what} in {span:.1f} s "
                 f"({self.total} in this episode){tail}"}]


@dataclass
class Outage:
    """From the first problem (a failed attempt, a lost connection) until a scan's I/O
    works again: what it was made of, in all and since the last count entry."""

    since_wall: str
    window_start: float
    losses: int = 0  # connections lost, the first included
    failed: int = 0  # connection attempts that failed
    connects: int = 0  # connections made during the outage (that then did not hold)
    window: Counter[str] = field(default_factory=Counter)  # the same, since the last entry
    last: str = ""  # the last problem, in plain words

    def add(self, what: str, reason: str) -> int:
        setattr(self, what, getattr(self, what) + 1)
        self.window[what] += 1
        if reason:
            self.last = reason
        count: int = getattr(self, what)
        return count

    @staticmethod
    def describe(counts: Mapping[str, int]) -> str:
        def n(count: int, one: str, many: str) -> str:
            return f"{count} {one if count == 1 else many}"
        parts = [n(counts.get("losses", 0), "connection lost", "connections lost"),
                 n(counts.get("failed", 0), "failed attempt to connect",
                   "failed attempts to connect")]
        if counts.get("connects"):
            parts.append(n(counts["connects"], "connection made that did not hold",
                           "connections made that did not hold"))
        return ", ".join(parts)

    def totals(self) -> dict[str, int]:
        return {"losses": self.losses, "failed": self.failed, "connects": self.connects}


class LinkLog:
    """The link's journal entries, waiting for the recorder. Thread-safe: the connection is
    first tried before the scan thread starts, then from the scan thread.

    An outage (see :class:`Outage`) is journalled as its first problem (`connect-failed` or
    `lost`, with what was wrong), a `link-problems` count a minute while it goes on, and
    its end: `reconnected` once a scan's I/O works again, or `connect-retries` if the session
    ends first. A device that accepts connections and then drops them, or answers nonsense,
    costs a few entries, not two per connection.
    """

    def __init__(self, where: str, clock: Callable[[], float] = time.monotonic,
                 window_s: float = WINDOW_S):
        self.where = where
        self.clock = clock
        self.window_s = window_s
        self._lock = threading.Lock()
        self._pending: list[Entry] = []
        self.outage: Outage | None = None
        self._ever_connected = False
        self._attempt = 0  # the attempt that made the current connection
        self.exceptions = Burst("exception", "exceptions", "exception responses", window_s)

    def _add(self, entries: list[Entry], wall: str | None = None) -> None:
        """Queue entries stamped `wall` (default: now). A problem that opens an outage is
        stamped with the outage's start, which later entries quote as `failing_since`."""
        wall = wall or wall_now()
        with self._lock:
            self._pending.extend({"type": "plant", "wall": wall, **e} for e in entries)

    def drain(self) -> list[Entry]:
        with self._lock:
            out, self._pending = self._pending, []
        return out

    def _outage(self, wall: str) -> Outage:
        if self.outage is None:
            self.outage = Outage(wall, self.clock())
        return self.outage

    def _tick(self) -> None:
        """While an outage lasts: one count entry per window."""
        o = self.outage
        now = self.clock()
        if o is None or now - o.window_start < self.window_s:
            return
        self._add([{"event": "link-problems", "losses": o.window["losses"],
                    "failed_attempts": o.window["failed"], "failing_since": o.since_wall,
                    "message": f"still no working link to {self.where}: in the last "
                    f"{now - o.window_start:.0f} s, {Outage.describe(o.window)}; last: "
                    f"{o.last}"}])
        o.window.clear()
        o.window_start = now

    # -- connection ----------------------------------------------------------------------
    def connect_failed(self, attempt: int, reason: str) -> None:
        wall = wall_now()
        if self._outage(wall).add("failed", reason) == 1:  # the first; the rest are counted
            self._add([{"event": "connect-failed", "attempt": attempt,
                        "message": f"{reason}; retrying with backoff (retries are "
                        "summarised when the link works again or the session ends)"}], wall)
        self._tick()

    def connected(self, attempt: int) -> None:
        """A connection was made. The first one is an entry at once; a reconnection only
        once a scan's I/O has worked on it (:meth:`link_ok`), or it is merely counted."""
        self._attempt = attempt
        if self._ever_connected:
            self._outage(wall_now()).add("connects", "")
            self._tick()
            return
        self._ever_connected = True
        o, self.outage = self.outage, None
        message = f"connected to {self.where} (attempt {attempt})"
        entry: Entry = {"event": "connected", "attempt": attempt,
                        "failed_attempts": o.failed if o else 0}
        if o is not None:
            message += (f" after {o.failed} failed attempts since {o.since_wall}; last: "
                        f"{o.last}")
            entry["failing_since"] = o.since_wall
        entry["message"] = message
        self._add([entry])

    def lost(self, reason: str) -> None:
        self._add(self.exceptions.end(self.clock()))
        wall = wall_now()
        if self._outage(wall).add("losses", reason) == 1:
            self._add([{"event": "lost",
                        "message": f"connection to {self.where} lost: {reason}"}], wall)
        self._tick()

    def link_ok(self) -> None:
        """A scan whose I/O all worked: an exception episode is over, and so is an outage."""
        if self.exceptions.active:
            self._add(self.exceptions.end(self.clock()))
        o = self.outage
        if o is None:
            return
        self.outage = None
        # the connection that works now was counted among those made: it held
        held = {**o.totals(), "connects": max(0, o.connects - 1)}
        self._add([{"event": "reconnected", "attempt": self._attempt,
                    "failed_attempts": o.failed, "losses": o.losses,
                    "failing_since": o.since_wall,
                    "message": f"the link to {self.where} works again (connection attempt "
                    f"{self._attempt}); the outage since {o.since_wall}: "
                    f"{Outage.describe(held)}; last problem: {o.last}"}])

    def gave_up(self) -> None:
        """The end of a session while the link is not working: the outage's summary."""
        o, self.outage = self.outage, None
        if o is None:
            return
        self._add([{"event": "connect-retries", "failed_attempts": o.failed,
                    "losses": o.losses, "failing_since": o.since_wall,
                    "message": f"no working link to {self.where} since {o.since_wall} when "
                    f"the session ended: {Outage.describe(o.totals())}; last: {o.last}"}])

    # -- exception responses -------------------------------------------------------------
    def exception(self, name: str, detail: str) -> None:
        self._add(self.exceptions.hit(self.clock(), name=name, message=detail))

    def close(self) -> None:
        self._add(self.exceptions.end(self.clock()))
        self.gave_up()

"""What happened to the link with a real plant, as journal entries, without flooding.

The plant produces these entries where things happen (the connection attempt, the request
that got an exception response), stamped with the wall time they happened at; the journal
recorder drains them at the next scan or when it closes. Things that repeat at the scan rate
are never one entry each: a retry loop is its first failure and then a summary, exception
responses and scan overruns are their first occurrence and then counts (see :class:`Burst`).
Entry types are documented in docs/journal.md.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
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


class LinkLog:
    """The link's journal entries, waiting for the recorder. Thread-safe: the connection is
    first tried before the scan thread starts, then from the scan thread."""

    def __init__(self, where: str, clock: Callable[[], float] = time.monotonic):
        self.where = where
        self.clock = clock
        self._lock = threading.Lock()
        self._pending: list[Entry] = []
        self._failures = 0  # failed attempts since the last connection (or the start)
        self._failing_since = ""  # wall time of the first of them
        self._last_failure = ""
        self._ever_connected = False
        self.exceptions = Burst("exception", "exceptions", "exception responses")

    def _add(self, entries: list[Entry]) -> None:
        wall = wall_now()
        with self._lock:
            self._pending.extend({"type": "plant", "wall": wall, **e} for e in entries)

    def drain(self) -> list[Entry]:
        with self._lock:
            out, self._pending = self._pending, []
        return out

    # -- connection ----------------------------------------------------------------------
    def connect_failed(self, attempt: int, reason: str) -> None:
        self._failures += 1
        self._last_failure = reason
        if self._failures == 1:  # the first of a series; the rest go into a summary
            self._failing_since = wall_now()
            self._add([{"event": "connect-failed", "attempt": attempt,
                        "message": f"{reason}; retrying with backoff (retries are "
                        "summarised when the connection is made or abandoned)"}])

    def connected(self, attempt: int) -> None:
        event = "reconnected" if self._ever_connected else "connected"
        message = f"connected to {self.where} (attempt {attempt})"
        entry: Entry = {"event": event, "attempt": attempt, "failed_attempts": self._failures}
        if self._failures:
            message += (f" after {self._failures} failed attempts since "
                        f"{self._failing_since}; last: {self._last_failure}")
            entry["failing_since"] = self._failing_since
        entry["message"] = message
        self._add([entry])
        self._ever_connected = True
        self._failures = 0

    def lost(self, reason: str) -> None:
        self._add(self.exceptions.end(self.clock()))
        self._add([{"event": "lost", "message": f"connection to {self.where} lost: {reason}"}])

    def gave_up(self) -> None:
        """The end of a session while still failing to connect: the retries' summary."""
        if self._failures:
            self._add([{"event": "connect-retries", "failed_attempts": self._failures,
                        "failing_since": self._failing_since,
                        "message": f"{self._failures} failed attempts to connect to "
                        f"{self.where} since {self._failing_since}, none succeeded; last: "
                        f"{self._last_failure}"}])
            self._failures = 0

    # -- exception responses -------------------------------------------------------------
    def exception(self, name: str, detail: str) -> None:
        self._add(self.exceptions.hit(self.clock(), name=name, message=detail))

    def scan_ok(self) -> None:
        """A scan whose I/O got no exception response: an exception episode is over."""
        if self.exceptions.active:
            self._add(self.exceptions.end(self.clock()))

    def close(self) -> None:
        self._add(self.exceptions.end(self.clock()))
        self.gave_up()

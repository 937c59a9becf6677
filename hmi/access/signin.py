"""Signing in: one argon2 check per attempt whatever the name, counted, off the serving loops.

Every attempt costs one argon2id verification: a known user's hash, or for a name nobody
has a dummy hash of the same parameters, so an answer's time never tells a user who exists
from one who does not; the answers' words never do either. Wrong passwords in a row are
counted per name (unknown names too, for the same reason), by every door and process
together, in ``FILE.failures`` beside the users file under its lock: at
``lockout-after`` (5) the name is locked for ``lockout-time``, whatever password comes next.

The check is CPU work of about 50 ms: a door that serves data from an event loop calls
:meth:`Authenticator.check_async` (or :meth:`submit` from a thread), which runs it in this
module's own pool of two threads (argon2 releases the GIL while it hashes) and refuses at
once, with a reason, when more than :data:`MAX_WAITING` attempts wait — thirty clients
guessing at once wait for each other, never for the loop that publishes the cell.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from hmi.timefmt import format_duration

from .users import MAX_PASSWORD, NAME, User, UsersFile, hasher, locked, read, write_atomically

MAX_WAITING = 16  # sign-in attempts queued or running at once, every door of the process
MAX_FAILURE_NAMES = 10_000  # names whose failures are kept (the oldest forgotten first)


def normal_priority() -> None:
    """A sign-in thread runs at normal priority: a password's hash is CPU work that a thread
    started by a runtime's real-time server thread would otherwise do at real-time priority
    (hmi.runtime.runtime.helpers_realtime)."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


@dataclass(frozen=True)
class SignInResult:
    accepted: bool
    reason: str  # plain words; "" when accepted
    user: User | None = None
    locked_now: bool = False  # this wrong password locked the account (journalled so)

    @property
    def role(self) -> str | None:
        return self.user.role if self.user else None


WRONG = "wrong user name or password"


class Authenticator:
    """Checks names and passwords against a users file, re-read when it changes."""

    def __init__(self, path: Path, clock: Callable[[], float] = time.time):
        self.path = path
        self.clock = clock
        self._hasher = hasher()
        self._dummy = self._hasher.hash(os.urandom(16).hex())
        self._cache: tuple[tuple[int, int, int] | None, UsersFile | None] = (None, None)
        self._executor: ThreadPoolExecutor | None = None
        self._slots = threading.BoundedSemaphore(MAX_WAITING)
        self._guard = threading.Lock()

    @staticmethod
    def failures_file(users_path: Path) -> Path:
        return users_path.with_name(users_path.name + ".failures")

    @property
    def failures_path(self) -> Path:
        return self.failures_file(self.path)

    def users(self) -> UsersFile | None:
        """The users file as it is now (read again when its size, time or inode changed)."""
        try:
            st = os.stat(self.path)
            key: tuple[int, int, int] | None = (st.st_ino, st.st_size, st.st_mtime_ns)
        except OSError:
            key = None
        with self._guard:
            if key is not None and key == self._cache[0]:
                return self._cache[1]
        users = read(self.path) if key is not None else None
        with self._guard:
            self._cache = (key, users)
        return users

    def _verify(self, digest: str, password: str) -> bool:
        from argon2.exceptions import InvalidHashError, VerificationError
        try:
            return bool(self._hasher.verify(digest, password))
        except (VerificationError, InvalidHashError):
            return False

    def check(self, name: str, password: str) -> SignInResult:
        """Blocking: about 50 ms of CPU. Doors that serve data use check_async/submit."""
        users = self.users()
        if users is None:
            return SignInResult(False, "nobody can sign in here: there is no users file "
                                "(plchmi users add NAME --role ROLE creates it)")
        user = users.users.get(name) if NAME.match(name) else None
        ok = self._verify(user.hash if user else self._dummy, password[:MAX_PASSWORD])
        ok = ok and user is not None and len(password) <= MAX_PASSWORD
        settings = users.settings
        key = name if NAME.match(name) else "?" + hashlib.sha256(
            name.encode("utf-8", "surrogatepass")).hexdigest()[:16]
        now = self.clock()
        with locked(self.path):
            state = self._failures()
            count, until, _ = state.get(key, (0, 0.0, 0.0))
            if until > now:
                left = format_duration(max(1, int(until - now)) * 1_000_000)
                return SignInResult(False, f"sign-in to this account is locked for another "
                                    f"{left} after {settings.lockout_after} wrong passwords "
                                    "in a row")
            if not ok:
                count = count + 1 if until == 0 else 1  # a lock that ran out starts again
                reason = WRONG
                locked_now = count >= settings.lockout_after
                if locked_now:
                    until = now + settings.lockout_us / 1e6
                    reason += (f"; {count} wrong in a row: sign-in to this account is locked "
                               f"for {format_duration(settings.lockout_us)}")
                else:
                    until = 0.0
                state[key] = (count, until, now)
                self._save(state)
                return SignInResult(False, reason, locked_now=locked_now)
            if key in state:
                del state[key]
                self._save(state)
        assert user is not None
        if user.locked:
            return SignInResult(False, f"the account {name} is locked by an administrator "
                                f"(plchmi users unlock {name})")
        return SignInResult(True, "", user)

    def _failures(self) -> dict[str, tuple[int, float, float]]:
        try:
            data = json.loads(self.failures_path.read_text(encoding="utf-8"))
            return {str(k): (int(v[0]), float(v[1]), float(v[2])) for k, v in data.items()}
        except (OSError, ValueError, TypeError, IndexError, AttributeError):
            return {}  # none yet, or damaged: counting starts again (never a crash)

    def _save(self, state: dict[str, tuple[int, float, float]]) -> None:
        if len(state) > MAX_FAILURE_NAMES:
            for key in sorted(state, key=lambda k: state[k][2])[:len(state)
                                                                 - MAX_FAILURE_NAMES]:
                del state[key]
        with contextlib.suppress(Exception):
            write_atomically(self.failures_path, json.dumps(state))

    # -- off the caller's loop ---------------------------------------------------------

    def submit(self, name: str, password: str) -> Future[SignInResult]:
        """The check in this authenticator's own threads; refused at once (a finished
        future) when MAX_WAITING attempts are already waiting."""
        if not self._slots.acquire(blocking=False):
            done: Future[SignInResult] = Future()
            done.set_result(SignInResult(False, "too many sign-in attempts at once; try "
                                         "again in a few seconds"))
            return done
        with self._guard:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=2,
                                                    thread_name_prefix="plchmi-signin",
                                                    initializer=normal_priority)
        try:
            future = self._executor.submit(self.check, name, password)
        except BaseException:
            self._slots.release()
            raise
        future.add_done_callback(lambda _: self._slots.release())
        return future

    async def check_async(self, name: str, password: str) -> SignInResult:
        return await asyncio.wrap_future(self.submit(name, password))

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)

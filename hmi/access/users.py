"""The users file: who may sign in, with which role, and how the doors treat sessions.

One line per user, ``NAME:ROLE:STATE:HASH`` — ROLE viewer, operator or engineer; STATE
``active`` or ``locked`` (``plchmi users lock``); HASH an argon2id hash (argon2-cffi), never
a password — and settings as ``KEY = VALUE`` lines (:class:`Settings`); ``#`` starts a
comment. ``plchmi users add|passwd|lock|unlock|remove|list`` write it; a person may edit it
too: a bad line is a usage error naming file:line. The file is written whole into a
temporary file and renamed over the old one, permissions 0600, under the lock file beside it
(two commands at once never lose a line).

The default file is ``$PLCHMI_DATA/users`` (the data folder of docs/journal.md): every cell
on this machine shares it, so a person has one identity at every door.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from hmi.errors import UsageError
from hmi.paths import data_folder
from hmi.textfile import FileProblem, read_text
from hmi.timefmt import DURATION_HINT, DurationError, format_duration, parse_duration

from .roles import ROLES

if TYPE_CHECKING:
    from argon2 import PasswordHasher

NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
_USER = re.compile(r"^(?P<name>[^:=\s]{1,64}):(?P<role>[a-z]+):(?P<state>[a-z]+):"
                   r"(?P<hash>\$argon2id\$v=19\$m=\d{1,7},t=\d{1,3},p=\d{1,3}\$"
                   r"[A-Za-z0-9+/]{11,64}\$[A-Za-z0-9+/]{16,128})$")
_SETTING = re.compile(r"^(?P<key>[a-z-]{1,40})\s*=\s*(?P<value>.*?)\s*$")
MAX_USERS_FILE_BYTES = 1_000_000
MIN_PASSWORD = 8
MAX_PASSWORD = 1024  # argon2 takes any length; a bound keeps a sign-in cheap to refuse

# argon2id with OWASP's parameters (19 MiB, 2 passes, 1 lane): about 50 ms a check on this
# class of machine under load, off the loops that serve data (hmi.access.signin).
TIME_COST, MEMORY_COST_KIB, PARALLELISM = 2, 19456, 1


def default_path() -> Path:
    return data_folder() / "users"


@dataclass(frozen=True)
class Settings:
    """How the doors treat sign-in and sessions; each a ``KEY = VALUE`` line."""

    lockout_after: int = 5  # wrong passwords in a row lock the account ...
    lockout_us: int = 15 * 60_000_000  # ... for this long
    idle_lock_us: int = 15 * 60_000_000  # a session nobody touches locks after this
    idle_warning_us: int = 60_000_000  # the warning comes this long before
    sessions_per_user: int = 3  # sessions of one user open at once, every door together
    local_terminal: str = "sign-in"  # or a role: the local terminal's without signing in
    banner: str = ""  # shown above every sign-in (also the project's banner:, see login.py)


_SETTING_KEYS = {
    "lockout-after": "lockout_after", "lockout-time": "lockout_us",
    "idle-lock": "idle_lock_us", "idle-warning": "idle_warning_us",
    "sessions-per-user": "sessions_per_user", "local-terminal": "local_terminal",
    "banner": "banner"}


@dataclass(frozen=True)
class User:
    name: str
    role: str
    locked: bool  # locked by an administrator (plchmi users lock), until unlocked
    hash: str

    def line(self) -> str:
        return f"{self.name}:{self.role}:{'locked' if self.locked else 'active'}:{self.hash}"


@dataclass(frozen=True)
class UsersFile:
    path: Path
    users: dict[str, User] = field(default_factory=dict)
    settings: Settings = Settings()


def _setting(path: Path, number: int, key: str, value: str) -> tuple[str, object]:
    where = f"{path}:{number}"
    if key not in _SETTING_KEYS:
        raise UsageError(f"{where}: unknown setting {key!r} (expected one of "
                         f"{', '.join(_SETTING_KEYS)})")
    name = _SETTING_KEYS[key]
    if name in ("lockout_after", "sessions_per_user"):
        if not (value.isascii() and value.isdigit()) or not 1 <= int(value) <= 1000:
            raise UsageError(f"{where}: {key} = {value!r}: expected a whole number from 1 "
                             "to 1000")
        return name, int(value)
    if name.endswith("_us"):
        try:
            us = parse_duration(value)
        except DurationError as exc:
            raise UsageError(f"{where}: {key} = {value!r} {exc.reason} (expected "
                             f"{DURATION_HINT})") from None
        if us <= 0:
            raise UsageError(f"{where}: {key} must be longer than zero")
        return name, us
    if name == "local_terminal":
        if value not in ("sign-in", *ROLES):
            raise UsageError(f"{where}: local-terminal = {value!r}: expected sign-in, "
                             "viewer, operator or engineer")
        return name, value
    if len(value) > 2000 or any(ord(c) < 32 for c in value):
        raise UsageError(f"{where}: banner: at most 2000 printable characters")
    return name, value


def parse(path: Path, text: str) -> UsersFile:
    users: dict[str, User] = {}
    settings: dict[str, object] = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        setting = _SETTING.match(line)
        if setting is not None and ":" not in line.split("=", 1)[0]:
            key, value = _setting(path, number, setting["key"], setting["value"])
            settings[key] = value
            continue
        match = _USER.match(line)
        if match is None:
            raise UsageError(f"{path}:{number}: expected NAME:ROLE:STATE:HASH (as plchmi "
                             "users add writes it) or KEY = VALUE")
        name = match["name"]
        if not NAME.match(name):
            raise UsageError(f"{path}:{number}: user name {name!r}: 1 to 64 letters, digits, "
                             "'_', '.', '@' or '-'")
        if match["role"] not in ROLES:
            raise UsageError(f"{path}:{number}: role {match['role']!r}: expected viewer, "
                             "operator or engineer")
        if match["state"] not in ("active", "locked"):
            raise UsageError(f"{path}:{number}: state {match['state']!r}: expected active "
                             "or locked")
        if name in users:
            raise UsageError(f"{path}:{number}: user {name} is named twice")
        users[name] = User(name, match["role"], match["state"] == "locked", match["hash"])
    values = Settings(**settings)  # type: ignore[arg-type]
    if values.idle_warning_us >= values.idle_lock_us:
        raise UsageError(f"{path}: idle-warning ({format_duration(values.idle_warning_us)}) "
                         f"must be shorter than idle-lock "
                         f"({format_duration(values.idle_lock_us)})")
    return UsersFile(path, users, values)


def read(path: Path) -> UsersFile | None:
    """The users file, or None if there is none (nobody can sign in)."""
    try:
        text = read_text(path, MAX_USERS_FILE_BYTES)
    except FileProblem as exc:
        if exc.message == "file not found":
            return None
        where = f"{path}:{exc.line}:{exc.col}" if exc.line else str(path)
        raise UsageError(f"{where}: {exc.message}") from None
    return parse(path, text)


def hasher() -> PasswordHasher:
    from argon2 import PasswordHasher
    return PasswordHasher(time_cost=TIME_COST, memory_cost=MEMORY_COST_KIB,
                          parallelism=PARALLELISM)


def check_password_rules(password: str) -> None:
    if len(password) < MIN_PASSWORD:
        raise UsageError(f"the password must be at least {MIN_PASSWORD} characters long")
    if len(password) > MAX_PASSWORD:
        raise UsageError(f"the password must be at most {MAX_PASSWORD} characters long")


@contextlib.contextmanager
def locked(path: Path) -> Iterator[None]:
    """The users file's lock (a file beside it): one writer at a time, across processes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path.with_name(path.name + ".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC,
                 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def write_atomically(path: Path, text: str) -> None:
    """`text` into `path`, whole or not at all (a temporary file renamed over it), 0600."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise UsageError(f"{path}: cannot be written ({exc.strerror})") from None


HEADER = ("# plchmi users (docs/security.md): NAME:ROLE:STATE:HASH, argon2id hashes only.\n"
          "# Written by plchmi users add|passwd|lock|unlock|remove; settings as KEY = VALUE.\n")


def _rewrite(path: Path, name: str, user: User | None) -> None:
    """Replace (or add, or with None remove) `name`'s line, keeping every other line."""
    lines: list[str] = []
    current = read(path)
    if current is not None:
        lines = read_text(path, MAX_USERS_FILE_BYTES).splitlines()
    out: list[str] = []
    done = False
    for raw in lines:
        match = _USER.match(raw.strip())
        if match is not None and match["name"] == name:
            if user is not None and not done:
                out.append(user.line())
            done = True
            continue
        out.append(raw)
    if user is not None and not done:
        out.append(user.line())
    text = "\n".join(out) + "\n"
    if current is None:
        text = HEADER + text
    parse(path, text)  # never write a file that would not read back
    write_atomically(path, text)


def find(path: Path, name: str) -> User:
    users = read(path)
    if users is None:
        raise UsageError(f"{path}: no users file (plchmi users add NAME --role ROLE "
                         "creates it)")
    if name not in users.users:
        raise UsageError(f"{path}: no user {name!r}")
    return users.users[name]


def add(path: Path, name: str, role: str, password: str) -> None:
    if not NAME.match(name):
        raise UsageError(f"user name {name!r}: 1 to 64 letters, digits, '_', '.', '@' or '-'")
    if role not in ROLES:
        raise UsageError(f"role {role!r}: expected viewer, operator or engineer")
    check_password_rules(password)
    digest = hasher().hash(password)
    with locked(path):
        users = read(path)
        if users is not None and name in users.users:
            raise UsageError(f"{path}: user {name} exists (plchmi users passwd {name} changes "
                             "the password)")
        _rewrite(path, name, User(name, role, False, digest))


def change(path: Path, name: str, *, password: str | None = None, role: str | None = None,
           lock: bool | None = None) -> User:
    """Change one user's password, role or lock; the user as written."""
    if role is not None and role not in ROLES:
        raise UsageError(f"role {role!r}: expected viewer, operator or engineer")
    digest = None
    if password is not None:
        check_password_rules(password)
        digest = hasher().hash(password)
    with locked(path):
        user = find(path, name)
        user = replace(user, hash=digest or user.hash, role=role or user.role,
                       locked=user.locked if lock is None else lock)
        _rewrite(path, name, user)
    return user


def remove(path: Path, name: str) -> None:
    with locked(path):
        find(path, name)
        _rewrite(path, name, None)

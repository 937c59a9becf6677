"""Who may send operator commands over OPC UA: a password file, and trusted certificates.

The password file holds one user per line, ``name:pbkdf2_sha256$ITERATIONS$SALT$HASH``
(hex salt and hash; ``#`` starts a comment), written by ``plchmi opcua-passwd FILE NAME``.
No password is ever stored in clear. A user may also present an X.509 certificate: the
certificates given with ``--opcua-trust CERT`` are trusted, each under its file's name.

Standard library only (hashlib, hmac): the check runs on the server's own event loop.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
from dataclasses import dataclass
from pathlib import Path

from hmi.errors import UsageError

ITERATIONS = 200_000
_LINE = re.compile(r"^(?P<name>[A-Za-z0-9_.@-]{1,64}):pbkdf2_sha256\$(?P<n>[0-9]{1,7})"
                   r"\$(?P<salt>[0-9a-f]{16,128})\$(?P<hash>[0-9a-f]{64})$")
NAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
MAX_USERS_FILE_BYTES = 1_000_000


@dataclass(frozen=True)
class PasswordEntry:
    name: str
    iterations: int
    salt: bytes
    digest: bytes

    def matches(self, password: str) -> bool:
        candidate = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), self.salt,
                                        self.iterations)
        return hmac.compare_digest(candidate, self.digest)

    def line(self) -> str:
        return (f"{self.name}:pbkdf2_sha256${self.iterations}${self.salt.hex()}"
                f"${self.digest.hex()}")


def hash_password(name: str, password: str, iterations: int = ITERATIONS) -> PasswordEntry:
    salt = os.urandom(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return PasswordEntry(name, iterations, salt, digest)


def read_password_file(path: Path) -> dict[str, PasswordEntry]:
    """The users of a password file; a bad line is a usage error naming file:line."""
    try:
        if path.stat().st_size > MAX_USERS_FILE_BYTES:
            raise UsageError(f"{path}: more than {MAX_USERS_FILE_BYTES:,} bytes; not a "
                             "password file")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"{path}: no such password file (create it with "
                         f"plchmi opcua-passwd {path} NAME)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot be read as a password file ({exc})") from None
    users: dict[str, PasswordEntry] = {}
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        match = _LINE.match(line)
        if match is None:
            raise UsageError(f"{path}:{number}: expected NAME:pbkdf2_sha256$ITERATIONS$SALT$"
                             "HASH (as plchmi opcua-passwd writes it)")
        if match["name"] in users:
            raise UsageError(f"{path}:{number}: user {match['name']} is named twice")
        users[match["name"]] = PasswordEntry(match["name"], int(match["n"]),
                                             bytes.fromhex(match["salt"]),
                                             bytes.fromhex(match["hash"]))
    if not users:
        raise UsageError(f"{path}: no user in the password file")
    return users


def write_user(path: Path, name: str, password: str) -> bool:
    """Add or replace one user's line; True if the user was new."""
    if not NAME.match(name):
        raise UsageError(f"user name {name!r}: 1 to 64 letters, digits, '_', '.', '@' or '-'")
    if len(password) < 8:
        raise UsageError("the password must be at least 8 characters long")
    lines: list[str] = []
    new = True
    if path.exists():
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"{path}: cannot be read ({exc})") from None
        kept = [line for line in lines if not line.startswith(f"{name}:")]
        new = len(kept) == len(lines)
        lines = kept
    lines.append(hash_password(name, password).line())
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write("\n".join(lines) + "\n")
    except OSError as exc:
        raise UsageError(f"{path}: cannot be written ({exc.strerror})") from None
    return new


@dataclass(frozen=True)
class Identity:
    """Who a client is: a named user (password or certificate), or anonymous."""

    name: str | None
    how: str  # "password", "certificate", "anonymous"

    @property
    def label(self) -> str:
        return f"{self.name} ({self.how})" if self.name else "anonymous"


class Users:
    """Checks a client's credentials against the password file and trusted certificates."""

    def __init__(self, passwords: dict[str, PasswordEntry] | None = None,
                 certificates: dict[str, bytes] | None = None):
        self.passwords = passwords or {}
        self.certificates = certificates or {}  # name -> DER bytes

    def check(self, username: str | None, password: str | None,
              certificate: bytes | None) -> Identity | None:
        """The identity, or None when the credentials are wrong (the session is refused).

        `certificate` is the client's certificate (DER): its user certificate, or, for any
        other token, the certificate of its secure channel. A trusted one names the client;
        an untrusted one changes nothing (an anonymous client may still read)."""
        if certificate is not None and username is None:
            for name, der in self.certificates.items():
                if hmac.compare_digest(der, certificate):
                    return Identity(name, "certificate")
        if username is None:
            return Identity(None, "anonymous")
        entry = self.passwords.get(username)
        if entry is None or password is None or not entry.matches(password):
            return None
        return Identity(username, "password")

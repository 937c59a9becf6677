"""Who an OPC UA client is: the plchmi users file (one identity at every door), trusted user
certificates, and the trust list of client applications.

A user signs in with a name and password of the users file (hmi/access: argon2id, the same
lockout and the same roles as every other door), or with a user certificate given by
``--opcua-trust CERT`` — the user named after the file, who must be in the users file too
(their role is theirs there). A client that presents neither is anonymous: a viewer.

Client *applications* (the certificate of a secure channel) are checked against a trust
list, ``$PLCHMI_DATA/opcua/pki/trusted/`` (``plchmi opcua trust CERT`` puts one there); an
unknown one is refused and copied to ``$PLCHMI_DATA/opcua/pki/rejected/`` for review, as
OPC UA servers do.
"""

from __future__ import annotations

import hashlib
import hmac
import os
from dataclasses import dataclass
from pathlib import Path

from hmi.access.signin import Authenticator
from hmi.errors import UsageError
from hmi.paths import data_folder


@dataclass(frozen=True)
class Identity:
    """Who a client is: a named user (password or certificate) with a role, or anonymous."""

    name: str | None
    how: str  # "password", "certificate", "anonymous"
    role: str = "viewer"

    @property
    def label(self) -> str:
        return f"{self.name} ({self.role}, {self.how})" if self.name else "anonymous"


ANONYMOUS = Identity(None, "anonymous", "viewer")


class Users:
    """Checks a client's credentials: the users file's passwords, trusted user
    certificates. The password check is argon2 (about 50 ms): :meth:`check_password` runs
    it in the authenticator's own threads, never on the server's loop."""

    def __init__(self, authenticator: Authenticator | None = None,
                 certificates: dict[str, bytes] | None = None):
        self.authenticator = authenticator
        self.certificates = certificates or {}  # name -> DER bytes

    @property
    def passwords(self) -> bool:
        """Whether names and passwords can sign in (a users file with users)."""
        if self.authenticator is None:
            return False
        found = self.authenticator.users()
        return found is not None and bool(found.users)

    @property
    def any(self) -> bool:
        return self.passwords or bool(self.certificates)

    def count(self) -> int:
        found = self.authenticator.users() if self.authenticator else None
        return (len(found.users) if found else 0) + len(self.certificates)

    async def check_password(self, name: str, password: str
                             ) -> tuple[Identity | None, str, bool]:
        """The identity, or None and why not; whether this attempt locked the account."""
        if self.authenticator is None:
            return None, "no users file: nobody signs in with a password here", False
        result = await self.authenticator.check_async(name, password)
        if not result.accepted or result.user is None:
            return None, result.reason, result.locked_now
        return Identity(name, "password", result.user.role), "", False

    def check_certificate(self, der: bytes) -> tuple[Identity | None, str]:
        """A user certificate: trusted, and its user in the users file (their role)."""
        for name, trusted in self.certificates.items():
            if hmac.compare_digest(trusted, der):
                found = self.authenticator.users() if self.authenticator else None
                user = found.users.get(name) if found else None
                if user is None:
                    return None, (f"the certificate of {name} is trusted, but {name} is not "
                                  "in the users file (plchmi users add)")
                if user.locked:
                    return None, f"the account {name} is locked"
                return Identity(name, "certificate", user.role), ""
        return None, "an untrusted user certificate"


def pki_folder() -> Path:
    return data_folder() / "opcua" / "pki"


def thumbprint(der: bytes) -> str:
    return hashlib.sha1(der).hexdigest()


class TrustList:
    """The client applications trusted on this machine (DER files in `trusted/`); an
    unknown one is copied to `rejected/` (named by its thumbprint) for review."""

    def __init__(self, folder: Path | None = None):
        self.folder = folder or pki_folder()
        self.trusted_folder = self.folder / "trusted"
        self.rejected_folder = self.folder / "rejected"

    def trusted(self) -> set[str]:
        """The thumbprints of the trusted certificates (read again at every check: a
        certificate trusted while the server runs is trusted at once)."""
        found: set[str] = set()
        try:
            names = sorted(os.listdir(self.trusted_folder))
        except OSError:
            return found
        for name in names[:1000]:
            der = _load_der(self.trusted_folder / name)
            if der is not None:
                found.add(thumbprint(der))
        return found

    def check(self, der: bytes) -> bool:
        if thumbprint(der) in self.trusted():
            return True
        try:
            self.rejected_folder.mkdir(parents=True, exist_ok=True)
            target = self.rejected_folder / f"{thumbprint(der)}.der"
            if not target.exists() and len(os.listdir(self.rejected_folder)) < 1000:
                target.write_bytes(der)
        except OSError:
            pass  # the refusal stands; only the copy for review is missing
        return False

    def trust(self, path: Path) -> Path:
        der = certificate_der(path, "plchmi opcua trust")
        self.trusted_folder.mkdir(parents=True, exist_ok=True)
        target = self.trusted_folder / f"{thumbprint(der)}.der"
        target.write_bytes(der)
        rejected = self.rejected_folder / target.name
        if rejected.exists():
            rejected.unlink()
        return target


def _load_der(path: Path) -> bytes | None:
    try:
        return certificate_der(path, "")
    except UsageError:
        return None


def certificate_der(path: Path, what: str) -> bytes:
    """A certificate file (DER or PEM) as DER bytes."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise UsageError(f"{what} {path}: cannot be read ({exc.strerror})") from None
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding
    try:
        cert = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----")
                else x509.load_der_x509_certificate(data))
    except ValueError:
        raise UsageError(f"{what} {path}: not an X.509 certificate (DER or PEM)") from None
    return cert.public_bytes(Encoding.DER)

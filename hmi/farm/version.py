"""The version of plchmi a worker runs: its release and a digest of its code.

Two plchmi installations give the same study results only if they run the same code, so the
release number alone does not pin it (a development checkout changes without a release):
the digest covers every module of the ``hmi`` package and the component library, whose files
a project instantiates from the installation rather than from its own folder.
"""

from __future__ import annotations

import hashlib
import os
import platform
import socket
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from hmi.paths import COMPONENTS

PACKAGE = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class CodeVersion:
    release: str  # plchmi's version (pyproject.toml)
    digest: str  # sha256 of the hmi package's modules and the component library, hex

    def __str__(self) -> str:
        return f"plchmi {self.release} (code {self.digest[:12]})"


@cache
def code_version() -> CodeVersion:
    """This installation's version (computed once per process: a few ms)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        release = version("plchmi")
    except PackageNotFoundError:
        release = "unknown"
    h = hashlib.sha256()
    for root, pattern in ((PACKAGE, "*.py"), (COMPONENTS, "*.yaml")):
        for path in sorted(root.rglob(pattern)):
            h.update(str(path.relative_to(root)).encode())
            h.update(b"\0")
            h.update(path.read_bytes())
            h.update(b"\0")
    return CodeVersion(release, h.hexdigest())


def identity() -> dict[str, str]:
    """What a worker says about itself when asked before any work (plain data)."""
    code = code_version()
    return {"release": code.release, "digest": code.digest, "host": socket.gethostname(),
            "pid": str(os.getpid()), "python": platform.python_version()}

"""Where a project's runtime can be found: its socket and its lock in the project's data
folder (beside its journal), the socket readable and writable by its owner only.

One runtime per project: the runtime holds ``runtime.lock`` (an advisory lock, released by
the kernel whatever ends the process, kill -9 included) and writes its pid there; a socket
left behind by a runtime that died is stale, and the next runtime replaces it.

A Unix socket's path is at most 107 bytes; a longer one (a deep data folder) is reached
through the folder's file descriptor (``/proc/self/fd/N/runtime.sock``, Linux).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from hmi.explain.journal import safe_file_name
from hmi.paths import data_folder

SOCKET = "runtime.sock"
LOCK = "runtime.lock"
LOG = "runtime.log"
MAX_SOCKET_PATH = 100  # bytes; the kernel's limit is 107
TRIES = 20


@dataclass(frozen=True)
class Place:
    folder: Path

    @property
    def socket(self) -> Path:
        return self.folder / SOCKET

    @property
    def lock(self) -> Path:
        return self.folder / LOCK

    @property
    def log(self) -> Path:
        return self.folder / LOG


def place(project_name: str, socket: Path | None = None) -> Place:
    """The runtime's place for a project (`socket`: an explicit socket path instead)."""
    if socket is not None:
        return Place(socket.parent)
    return Place(data_folder() / safe_file_name(project_name))


@contextlib.contextmanager
def socket_address(path: Path) -> Iterator[str]:
    """A path the kernel accepts for `path` (module docstring), valid inside the block."""
    if len(os.fsencode(path)) <= MAX_SOCKET_PATH:
        yield str(path)
        return
    fd = os.open(path.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        yield f"/proc/self/fd/{fd}/{path.name}"
    finally:
        os.close(fd)


class Held(Exception):
    """Another runtime holds the project's lock (its pid, if it wrote it)."""

    def __init__(self, pid: int | None):
        super().__init__(pid)
        self.pid = pid


class RuntimeLock:
    """The project's runtime lock, held for the process's life (module docstring)."""

    def __init__(self, where: Place):
        where.folder.mkdir(parents=True, exist_ok=True)
        self.path = where.lock
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        # (a few tries: a screen looking whether a runtime runs holds it for an instant)
        for attempt in range(TRIES):
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as exc:
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                    os.close(self._fd)
                    raise
                if attempt == TRIES - 1:
                    pid = read_pid(self.path)
                    os.close(self._fd)
                    raise Held(pid) from None
                time.sleep(0.025)
        os.ftruncate(self._fd, 0)
        os.write(self._fd, f"{os.getpid()}\n".encode())

    def release(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def read_pid(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def running(where: Place) -> int | None:
    """The pid of the runtime holding the project's lock, None if none does."""
    try:
        fd = os.open(where.lock, os.O_RDWR)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return read_pid(where.lock) or -1
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)

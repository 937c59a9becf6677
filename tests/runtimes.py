"""A cell's runtime as a real process (``plchmi serve``), for the tests of the split: started,
waited for until it accepts screens (never a fixed sleep), screens attached over its real
socket, and stopped (or killed) at the end."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from hmi.link.base import Identity
from hmi.link.client import AttachError, SocketLink, connect
from hmi.project.kept import fingerprint, load_once

ROOT = Path(__file__).resolve().parent.parent
HANG_GUARD_S = 120.0  # only against a runtime that never comes up (a loaded machine waits)


class RuntimeProcess:
    def __init__(self, project: Path, socket: Path, *options: str, virtual: bool = True,
                 env: dict[str, str] | None = None):
        self.project = project
        self.socket = socket
        command = [sys.executable, "-m", "hmi.cli", "serve", str(project), "--socket",
                   str(socket), *(["--virtual"] if virtual else []), *options]
        self.log = socket.parent / "runtime.test.log"
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log, "wb") as log:
            self.process = subprocess.Popen(command, cwd=ROOT, stdin=subprocess.DEVNULL,
                                            stdout=log, stderr=log,
                                            env={**os.environ, **(env or {})})
        started = time.monotonic()
        while True:
            if self.process.poll() is not None:
                raise AssertionError(f"the runtime ended ({self.process.returncode}): "
                                     f"{self.log.read_text()}")
            with contextlib.suppress(AttachError):
                connect(socket, 1.0).close()
                break
            if time.monotonic() - started > HANG_GUARD_S:
                raise AssertionError(f"the runtime did not come up: {self.log.read_text()}")
            time.sleep(0.02)

    def attach(self, user: str = "alice", role: str = "operator", door: str = "terminal",
               want_control: bool = True, diagnoser: str | None = None) -> SocketLink:
        project = load_once(self.project, diagnoser)
        link = SocketLink(project, self.socket, fingerprint(self.project, diagnoser),
                          Identity(user, role, door, f"{user}-{role}"), want_control)
        assert link.first_frame.wait(HANG_GUARD_S), "no first frame"
        return link

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        return self.process.wait(HANG_GUARD_S)

    def kill(self) -> None:
        self.process.kill()
        self.process.wait(HANG_GUARD_S)

    def output(self) -> str:
        return self.log.read_text()


@contextlib.contextmanager
def runtime(project: Path, socket: Path, *options: str, virtual: bool = True
            ) -> Iterator[RuntimeProcess]:
    process = RuntimeProcess(project, socket, *options, virtual=virtual)
    try:
        yield process
    finally:
        process.stop()


def wait_for(predicate, what: str, guard_s: float = HANG_GUARD_S):
    """Until `predicate()` is truthy (state from another process: no fixed sleep), bounded
    only by a hang guard."""
    started = time.monotonic()
    while True:
        result = predicate()
        if result:
            return result
        if time.monotonic() - started > guard_s:
            raise AssertionError(f"{what} did not happen within {guard_s:g} s (a hang)")
        time.sleep(0.01)

"""`plchmi serve-plant` in a child process: for the bench and the tests, a real server.

The child prints a banner naming the port it listens on (`--port 0` lets the system pick a
free one, so parallel runs never collide), then one line per change of the I/O it serves; a
reader thread keeps every line so that callers can wait for one, with a deadline.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

BANNER_END = "Ctrl-C stops the server."
_SERVING_RE = re.compile(r"^Serving .* on (?P<host>\S+):(?P<port>\d+)$")


class ServerProcess:
    def __init__(self, project: str | Path, extra: Sequence[str] = (), port: int = 0,
                 host: str = "127.0.0.1"):
        self.project = str(project)
        self.extra = list(extra)
        self.port = port
        self.host = host
        self.lines: list[str] = []
        self.proc: subprocess.Popen[str] | None = None
        self._cond = threading.Condition()
        self._reader: threading.Thread | None = None

    def start(self, timeout: float = 30.0) -> int:
        """Start (or restart) the server; return its port once it listens.

        Lines accumulate across restarts: `len(lines)` before a restart marks where the new
        server's lines begin.
        """
        first = len(self.lines)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hmi.cli", "serve-plant", self.project, "--host", self.host,
             "--port", str(self.port), *self.extra],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        self._reader = threading.Thread(target=self._read, args=(self.proc,), daemon=True)
        self._reader.start()
        line = self.wait_for(lambda s: _SERVING_RE.match(s) is not None, timeout, first)
        self.wait_for(BANNER_END, timeout, first)  # the whole banner is in
        match = _SERVING_RE.match(line)
        assert match is not None
        self.port = int(match["port"])
        return self.port

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with self._cond:
                self.lines.append(line.rstrip("\n"))
                self._cond.notify_all()
        with self._cond:
            self._cond.notify_all()

    def wait_for(self, match: str | Callable[[str], bool], timeout: float,
                 start: int = 0) -> str:
        """The first line from index `start` that contains `match` (or satisfies it)."""
        test = (lambda s: match in s) if isinstance(match, str) else match
        deadline = time.monotonic() + timeout
        seen = start
        with self._cond:
            while True:
                for line in self.lines[seen:]:
                    if test(line):
                        return line
                seen = max(seen, len(self.lines))
                left = deadline - time.monotonic()
                exited = self.proc is not None and self.proc.poll() is not None
                if left <= 0 or (exited and not (self._reader and self._reader.is_alive())):
                    tail = "\n".join(self.lines[-15:])
                    why = "the server exited" if exited else f"nothing after {timeout:g} s"
                    raise RuntimeError(f"serve-plant: {why}; waiting for {match!r}; "
                                       f"last lines:\n{tail}")
                self._cond.wait(min(left, 0.5))

    def stop(self, timeout: float = 20.0) -> int:
        """Ctrl-C the server and wait for it to print its summary and exit."""
        if self.proc is None or self.proc.poll() is not None:
            return self.proc.returncode if self.proc else 0
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait()
        if self._reader:
            self._reader.join(5)
        return code

    def kill(self) -> None:
        """Kill the server outright (SIGKILL): a device that vanishes mid-run."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if self._reader:
            self._reader.join(5)

    def __enter__(self) -> ServerProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

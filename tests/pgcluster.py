"""A throwaway PostgreSQL cluster for the tests: initdb in a temporary folder, pg_ctl start on
a Unix socket in that folder (no TCP port), pg_ctl stop and the folder removed at the end.

PostgreSQL refuses to run as root: as root the cluster runs as ``nobody`` (runuser), its
folder given to that user. The binaries are looked for on PATH, then in Debian's
/usr/lib/postgresql/*/bin (Debian's ``postgresql`` package does not put them on PATH);
without them :class:`Unavailable` says why, and the tests that need the cluster are
skipped with that reason (pytest -rs prints it; `.ci/run` installs the package).
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

PORT = 5432  # the socket's name only: the cluster listens on no TCP port


class Unavailable(Exception):
    """No PostgreSQL server can be started here; the message says why."""


def binaries() -> Path:
    found = shutil.which("pg_ctl")
    if found:
        return Path(found).parent
    for folder in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True):
        if (Path(folder) / "pg_ctl").exists():
            return Path(folder)
    raise Unavailable("PostgreSQL's server binaries (initdb, pg_ctl) are not installed "
                      "(Debian: apt-get install postgresql; .ci/run installs it)")


OWNER = "owner.pid"  # in a cluster's folder: the test process that started it


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def stop_orphans(bin: Path, as_user: list[str]) -> list[Path]:
    """Stop and remove the clusters whose test process is gone (killed by a timeout, or a
    worker that crashed: its teardown never ran, and the server would run on for good,
    holding memory on a shared machine). A folder without its owner's pid is being created
    by a live process, or is not ours: left alone. Returns the folders removed."""
    removed = []
    for owner in Path(tempfile.gettempdir()).glob(f"plchmi-pg-*/{OWNER}"):
        try:
            pid = int(owner.read_text())
        except (OSError, ValueError):
            continue
        if _alive(pid):
            continue
        folder = owner.parent
        if (folder / "db" / "postmaster.pid").exists():
            with contextlib.suppress(OSError, subprocess.TimeoutExpired):
                subprocess.run([*as_user, str(bin / "pg_ctl"), "-D", str(folder / "db"), "-m",
                                "immediate", "-w", "stop"], capture_output=True, timeout=60,
                               cwd=folder)
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


class Cluster:
    def __init__(self) -> None:
        self.bin = binaries()
        self.folder = Path(tempfile.mkdtemp(prefix="plchmi-pg-"))
        (self.folder / OWNER).write_text(str(os.getpid()))
        self.data = self.folder / "db"
        self.log = self.folder / "log"
        self.as_user: list[str] = []
        if os.geteuid() == 0:
            if shutil.which("runuser") is None:
                raise Unavailable("running as root without runuser: PostgreSQL refuses to "
                                  "run as root")
            self.as_user = ["runuser", "-u", "nobody", "--"]
            shutil.chown(self.folder, "nobody")
        stop_orphans(self.bin, self.as_user)
        self.started = False

    def _run(self, *args: str, timeout: float = 120) -> None:
        result = subprocess.run([*self.as_user, *args], capture_output=True, text=True,
                                timeout=timeout, cwd=self.folder)
        if result.returncode != 0:
            raise Unavailable(f"{Path(args[0]).name} failed ({result.returncode}): "
                              f"{(result.stderr or result.stdout).strip()[-800:]}")

    def start(self) -> Cluster:
        """Create the cluster (the first time) and start its server."""
        if not self.data.exists():
            try:
                self._run(str(self.bin / "initdb"), "-D", str(self.data), "-U", "plchmi",
                          "-A", "trust", "--no-sync", "-E", "UTF8")
            except BaseException:
                self.stop()
                raise
        options = (f"-k {self.folder} -p {PORT} -c listen_addresses='' -c fsync=off "
                   "-c full_page_writes=off")
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-o", options, "-l",
                  str(self.log), "-w", "-t", "120", "start")
        self.started = True
        return self

    @property
    def url(self) -> str:
        return f"postgresql://plchmi@/postgres?host={self.folder}&port={PORT}"

    def database(self, name: str) -> str:
        """A fresh database in the cluster; its URL."""
        import psycopg
        with psycopg.connect(self.url, autocommit=True) as db:
            db.execute(f'DROP DATABASE IF EXISTS "{name}"')
            db.execute(f'CREATE DATABASE "{name}"')
        return f"postgresql://plchmi@/{name}?host={self.folder}&port={PORT}"

    def kill(self) -> None:
        """The server gone at once (pg_ctl stop -m immediate: no clean shutdown), the
        cluster kept for start()."""
        self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "immediate", "-w",
                  "stop", timeout=60)
        self.started = False

    def stop(self) -> None:
        """The server stopped and the cluster removed."""
        if self.started:
            with contextlib.suppress(Unavailable, subprocess.TimeoutExpired):
                self._run(str(self.bin / "pg_ctl"), "-D", str(self.data), "-m", "immediate",
                          "-w", "stop", timeout=60)
            self.started = False
        shutil.rmtree(self.folder, ignore_errors=True)

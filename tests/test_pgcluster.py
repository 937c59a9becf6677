"""The tests' throwaway PostgreSQL cluster does not outlive a killed test process: the next
cluster started stops it and removes its folder (a server left running holds memory on a
shared machine for good)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.pgcluster import Cluster, Unavailable

STARTER = """
import sys, time
sys.path.insert(0, {tests!r})
from pgcluster import Cluster
cluster = Cluster().start()
print(cluster.folder, flush=True)
sys.stdin.read()  # until the test kills this process: its teardown never runs
"""


def _postmaster(folder: Path) -> int:
    return int((folder / "db" / "postmaster.pid").read_text().splitlines()[0])


def _running(pid: int) -> bool:
    """A process there and not a zombie (this machine's init does not reap the servers
    pg_ctl leaves to it: a stopped one stays as a zombie)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_a_cluster_whose_test_process_was_killed_is_stopped_by_the_next():
    try:
        Cluster().stop()  # (binaries there, and folders creatable)
    except Unavailable as exc:
        pytest.skip(f"no PostgreSQL here: {exc}")
    starter = subprocess.Popen(
        [sys.executable, "-c", STARTER.format(tests=str(Path(__file__).parent))],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        line = starter.stdout.readline().strip() if starter.stdout else ""
        assert line, "the starter printed no folder (it failed)"
        orphan = Path(line)
        server = _postmaster(orphan)
        assert _running(server)
    finally:
        starter.kill()
        starter.wait()
    next_one = Cluster()
    try:
        assert not orphan.exists()
        assert not _running(server)
    finally:
        next_one.stop()


def test_a_living_owners_cluster_is_left_alone():
    try:
        first = Cluster().start()
    except Unavailable as exc:
        pytest.skip(f"no PostgreSQL here: {exc}")
    try:
        second = Cluster()
        try:
            assert (first.data / "postmaster.pid").exists()
            assert _running(_postmaster(first.folder))
        finally:
            second.stop()
    finally:
        first.stop()

"""A killed runtime loses at most its last batch, and nothing it had committed.

A real process (tests/history_child.py: the valve scanning in real time, its historian
writing with the default flush interval of 1 s) is killed with SIGKILL after a few seconds.
Its history is then read back and compared with the same run replayed here in virtual time
(the simulated valve is deterministic, so the replay records exactly the child's samples):

* what the store holds is exactly the replay's samples up to the end of its segment — every
  committed batch whole, nothing half-written, nothing missing before it;
* what was lost is what the child recorded after that: at most one flush interval (1 s)
  plus the commit under way when it died. The figures of each kill are printed (-s).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from hmi.history.catalogue import catalogue
from hmi.history.query import HistoryReader
from hmi.history.recorder import HistoryRecorder, SampleQueue
from hmi.history.target import Target, open_store
from hmi.history.writer import FLUSH_S
from tests.conftest import PROJECTS, make_session

CHILD = Path(__file__).resolve().parent / "history_child.py"
EPOCH = 1_790_000_000_000_000
MARGIN_S = 0.5  # the commit under way and the scheduling of a loaded machine


def _kill_after(target: Target, seconds: float) -> int:
    """Start the child, kill it (SIGKILL) once it has scanned `seconds`; the time of the
    last scan it reported."""
    child = subprocess.Popen([sys.executable, str(CHILD), target.where, str(EPOCH)],
                             stdout=subprocess.PIPE, text=True, bufsize=1)
    last = None
    try:
        assert child.stdout is not None
        for line in child.stdout:
            last = int(line)
            if last - EPOCH >= seconds * 1e6:
                os.kill(child.pid, signal.SIGKILL)
                break
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(30)
    # what the pipe still held: scans the child recorded before it died
    rest = child.stdout.read() if child.stdout else ""
    for line in rest.split():
        last = int(line)
    assert last is not None, "the child never scanned"
    return last


def _replay(until_us: int) -> tuple[list[str], list[tuple[int, int, float]]]:
    session = make_session(PROJECTS / "cispi_valve")
    c = catalogue(session.project, session.engine.layout, True,
                  tuple(session.engine.plant.state()))
    queue = SampleQueue(10**9)
    recorder = HistoryRecorder(c, queue, EPOCH)
    session.scan_listeners.append(recorder.on_scan)
    session.run_for(until_us - EPOCH)
    return [s.name for s in c.signals], queue.take().samples


def _check(target: Target, seconds: float) -> None:
    last = _kill_after(target, seconds)
    reader = HistoryReader(open_store(target, read_only=True), "cispi_valve")
    (segment,) = reader.segments(0, 2**62)
    names, replay = _replay(last)
    got = sorted((names.index(s.name), x.t_us, x.value) for s in reader.signals()
                 for x in reader.store.samples("cispi_valve", s.name, 0, 2**62)
                 if s.name != "scan.time" and s.name != "scan.late")
    measured = {names.index("scan.time"), names.index("scan.late")}
    expected = sorted(x for x in replay if x[1] <= segment.end_us and x[0] not in measured)
    assert got == expected  # every committed batch whole, nothing before it missing
    lost = [x for x in replay if x[1] > segment.end_us and x[0] not in measured]
    lost_s = (last - segment.end_us) / 1e6
    print(f"\n{target.kind}: killed at {(last - EPOCH) / 1e6:.2f} s; history up to "
          f"{(segment.end_us - EPOCH) / 1e6:.2f} s; lost {lost_s:.2f} s of the run, "
          f"{len(lost)} samples (of {len(replay)})")
    assert lost_s <= FLUSH_S + MARGIN_S
    assert got and segment.end_us > EPOCH  # it had committed something


def test_a_killed_runtime_loses_at_most_its_last_batch_sqlite(tmp_path):
    _check(Target("sqlite", str(tmp_path / "h.sqlite")), 4.3)


@pytest.mark.xdist_group("postgres")
def test_a_killed_runtime_loses_at_most_its_last_batch_postgres(postgres):
    _check(Target("postgresql", postgres.database("killed")), 4.7)


@pytest.mark.slow
@pytest.mark.parametrize("seconds", [1.5, 2.05, 3.5, 5.99, 7.25])
def test_kills_at_other_moments(tmp_path, seconds):
    _check(Target("sqlite", str(tmp_path / "h.sqlite")), seconds)

"""When the history cannot be written, the cell goes on and the operator is told.

* A full disk (a real 1 MB tmpfs, mounted here when the machine lets us): the historian's
  alarm is raised, the scans go on with nothing latched, and once space is freed the queued
  samples are written and the alarm clears: nothing is lost.
* A lost PostgreSQL server (the cluster stopped under the writer, then started again): the
  same.
* Longer than the queue holds: the loss is a gap in the history, said as one (two segments;
  nothing is known inside the gap), and what follows starts from known values.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid

import pytest

from hmi.history.historian import KEY, Historian
from hmi.history.query import HistoryReader
from hmi.history.recorder import HistoryRecorder, SampleQueue
from hmi.history.target import Target, open_store
from tests.conftest import PROJECTS, make_session
from tests.pgcluster import Cluster, Unavailable

EPOCH = 1_790_000_000_000_000
WRITER_CYCLE_S = 120.0  # a hang guard only: each wait ends on the writer's cycle


def _alarm(session):
    return next((a for a in session.last.alarms if a.key == KEY), None)


def _run_until(session, historian, condition, limit_s=60):
    """Scan (virtual time, 100 ms at a time) until `condition()`; the writer works in its
    own thread meanwhile, so each step also waits for one of its cycles (its status is
    replaced at the end of each, written or failed): the scans never run ahead of a writer
    slowed by the load."""
    writer = historian.writer
    for _ in range(limit_s * 10):
        session.run_for(100_000)
        with writer._committed:
            before = writer.status
            writer._flush_now.set()
            assert writer._committed.wait_for(lambda before=before: writer.status is not before,
                                              WRITER_CYCLE_S), \
                f"the writer did no cycle in {WRITER_CYCLE_S:g} s"
        if condition():
            return
    raise AssertionError("the condition never came true")


@pytest.fixture
def tiny_disk(tmp_path):
    folder = tmp_path / "tiny"
    folder.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a 1 MB tmpfs (a real full disk) needs root")
    result = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1M", "tmpfs", str(folder)],
                            capture_output=True, text=True)
    if result.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {result.stderr.strip()}")
    yield folder
    subprocess.run(["umount", "-l", str(folder)], check=False)


def test_a_full_disk_raises_the_alarm_and_the_cell_goes_on(tiny_disk):
    session = make_session(PROJECTS / "cispi_valve", control="faulty")
    session.epoch_us = EPOCH
    historian = Historian(session, Target("sqlite", str(tiny_disk / "h.sqlite")),
                          flush_s=0.05).attach()
    reference = HistoryRecorder(historian.catalogue, SampleQueue(10**9), EPOCH)
    session.scan_listeners.append(reference.on_scan)
    _run_until(session, historian, lambda: historian.status.batches > 2)
    _fill(tiny_disk)  # to the last byte
    _run_until(session, historian, lambda: _alarm(session) is not None)
    alarm = _alarm(session)
    assert "disk is full" in alarm.explanation.why and alarm.priority == 3
    scan = session.engine.scan
    session.run_for(5_000_000)  # the cell goes on: scans, nothing latched, no error
    assert session.engine.scan >= scan + 500 and not session.last.snapshot.latched
    assert session.last.error is None
    (tiny_disk / "filler").unlink()
    _run_until(session, historian, lambda: _alarm(session) is None or
               _alarm(session).state == "cleared-unacknowledged")
    historian.close()
    assert historian.status.dropped == 0
    # every sample recorded is in the store, the outage included
    reader = HistoryReader(open_store(historian.target, read_only=True), "cispi_valve")
    names = [s.name for s in historian.catalogue.signals]
    expected = reference.queue.take().samples
    got = [(names.index(n), s.t_us, s.value) for n in names
           for s in reader.store.samples("cispi_valve", n, 0, 2**62)]
    assert sorted(got) == sorted(expected)
    assert len(reader.segments(0, 2**62)) == 1


@pytest.mark.xdist_group("postgres")
def test_a_lost_database_raises_the_alarm_and_nothing_is_lost():
    try:
        cluster = Cluster().start()
    except Unavailable as exc:
        pytest.skip(f"no PostgreSQL here: {exc}")
    try:
        url = cluster.database(f"lost_{uuid.uuid4().hex[:8]}")
        session = make_session(PROJECTS / "cispi_valve")
        session.epoch_us = EPOCH
        historian = Historian(session, Target("postgresql", url), flush_s=0.05).attach()
        reference = HistoryRecorder(historian.catalogue, SampleQueue(10**9), EPOCH)
        session.scan_listeners.append(reference.on_scan)
        _run_until(session, historian, lambda: historian.status.batches > 2)
        cluster.kill()
        _run_until(session, historian, lambda: _alarm(session) is not None)
        assert "cannot be written" in _alarm(session).explanation.why.lower() or \
            "history" in _alarm(session).text.lower()
        session.run_for(10_000_000)
        assert not session.last.snapshot.latched and session.last.error is None
        cluster.start()
        _run_until(session, historian, lambda: historian.status.state == "writing"
                   and _alarm(session).state != "active-unacknowledged")
        historian.close()
        reader = HistoryReader(open_store(historian.target, read_only=True), "cispi_valve")
        names = [s.name for s in historian.catalogue.signals]
        got = [(names.index(n), s.t_us, s.value) for n in names
               for s in reader.store.samples("cispi_valve", n, 0, 2**62)]
        assert sorted(got) == sorted(reference.queue.take().samples)
        assert historian.status.dropped == 0 and historian.status.failures >= 1
    finally:
        cluster.stop()


def _fill(disk) -> None:
    with open(disk / "filler", "wb") as out:
        try:
            while True:
                out.write(b"\0" * 65536)
                out.flush()
        except OSError:
            pass


def test_a_loss_longer_than_the_queue_is_a_gap(tiny_disk):
    """The disk full for longer than the queue holds (400 samples here)."""
    session = make_session(PROJECTS / "cispi_valve")
    session.epoch_us = EPOCH
    historian = Historian(session, Target("sqlite", str(tiny_disk / "h.sqlite")),
                          flush_s=0.05, queue_limit=400).attach()
    _run_until(session, historian, lambda: historian.status.batches > 2)
    _fill(tiny_disk)
    _run_until(session, historian, lambda: historian.queue.dropped > 0)
    session.run_for(20_000_000)
    assert "lost" in _alarm(session).explanation.consequences.lower() or \
        _alarm(session) is not None
    (tiny_disk / "filler").unlink()
    _run_until(session, historian, lambda: historian.status.state == "writing"
               and historian.queue.lost_since is None and historian.status.waiting == 0)
    session.run_for(10_000_000)
    resumed = EPOCH + session.engine.now
    historian.close()
    reader = HistoryReader(open_store(historian.target, read_only=True), "cispi_valve")
    segments = reader.segments(0, 2**62)
    assert len(segments) == 2
    first, second = segments
    assert first.end_us < second.start_us
    inside = (first.end_us + second.start_us) // 2
    assert all(v is None for v in reader.values_at(["fso", "O", "V1.state"], inside).values())
    after = reader.values_at([s.name for s in reader.signals() if s.group == "io"],
                             second.start_us)
    assert all(v is not None for v in after.values())
    assert second.end_us >= resumed - 1_000_000
    assert historian.status.dropped > 0

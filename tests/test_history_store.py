"""The history stores: SQLite and a real PostgreSQL (a throwaway cluster, tests/pgcluster.py)
answer every query with the same rows, and the rows a plain Python model of the recorded
samples gives; retention deletes what it should and nothing else.

One recorded run feeds both: the faulty valve program (the filter corrects it: violations)
with F13 injected (the diagnoser's alarm, a reset), three minutes of virtual time, two
historians on one session (one per back-end) and a third recorder with no store: the
reference stream.
"""

from __future__ import annotations

import io
from bisect import bisect_right
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.engine.commands import Acknowledge, FaultReset, RepairFaults
from hmi.history.catalogue import catalogue
from hmi.history.historian import Historian
from hmi.history.query import HistoryReader, write_csv
from hmi.history.recorder import HistoryRecorder, SampleQueue
from hmi.history.store import Batch, Event
from hmi.history.target import Target, open_store
from hmi.session.runio import open_journal
from tests.conftest import PROJECTS, make_session

EPOCH = 1_790_000_000_000_000  # 2026-09-21, a fixed wall time for the run's time 0
RUN_US = 180_000_000

pytestmark = pytest.mark.xdist_group("postgres")


@dataclass
class Recorded:
    readers: dict[str, HistoryReader]
    reference: list[tuple[str, int, float]]  # (signal, t, value), as recorded
    names: list[str]
    start: int
    end: int


def record(targets: dict[str, Target], journal_path) -> Recorded:
    session = make_session(PROJECTS / "cispi_valve", control="faulty", inject=["F13@40s"])
    session.epoch_us = EPOCH
    journal = open_journal(session, journal_path, "test")
    historians = {kind: Historian(session, target, source="test", flush_s=0.05,
                                  journal=journal).attach()
                  for kind, target in targets.items()}
    first = next(iter(historians.values()))
    queue = SampleQueue(10**9)
    reference = HistoryRecorder(first.catalogue, queue, EPOCH)
    session.scan_listeners.append(reference.on_scan)
    session.run_for(100_000_000)
    session.command(Acknowledge(None))
    session.command(RepairFaults())
    session.command(FaultReset())
    session.run_for(RUN_US - 100_000_000)
    journal.close()
    for historian in historians.values():
        historian.close()
        assert historian.status.failures == 0 and historian.status.dropped == 0
    taken = queue.take()
    names = [s.name for s in first.catalogue.signals]
    readers = {kind: HistoryReader(open_store(target, read_only=True), "cispi_valve")
               for kind, target in targets.items()}
    return Recorded(readers, [(names[i], t, v) for i, t, v in taken.samples], names,
                    EPOCH, EPOCH + session.engine.now)


@pytest.fixture(scope="module")
def recorded(postgres, tmp_path_factory):
    url = postgres.database("same_rows")
    folder = tmp_path_factory.mktemp("history")
    return record({"sqlite": Target("sqlite", str(folder / "h.sqlite")),
                   "postgresql": Target("postgresql", url)}, folder / "journal.jsonl")


def _series(recorded: Recorded, name: str) -> list[tuple[int, float]]:
    return [(t, v) for n, t, v in recorded.reference if n == name]


def test_both_stores_hold_what_was_recorded(recorded):
    sqlite, pg = recorded.readers["sqlite"], recorded.readers["postgresql"]
    assert [s.name for s in sqlite.signals()] == [s.name for s in pg.signals()] == recorded.names
    assert sqlite.signals() == pg.signals()
    assert sqlite.span() == pg.span() == (recorded.start, recorded.end)
    for name in recorded.names:
        expected = _series(recorded, name)
        for reader in (sqlite, pg):
            got = [(s.t_us, s.value) for s in reader.store.samples(
                "cispi_valve", name, recorded.start - 1, recorded.end)]
            assert got == expected, (name, reader.store.where)
    # the run had what the trends show: violations, the diagnoser's fault, actions
    assert any(v for n, _, v in recorded.reference if n == "CSs1")
    assert len({v for n, _, v in recorded.reference if n == "V1.state"}) > 3
    events = sqlite.events(recorded.start, recorded.end)
    assert events == pg.events(recorded.start, recorded.end)
    kinds = {(e.type, e.event) for e in events}
    assert ("alarm", "raised") in kinds and ("alarm", "acknowledged") in kinds
    assert any(e.type == "action" and e.event.startswith("fault reset") for e in events)


def test_the_csv_export_is_the_same(recorded):
    texts = []
    for reader in recorded.readers.values():
        out = io.StringIO()
        write_csv(reader, ["fso", "C", "V1.state", "O.travel", "CSs1"], recorded.start,
                  recorded.end, out)
        texts.append(out.getvalue())
    assert texts[0] == texts[1]
    rows = texts[0].splitlines()
    assert rows[0] == "time,fso,C,V1.state,O.travel,CSs1"
    assert len(rows) > 20


def _reference_value(recorded: Recorded, name: str, t: int) -> float | None:
    series = _series(recorded, name)
    k = bisect_right(series, (t, float("inf")))
    if not recorded.start <= t <= recorded.end or k == 0:
        return None
    return series[k - 1][1]


def _reference_buckets(recorded: Recorded, name: str, start: int, end: int, n: int):
    span = end - start
    found: dict[int, list[float]] = {}
    for t, v in _series(recorded, name):
        if start < t <= end:
            c = ((t - start) * n + span - 1) // span - 1
            found.setdefault(c, []).append(v)
    return [(c, len(vs), min(vs), max(vs), vs[-1]) for c, vs in sorted(found.items())]


@settings(max_examples=40)
@given(st.data())
def test_random_windows_give_the_same_rows(recorded, data):
    """Any window, any width: both stores and the model of the recorded stream agree on the
    samples, the value at an instant, and the columns of a drawing."""
    sqlite, pg = recorded.readers["sqlite"], recorded.readers["postgresql"]
    name = data.draw(st.sampled_from(recorded.names))
    lo, hi = recorded.start - 5_000_000, recorded.end + 5_000_000
    a = data.draw(st.integers(lo, hi))
    b = data.draw(st.integers(a + 1, hi + 1))
    width = data.draw(st.integers(1, 300))
    expected = [(t, v) for t, v in _series(recorded, name) if a < t <= b]
    for reader in (sqlite, pg):
        store = reader.store
        assert [(s.t_us, s.value) for s in store.samples("cispi_valve", name, a, b)] == \
            expected
        assert [(x.column, x.count, x.low, x.high, x.last)
                for x in store.buckets("cispi_valve", name, a, b, width)] == \
            _reference_buckets(recorded, name, a, b, width)
        assert reader.value_at(name, b) == _reference_value(recorded, name, b)
    assert sqlite.window([name], a, b, width) == pg.window([name], a, b, width)


def _batch(samples, events=(), segment=None, covered=None):
    return Batch(list(samples), list(events), segment, covered)


DAY = 86_400_000_000


def _month_store(target: Target):
    """Three months of a cell's history written straight through the store: two signals,
    one sample an hour, two segments (a stop of a day in the middle), an event a day."""
    store = open_store(target)
    from hmi.engine.layout import Layout
    from hmi.project.loader import load_project
    project = load_project(PROJECTS / "cispi_valve")
    cat = catalogue(project, Layout.build(project, project.control()))
    ids = [i for i, _ in store.prepare("cell", cat.signals)]
    start = 1_785_542_400_000_000  # 2026-08-01 00:00 UTC
    middle = start + 45 * DAY
    for first, last in ((start, middle), (middle + DAY, start + 92 * DAY)):
        segment = store.begin_segment("cell", first, "test", "real")
        hours = range(first, last + 1, 3_600_000_000)
        samples = [(ids[0], t, float(k % 2)) for k, t in enumerate(hours)]
        samples += [(ids[3], t, float(k % 5 == 0)) for k, t in enumerate(hours)]
        events = [Event(t, "alarm", "raised", "k", "high", "x", "", {"n": k})
                  for k, t in enumerate(range(first, last, DAY))]
        for chunk in range(0, len(samples), 500):
            store.write("cell", _batch(samples[chunk:chunk + 500], segment=segment,
                                       covered=max(t for _, t, _ in samples[chunk:chunk + 500])))
        store.write("cell", _batch([], events, segment, last))
    return store, cat, start


@pytest.mark.parametrize("kind", ["sqlite", "postgresql"])
def test_retention_deletes_what_it_should_and_nothing_else(kind, postgres, tmp_path):
    target = Target("sqlite", str(tmp_path / "r.sqlite")) if kind == "sqlite" else \
        Target("postgresql", postgres.database("retention"))
    store, cat, start = _month_store(target)
    reader = HistoryReader(store, "cell")
    names = [cat.signals[0].name, cat.signals[3].name]
    end = start + 92 * DAY
    grid = range(start, end + DAY, DAY // 7)
    cutoffs = [start + 20 * DAY + 12_345, start + 45 * DAY + 3 * 3_600_000_000 // 2]
    before = {(n, t): reader.value_at(n, t) for n in names for t in grid}
    rows_before = {n: store.samples("cell", n, start - 1, end) for n in names}
    events_before = store.events("cell", start - 1, end)
    partitions = _partitions(store) if kind == "postgresql" else None
    for cutoff in cutoffs:
        store.delete_before("cell", cutoff)
        for n in names:
            rows = store.samples("cell", n, start - 1, end)
            assert all(s.t_us >= cutoff for s in rows)  # nothing older is left
            kept = [s for s in rows_before[n] if s.t_us >= cutoff]
            # nothing newer is gone; at most one sample added, at the cutoff itself
            assert [s for s in rows if s.t_us > cutoff or s in kept] == kept
            assert len(rows) - len(kept) <= 1
            for t in grid:
                if t >= cutoff:
                    assert reader.value_at(n, t) == before[(n, t)], (n, t, cutoff)
                else:
                    assert reader.value_at(n, t) is None
        assert store.events("cell", start - 1, end) == \
            [e for e in events_before if e.t_us >= cutoff]
        assert reader.span() is not None and reader.span()[0] >= cutoff
    if kind == "postgresql":
        # August's partition held nothing any more after the second cutoff (mid-September):
        # dropped; September's, still partly in use, kept
        left = _partitions(store)
        assert "plchmi_samples_2026_08" in partitions and "plchmi_samples_2026_08" not in left
        assert "plchmi_samples_2026_09" in left
    store.close()


def _partitions(store) -> set[str]:
    return {r[0] for r in store.db.execute(
        "SELECT c.relname FROM pg_inherits i JOIN pg_class c ON c.oid = i.inhrelid")}


def test_a_reader_cannot_write(recorded):
    from hmi.history.store import StoreError
    for reader in recorded.readers.values():
        with pytest.raises(StoreError):
            reader.store.delete_before("cispi_valve", recorded.end)


@pytest.mark.parametrize("clock", ["right", "years ahead"])
def test_the_writer_counts_retention_back_from_the_history_when_the_clock_is_ahead(
        clock, tmp_path):
    """The writer's retention: 30 days back from the wall clock when the history is up to
    date; from the history's newest instant when the clock is far ahead of it (a clock set
    wrong, a history on a fixed time axis) — never the whole history wiped."""
    from dataclasses import replace

    from hmi.history.writer import HistoryWriter
    target = Target("sqlite", str(tmp_path / "w.sqlite"))
    store, cat, _ = _month_store(target)
    end = store.span("cell")[1]
    store.close()
    wall_us = end + 3_600_000_000 if clock == "right" else end + 5 * 365 * DAY
    writer = HistoryWriter(target, replace(cat, cell="cell"), SampleQueue(100), source="test",
                           clock="real", retention_us=30 * DAY, wall=lambda: wall_us / 1e6)
    writer.start()
    writer.stop()  # its first cycle (nothing queued) runs retention; stop waits for it
    assert writer.status.state == "stopped"
    reader = HistoryReader(open_store(target, read_only=True), "cell")
    first, last = reader.span()
    assert last == end
    newest = min(wall_us, end)
    assert newest - 30 * DAY <= first < newest - 29 * DAY  # the last 30 days are all kept
    assert writer.status.deleted > 0

"""The historian's flush: once it returns True, everything queued before it was asked is in
the store, even when a batch was already being written at that moment (that batch was taken
before, and cannot answer for what came after its take)."""

from __future__ import annotations

import threading
import time

from hmi.engine.layout import Layout
from hmi.history.catalogue import catalogue
from hmi.history.query import HistoryReader
from hmi.history.recorder import SampleQueue
from hmi.history.store import Event
from hmi.history.target import Target, open_store
from hmi.history.writer import HistoryWriter
from hmi.project.loader import load_project
from tests.conftest import PROJECTS

GUARD_S = 30.0  # against a hang only; the steps below wait on state


def _event(t_us: int, text: str) -> Event:
    return Event(t_us, "action", text, "", "", text, "", {"t": t_us})


def _until(condition, what: str) -> None:
    started = time.monotonic()
    while not condition():
        assert time.monotonic() - started < GUARD_S, f"never: {what}"
        time.sleep(0.001)


def test_a_flush_during_a_write_waits_for_what_came_after_its_take(tmp_path, monkeypatch):
    project = load_project(PROJECTS / "cispi_valve")
    target = Target("sqlite", str(tmp_path / "h.sqlite"))
    queue = SampleQueue(1000)
    writer = HistoryWriter(target, catalogue(project, Layout.build(project, project.control())),
                           queue, source="test", clock="virtual", flush_s=3600.0)
    committed: list[str] = []
    in_first = threading.Event()
    release_first = threading.Event()
    flush_returned = threading.Event()
    real_write = writer._write
    writes = 0

    def write(store, taken):
        nonlocal writes
        writes += 1
        if writes == 1:  # the batch in flight when the flush is asked
            in_first.set()
            release_first.wait(GUARD_S)
        elif not flush_returned.is_set():
            # the next batch holds back until the flush has answered (or a while): a flush
            # that answered on the first batch is then caught, not raced
            flush_returned.wait(0.5)
        real_write(store, taken)
        committed.extend(e.text for e in taken.events)

    monkeypatch.setattr(writer, "_write", write)
    queue.put([], 1_000_000)
    queue.add_event(_event(1_000_000, "before"))
    writer.start()  # its first cycle takes "before" and holds in the write
    try:
        _until(in_first.is_set, "the first batch being written")
        queue.put([], 2_000_000)
        queue.add_event(_event(2_000_000, "during"))  # after the first batch's take
        answer: list[tuple[bool, list[str]]] = []

        def flush() -> None:
            ok = writer.flush(GUARD_S)
            answer.append((ok, list(committed)))
            flush_returned.set()

        asker = threading.Thread(target=flush)
        asker.start()
        _until(writer._flush_now.is_set, "the flush asked")
        release_first.set()
        asker.join(GUARD_S)
        ok, seen = answer[0]
        assert ok
        assert seen == ["before", "during"]
    finally:
        release_first.set()
        writer.stop()
    reader = HistoryReader(open_store(target, read_only=True), project.name)
    assert [e.text for e in reader.events(0, 3_000_000)] == ["before", "during"]

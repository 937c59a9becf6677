"""``plchmi bench history``: what the historian costs the cell, and what reading it costs.

Four figures, each against the issue's goal:

- **scan jitter** of the CISPI valve at a 10 ms scan against the wall clock (a LiveRunner
  thread, as in the HMI), without and with the historian recording into SQLite, in four
  alternating rounds of each (the machine's load moves between them), pooled: p99 with it
  within 5 % of without;
- **the cost in the scan** and **the database's size**: the valve run in virtual time (as fast
  as it goes) for 24 h of the cell (``--quick``: 1 h) with the historian, its scan listener
  timed at every scan (a histogram of 100 ns bins), then the file's size on disk (the
  database, its WAL and shared memory files): under 50 MB for 24 h; and an hour run without
  and with the historian: the time per scan of each (the recorder in the scan plus the
  writer thread's share of the interpreter);
- **a 24-hour trend of 4 signals**, read and drawn as the trend screen does (the history's
  signals and extent, the store's per-column summaries, the drawing) at 80 and 160 columns:
  under 200 ms;
- **OPC UA HistoryRead** (ReadRaw) of 1 h of one variable, by an asyncua client of a server
  serving that history: under 500 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hmi.bench import goal_line, load_line, percentile

if TYPE_CHECKING:
    from asyncua import ua
    from asyncua.client.client import Client

    from hmi.session.session import Session
    from hmi.session.view import CellView

SECTION = "history"
HELP = ("historian: scan jitter p99 with/without at 10 ms, its cost per scan, SQLite size of "
        "24 h of the valve, a 24 h trend of 4 signals drawn, OPC UA HistoryRead of 1 h")

PERIOD_US = 10_000
HOUR_US = 3_600_000_000
JITTER_S, QUICK_JITTER_S = 10.0, 3.0  # per round
ROUNDS, QUICK_ROUNDS = 4, 2  # of each set-up, alternating (the load drifts meanwhile)
HOURS, QUICK_HOURS = 24, 1
TREND_SIGNALS = ("O", "fso", "V1.state", "O.travel")
TREND_SIZES = ((80, 24), (160, 48))
REPEATS = 5
BIN_NS = 100  # the scan listener's histogram
BINS = 20_000  # up to 2 ms; longer ones counted in the last


def _session() -> Session:
    from hmi.bench.ui import valve_session
    return valve_session(PERIOD_US)


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in (path, Path(f"{path}-wal"), Path(f"{path}-shm"))
               if p.exists())


# -- jitter, live ------------------------------------------------------------------------------
def jitter_round(seconds: float, folder: Path | None) -> dict[str, Any]:
    """The live scan loop for `seconds`, with a historian into `folder` (None: without)."""
    from hmi.bench.ui import SETTLE_S
    from hmi.history.historian import Historian
    from hmi.history.target import Target
    from hmi.session.live import BENCH_JITTER, LiveRunner

    session = _session()
    historian = None
    if folder is not None:
        historian = Historian(session, Target("sqlite", str(folder / "live.sqlite")),
                              source="bench").attach()
    runner = LiveRunner(session, keep_jitter=BENCH_JITTER)
    runner.start()
    try:
        time.sleep(SETTLE_S)
        samples0, scans0, overruns0 = len(runner.jitter_us), session.engine.scan, \
            runner.overruns
        start = time.perf_counter()
        time.sleep(seconds)  # the measurement: the runner paces by the wall clock
        elapsed = time.perf_counter() - start
        result = {"jitter": list(runner.jitter_us)[samples0:], "elapsed": elapsed,
                  "scans": session.engine.scan - scans0,
                  "overruns": runner.overruns - overruns0}
    finally:
        runner.stop()
        if historian is not None:
            historian.close()
            result["written"] = historian.status.written
    return result


def jitter(seconds: float, rounds: int) -> list[str]:
    from hmi.bench.ui import jitter_line

    pooled: dict[bool, list[float]] = {False: [], True: []}
    out = []
    with tempfile.TemporaryDirectory(prefix="plchmi-bench-history-") as tmp:
        for round_ in range(rounds):
            for on in (False, True):
                folder = Path(tmp) / str(round_)
                folder.mkdir(exist_ok=True)
                r = jitter_round(seconds, folder if on else None)
                pooled[on] += r["jitter"]
                label = "history" if on else "off"
                line = jitter_line(label, r["jitter"], r["scans"], r["elapsed"], PERIOD_US,
                                   r["overruns"])
                if on:
                    line += f"  ({r['written']} samples written)"
                out.append(line)
    p99_off, p99_on = percentile(pooled[False], 99), percentile(pooled[True], 99)
    out.append(f"  jitter p99 pooled: off {p99_off:.0f} us, with the historian {p99_on:.0f} us "
               f"({p99_on / p99_off:.3f}x); " + goal_line(p99_on / p99_off, 1.05, "x off", False))
    return out


# -- recording, virtual time -------------------------------------------------------------------
def record(length_us: int, path: Path) -> dict[str, Any]:
    """The valve for `length_us` of virtual time, recorded into `path`, the scan listener
    timed."""
    from hmi.history.historian import Historian
    from hmi.history.target import Target

    session = _session()
    historian = Historian(session, Target("sqlite", str(path)), source="bench",
                          run_us=length_us).attach()
    bins = [0] * BINS
    worst = 0
    clock = time.perf_counter_ns
    inner = historian.on_scan

    def timed(cell: CellView) -> None:
        nonlocal worst
        t0 = clock()
        inner(cell)
        spent = clock() - t0
        bins[min(BINS - 1, spent // BIN_NS)] += 1
        if spent > worst:
            worst = spent

    listeners = session.scan_listeners
    listeners[listeners.index(historian.on_scan)] = timed
    start = time.perf_counter()
    done = 0
    while done < length_us:  # an hour at a time: the writer's queue is emptied meanwhile
        step = min(HOUR_US, length_us - done)
        session.run_for(step)
        done += step
    elapsed = time.perf_counter() - start
    listeners[listeners.index(timed)] = historian.on_scan
    historian.close(timeout=120)
    status = historian.status
    return {"scans": session.engine.scan, "elapsed": elapsed, "bins": bins, "worst": worst,
            "written": status.written, "dropped": status.dropped, "batches": status.batches}


def _bin_percentile(bins: list[int], p: float) -> float:
    """The p-th percentile of the histogram, in microseconds (a bin's upper edge)."""
    total = sum(bins)
    rank = max(1, round(p / 100 * total + 0.5))
    seen = 0
    for k, count in enumerate(bins):
        seen += count
        if seen >= rank:
            return (k + 1) * BIN_NS / 1000
    return len(bins) * BIN_NS / 1000


def bare_run(hours: int, folder: Path | None) -> float:
    """Seconds per scan of `hours` of the valve in virtual time, with a historian into
    `folder` or without (None)."""
    from hmi.history.historian import Historian
    from hmi.history.target import Target

    session = _session()
    historian = None
    if folder is not None:
        historian = Historian(session, Target("sqlite", str(folder / "bare.sqlite")),
                              source="bench", run_us=hours * HOUR_US).attach()
    start = time.perf_counter()
    session.run_for(hours * HOUR_US)
    elapsed = time.perf_counter() - start
    if historian is not None:
        historian.close(timeout=120)
    per_scan: float = elapsed / max(1, session.engine.scan)
    return per_scan


def recording(hours: int, path: Path) -> list[str]:
    r = record(hours * HOUR_US, path)
    bins = r["bins"]
    mean = sum((k + 0.5) * BIN_NS * c for k, c in enumerate(bins)) / max(1, sum(bins)) / 1000
    size = _size(path)
    per_hour = size / hours
    out = [f"  recorded {hours} h of the valve (virtual time, {r['scans']:,} scans) in "
           f"{r['elapsed']:.0f} s: {r['written']:,} samples and events in {r['batches']} "
           f"batches, {r['dropped']} dropped",
           f"  scan listener (the recorder, in the scan): p50 {_bin_percentile(bins, 50):.1f} "
           f"us  p99 {_bin_percentile(bins, 99):.1f} us  mean {mean:.1f} us  max "
           f"{r['worst'] / 1000:.0f} us a scan",
           f"  SQLite on disk: {size / 1e6:.1f} MB ({per_hour / 1e6:.2f} MB an hour, "
           f"{size / max(1, r['written']):.0f} bytes a sample); 24 h: "
           f"{per_hour * 24 / 1e6:.1f} MB"
           + ("" if hours == 24 else " (from this run's rate)") + "; "
           + goal_line(per_hour * 24 / 1e6, 50, "MB", False)]
    with tempfile.TemporaryDirectory(prefix="plchmi-bench-history-") as tmp:
        off = bare_run(1, None)
        on = bare_run(1, Path(tmp))
    out.append(f"  1 h of the valve in virtual time: {off * 1e6:.1f} us a scan without the "
               f"historian, {on * 1e6:.1f} us with it (+{(on - off) * 1e6:.1f} us: the "
               "recorder and the writer thread, one interpreter)")
    return out


# -- reading -----------------------------------------------------------------------------------
def trend(path: Path) -> list[str]:
    """A 24-hour trend of TREND_SIGNALS, read and drawn as the trend screen does."""
    from hmi.history.query import HistoryReader
    from hmi.history.target import Target, open_store
    from hmi.ui.trend import draw, plot_width

    reader = HistoryReader(open_store(Target("sqlite", str(path)), read_only=True),
                           "cispi_valve")
    out = []
    try:
        extent = reader.span()
        if extent is None:
            return ["  trend: the history is empty"]
        end = extent[1]
        start = end - 24 * HOUR_US
        for width, height in TREND_SIZES:
            times, read_times, cpu_times = [], [], []
            columns = plot_width(width)
            samples = sum(len(reader.store.samples("cispi_valve", name, start, end))
                          for name in TREND_SIGNALS)
            for _ in range(REPEATS):
                c0, t0 = time.process_time(), time.perf_counter()
                reader.signals()
                reader.span()
                window = reader.window(TREND_SIGNALS, start, end, columns)
                t1 = time.perf_counter()
                draw(window, columns - 1, height - 6)
                t2, c2 = time.perf_counter(), time.process_time()
                times.append(t2 - t0)
                read_times.append(t1 - t0)
                cpu_times.append(c2 - c0)
            worst = max(times) * 1000
            held = (end - extent[0]) / HOUR_US
            out.append(f"  24 h trend of {len(TREND_SIGNALS)} signals ({samples:,} samples"
                       + (f"; the history holds {held:.2g} h" if held < 24 else "") + ") at "
                       f"{width}x{height} ({columns} columns): median "
                       f"{statistics.median(times) * 1000:.0f} ms (read "
                       f"{statistics.median(read_times) * 1000:.0f} ms; CPU "
                       f"{statistics.median(cpu_times) * 1000:.0f} ms), first "
                       f"{times[0] * 1000:.0f} ms, max {worst:.0f} ms of {REPEATS}; "
                       + goal_line(worst, 200, "ms", False))
    finally:
        reader.store.close()
    return out


def history_read(path: Path) -> list[str]:
    """ReadRaw of the last hour of the busiest served variable, by an asyncua client."""
    from hmi.errors import UsageError
    from hmi.opcua import require
    try:
        require()
    except UsageError as exc:
        return [f"  HistoryRead not measured: {exc}"]
    import logging

    from asyncua.client.client import Client

    from hmi.bench.opcua import _free_port
    from hmi.history.query import HistoryReader
    from hmi.history.target import Target, open_store
    from hmi.opcua.server import CellServer, ServeOptions
    from hmi.session.session import settle_memory

    logging.getLogger("asyncua").setLevel(logging.ERROR)  # its session timeout notice
    target = Target("sqlite", str(path))
    reader = HistoryReader(open_store(target, read_only=True), "cispi_valve")
    extent = reader.span()
    if extent is None:
        reader.store.close()
        return ["  HistoryRead: the history is empty"]
    end = extent[1]
    start = end - HOUR_US
    server = CellServer(_session(), ServeOptions(port=_free_port()), history=target)
    server.start()  # raises if it cannot serve
    settle_memory()  # as the gateway does once its address space is built
    try:
        if server.storage is None:
            return ["  HistoryRead not measured: the server serves no history"]
        counts = {node: len(reader.store.samples("cispi_valve", h.signal, start, end))
                  for node, h in server.storage.nodes.items()}
        node_id = max(counts, key=lambda n: counts[n])
        signal = server.storage.nodes[node_id].signal
        reader.store.close()
        times, cpu, got = asyncio.run(_read_raw(Client, server.url, node_id, start, end))
    finally:
        server.stop()
    worst = max(times) * 1000
    return [f"  HistoryRead (ReadRaw) of 1 h of {signal} ({got} values, asyncua client, same "
            f"process): median {statistics.median(times) * 1000:.0f} ms (CPU of client and "
            f"server {statistics.median(cpu) * 1000:.0f} ms), first {times[0] * 1000:.0f} ms, "
            f"max {worst:.0f} ms of {REPEATS}; " + goal_line(worst, 500, "ms", False)]


async def _read_raw(client_type: type[Client], url: str, node_id: ua.NodeId, start_us: int,
                    end_us: int) -> tuple[list[float], list[float], int]:
    from datetime import UTC, datetime, timedelta
    epoch = datetime(1970, 1, 1, tzinfo=UTC)
    start = epoch + timedelta(microseconds=start_us)
    end = epoch + timedelta(microseconds=end_us)
    times: list[float] = []
    cpu: list[float] = []
    got = 0
    async with client_type(url, timeout=60) as client:
        node = client.get_node(node_id)
        for _ in range(REPEATS):
            c0, t0 = time.process_time(), time.perf_counter()
            values = await node.read_raw_history(start, end)  # follows continuation points
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            got = len(values)
    return times, cpu, got


def run(args: argparse.Namespace) -> None:
    quick = getattr(args, "quick", False)
    hours = QUICK_HOURS if quick else HOURS
    print(f"  cispi_valve, scan period {PERIOD_US // 1000} ms, SQLite; {load_line()}",
          flush=True)
    for line in jitter(*((QUICK_JITTER_S, QUICK_ROUNDS) if quick else (JITTER_S, ROUNDS))):
        print(line, flush=True)
    with tempfile.TemporaryDirectory(prefix="plchmi-bench-history-") as tmp:
        path = Path(tmp) / "history.sqlite"
        parts: tuple[Callable[[], list[str]], ...] = (
            lambda: recording(hours, path), lambda: trend(path), lambda: history_read(path))
        for part in parts:
            for line in part():
                print(line, flush=True)

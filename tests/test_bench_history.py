"""`plchmi bench history`: each part measures what it says, on a real SQLite history and a
real OPC UA server (figures are never asserted: speed is measured by the bench)."""

from __future__ import annotations

import re

from hmi.bench.history import BIN_NS, _bin_percentile, history_read, record, trend
from hmi.history.query import HistoryReader
from hmi.history.target import Target, open_store


def test_the_histogram_percentiles_are_bin_edges():
    bins = [0] * 10
    bins[2], bins[7] = 98, 2  # 98 scans in 200-300 ns, 2 in 700-800 ns
    assert _bin_percentile(bins, 50) == 3 * BIN_NS / 1000
    assert _bin_percentile(bins, 98) == 3 * BIN_NS / 1000
    assert _bin_percentile(bins, 99) == 8 * BIN_NS / 1000


def test_a_recorded_run_times_every_scan_and_is_read_back(tmp_path):
    path = tmp_path / "history.sqlite"
    r = record(90_000_000, path)  # 90 s of the valve
    assert sum(r["bins"]) == r["scans"]  # the listener was timed at every scan
    assert r["dropped"] == 0
    reader = HistoryReader(open_store(Target("sqlite", str(path)), read_only=True),
                           "cispi_valve")
    try:
        extent = reader.span()
        assert extent is not None and extent[1] - extent[0] >= 89_000_000
        assert reader.store.samples("cispi_valve", "fso", extent[0] - 1, extent[1])
    finally:
        reader.store.close()
    lines = trend(path)
    assert len(lines) == 2 and all(re.search(r"median \d+ ms", line) for line in lines)
    read = history_read(path)
    assert len(read) == 1
    got = re.search(r"\((\d+) values", read[0])
    assert got and int(got.group(1)) > 0, read[0]  # a real answer, read by a real client

"""`plchmi bench opcua` measures what it says: a client in another process subscribed to
every variable, and the latency of each notified scan (no figure is asserted: speed is the
bench's business, not a test's)."""

from __future__ import annotations

import pytest

pytest.importorskip("asyncua", reason="the [opcua] extra is not installed")

from hmi.bench.opcua import measure
from hmi.bench.ui import PROJECT
from hmi.opcua.model import build_model
from hmi.project.loader import load_project


def test_the_bench_client_subscribes_to_every_variable_and_times_the_scans():
    result = measure(0.5, server=True, client=True)  # 50 scans at 10 ms: notified, timed
    project = load_project(PROJECT)
    from hmi.engine.scan import Engine
    from hmi.plant.sim.plant import SimPlant
    points = build_model(project, Engine(project, SimPlant(project)).layout).points
    assert result["monitored"] == len(points) + 1  # and Status/RunState, the session's
    assert result["scans"] > 0 and result["jitter"]
    assert result["lags"], "no scan count notification reached the client"
    assert all(lag > 0 for lag in result["lags"])  # notified after the scan ended
    assert result["notifications"] >= len(result["lags"])


def test_the_bench_measures_the_scans_of_the_live_hmi():
    """The HMI's runner keeps no lateness samples of its own (a runtime's are in constant
    memory): the comparison line once said "no scan was measured" at every run."""
    from hmi.bench.ui import with_ui
    line = with_ui(0.5)[0]  # 50 scans at 10 ms beside the live app
    assert "no scan was measured" not in line and "scans in" in line, line

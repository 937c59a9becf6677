"""``plchmi bench opcua``: what serving the cell over OPC UA costs the scan.

The CISPI valve scans every 10 ms against the wall clock (a LiveRunner thread, as in the HMI
and in ``plchmi run --opcua``), in four set-ups of equal length:

- ``no server``: the scan loop alone (the baseline);
- ``server``: the OPC UA server running, no client;
- ``+client``: a client in another process subscribed to every variable of the cell (at
  the cell's 10 ms) and to the alarm events: the worst a SCADA asks;
- ``HMI``: the Textual HMI instead (``bench ui``'s set-up): the figure to stay within.

For each: scan jitter (how late each scan started against its schedule, p50/p99/max), the
overruns, and the scan time (the scan's own duration, which the server's thread can stretch:
one process, one GIL). With the client: the publishing latency, from the end of a scan to
the client's notification of that scan's ScanCount (both clocks are the machine's monotonic
clock), and the notifications per second. ``--quick`` shortens every set-up.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any

from hmi.bench import percentile
from hmi.bench.ui import PERIOD_US, PROJECT, SETTLE_S, jitter_line, valve_session, with_ui

if TYPE_CHECKING:
    from hmi.session.view import CellView

SECTION = "opcua"
HELP = ("OPC UA server at a 10 ms scan: jitter and scan time without/with the server and a "
        "client subscribed to everything, vs the HMI; publishing latency")

SECONDS, QUICK_SECONDS = 20.0, 4.0
CLIENT_READY_S = 60.0

# The client, run in its own process as a SCADA would be: subscribes to every variable and
# to the events, says "ready", then records each ScanCount notification for `seconds`.
CLIENT = r"""
import asyncio, json, sys, time
from asyncua import Client, ua

async def main(url, seconds):
    async with Client(url, timeout=30) as c:
        ns = await c.get_namespace_index("urn:plchmi:" + sys.argv[3])
        cell = await c.nodes.objects.get_child(f"{ns}:{sys.argv[3]}")
        variables, todo = [], [cell]
        while todo:
            node = todo.pop()
            for child in await node.get_children():
                cls = await child.read_node_class()
                if cls == ua.NodeClass.Variable:
                    name = (await child.read_browse_name()).Name
                    if name != "EngineeringUnits":
                        variables.append(child)
                elif cls == ua.NodeClass.Object:
                    todo.append(child)
        count = await cell.get_child([f"{ns}:Status", f"{ns}:ScanCount"])
        got = {"receipts": [], "notifications": 0, "events": 0}

        class Handler:
            def datachange_notification(self, node, value, data):
                got["notifications"] += 1
                if node == count:
                    got["receipts"].append((value, time.monotonic()))
            def event_notification(self, event):
                got["events"] += 1
            def status_change_notification(self, status):
                pass

        sub = await c.create_subscription(
            ua.CreateSubscriptionParameters(RequestedPublishingInterval=10,
                                            RequestedMaxKeepAliveCount=100,
                                            RequestedLifetimeCount=1000,
                                            MaxNotificationsPerPublish=0), Handler())
        await sub.subscribe_data_change(variables, sampling_interval=0, queuesize=1)
        await sub.subscribe_events(c.nodes.server)
        print(json.dumps({"ready": len(variables)}), flush=True)
        got["receipts"].clear()
        got["notifications"] = 0
        await asyncio.sleep(seconds)
        print(json.dumps(got), flush=True)

asyncio.run(main(sys.argv[1], float(sys.argv[2])))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def measure(seconds: float, server: bool, client: bool) -> dict[str, Any]:
    """One set-up: the live scan loop for `seconds`, with or without server and client."""
    from hmi.session.live import BENCH_JITTER, LiveRunner

    session = valve_session(PERIOD_US)
    ends: dict[int, float] = {}
    walls: list[float] = []

    def listener(cell: CellView) -> None:  # the bench's own cost, the same in every set-up
        ends[cell.snapshot.scan] = time.monotonic()
        walls.append(cell.scan_wall_us)

    session.scan_listeners.append(listener)
    cell = proc = None
    if server:
        from hmi.opcua.server import CellServer, ServeOptions
        cell = CellServer(session, ServeOptions(port=_free_port()))
        cell.start()
    runner = LiveRunner(session, keep_jitter=BENCH_JITTER)
    runner.start()
    result: dict[str, Any] = {}  # the figures, some read from the client's JSON
    try:
        if client:
            assert cell is not None
            proc = subprocess.Popen(
                [sys.executable, "-c", CLIENT, cell.url, str(seconds), session.project.name],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            assert proc.stdout is not None
            ready = json.loads(proc.stdout.readline() or "{}")  # blocks until subscribed
            if "ready" not in ready:
                raise RuntimeError("the OPC UA client did not subscribe: "
                                   + (proc.stderr.read() if proc.stderr else "")[-500:])
            result["monitored"] = ready["ready"]
        time.sleep(SETTLE_S)
        samples0, scans0, overruns0, walls0 = (len(runner.jitter_us), session.engine.scan,
                                               runner.overruns, len(walls))
        start = time.perf_counter()
        time.sleep(seconds)  # the measurement: the runner paces by the wall clock
        result.update(elapsed=time.perf_counter() - start,
                      jitter=list(runner.jitter_us)[samples0:],
                      scans=session.engine.scan - scans0,
                      overruns=runner.overruns - overruns0, walls=walls[walls0:])
        if proc is not None:
            out, _ = proc.communicate(timeout=seconds + 60)
            got = json.loads(out.strip().splitlines()[-1])
            lags = [(t - ends[scan]) * 1e6 for scan, t in got["receipts"] if scan in ends]
            result.update(lags=lags, notifications=got["notifications"],
                          events=got["events"])
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        runner.stop()
        if cell is not None:
            cell.stop()
    return result


def lines(label: str, r: dict[str, Any]) -> list[str]:
    out = [jitter_line(label, r["jitter"], r["scans"], r["elapsed"], PERIOD_US,
                       r["overruns"])]
    walls = r["walls"]
    if walls:
        out.append(f"  {'':<8} scan time p50 {percentile(walls, 50):6.0f} us  p99 "
                   f"{percentile(walls, 99):6.0f} us  mean {sum(walls) / len(walls):6.0f} us")
    if "lags" in r:
        lags = r["lags"]
        rate = r["notifications"] / r["elapsed"]
        if lags:
            out.append(f"  {'':<8} client: {r['monitored']} variables + events; publishing "
                       f"latency scan end -> client p50 {percentile(lags, 50) / 1000:.1f} ms "
                       f"p99 {percentile(lags, 99) / 1000:.1f} ms max "
                       f"{max(lags) / 1000:.1f} ms; {len(lags)} of {r['scans']} scans "
                       f"notified; {rate:.0f} notifications/s")
        else:
            out.append(f"  {'':<8} client: no ScanCount notification received")
    return out


def run(args: argparse.Namespace) -> None:
    from hmi.errors import UsageError
    from hmi.opcua import require
    try:
        require()
    except UsageError as exc:  # the bench never fails: it says what it could not measure
        print(f"  not measured: {exc}", flush=True)
        return
    seconds = QUICK_SECONDS if getattr(args, "quick", False) else SECONDS
    print(f"  {PROJECT.name}, scan period {PERIOD_US // 1000} ms, {seconds:g} s (wall clock) "
          "per set-up; client in another process", flush=True)
    for label, server, client in (("no server", False, False), ("server", True, False),
                                  ("+client", True, True)):
        for line in lines(label, measure(seconds, server, client)):
            print(line, flush=True)
    for line in with_ui(seconds)[:1]:
        print(line.replace("with UI ", "HMI     "), flush=True)

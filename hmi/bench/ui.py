"""``plchmi bench ui``: the HMI running headless, live, against the wall clock.

The CISPI valve scans in its thread every 10 ms while the Textual app polls, builds frames
and renders them (headless: the terminal output is discarded, the work is not). Printed:

- scan jitter: how late each scan started against its schedule (p50, p99, max), and the
  overruns (scans more than a period late, after which the runner re-anchors), first for the
  scan loop alone (the baseline), then with the UI running;
- the UI refresh rate: frames handed to the panels per second (the app caps it at 20);
- the same again while an operator opens and closes a dialog (the fault dialog, f then
  escape, every quarter of a second), with the garbage collector's full collections: each
  closed dialog leaves some 20,000 objects in reference cycles that only a full
  collection frees, and a full collection holds the interpreter lock throughout (tens of
  milliseconds here), so the scan thread cannot run meanwhile (docs/ui.md, "Live timing").

All of it shares one Python process, hence one GIL: the UI cannot run in parallel with a
scan, only between scans. The jitter with the UI on is the honest figure for that design.
``--quick`` shortens both measurements.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hmi.bench import percentile

if TYPE_CHECKING:
    from hmi.session.session import Session

SECTION = "ui"
HELP = ("HMI headless at a 10 ms scan, 30 s (wall) and 30 s more opening dialogs: scan "
        "jitter p50/p99, UI refresh rate, full garbage collections")

PROJECT = Path(__file__).resolve().parents[2] / "projects" / "cispi_valve"
PERIOD_US = 10_000
UI_SECONDS, BASELINE_SECONDS = 30.0, 10.0
QUICK_UI_SECONDS, QUICK_BASELINE_SECONDS = 5.0, 3.0
SIZE = (120, 36)
SETTLE_S = 0.5  # let the app finish mounting and its first layout before measuring
DIALOG_KEYS = ("f", "escape")  # open the fault dialog, close it
DIALOG_EVERY_S = 0.25


def valve_session(period_us: int) -> Session:
    from hmi.engine.build import build_engine
    from hmi.project.loader import load_project
    from hmi.session.session import Session

    return Session(build_engine(load_project(PROJECT)), period_us)


def jitter_line(label: str, jitter: list[float], scans: int, seconds: float,
                period_us: int, overruns: int) -> str:
    expected = seconds * 1e6 / period_us
    if not jitter:
        return f"  {label:<8} no scan was measured"
    return (f"  {label:<8} {scans} scans in {seconds:.1f} s ({scans / expected:.1%} of the "
            f"{expected:.0f} scheduled)  jitter p50 {percentile(jitter, 50):6.0f} us  "
            f"p99 {percentile(jitter, 99):6.0f} us  max {max(jitter):6.0f} us  "
            f"overruns {overruns}")


def baseline(seconds: float, period_us: int = PERIOD_US) -> str:
    """The scan loop alone, paced by the wall clock: what the UI is compared with."""
    from hmi.session.live import BENCH_JITTER, LiveRunner

    session = valve_session(period_us)
    runner = LiveRunner(session, keep_jitter=BENCH_JITTER)
    runner.start()
    time.sleep(SETTLE_S)
    samples0, scans0, overruns0 = len(runner.jitter_us), session.engine.scan, \
        runner.overruns
    start = time.perf_counter()
    time.sleep(seconds)  # the measurement itself: the runner paces by the wall clock
    elapsed = time.perf_counter() - start
    jitter = list(runner.jitter_us)[samples0:]
    scans, overruns = session.engine.scan - scans0, runner.overruns - overruns0
    runner.stop()
    return jitter_line("no UI", jitter, scans, elapsed, period_us, overruns)


class FullCollections:
    """The garbage collector's full (generation 2) collections while installed: how many,
    and how long each held the interpreter (its own work and the freeing of what it found)."""

    def __init__(self) -> None:
        self.pauses_ms: list[float] = []
        self._started = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            self._started = time.perf_counter()
        else:
            self.pauses_ms.append((time.perf_counter() - self._started) * 1e3)

    def __enter__(self) -> FullCollections:
        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        gc.callbacks.remove(self)

    def line(self) -> str:
        pauses = self.pauses_ms
        if not pauses:
            return f"  {'GC':<8} no full collection"
        many = "full collection" + ("s" if len(pauses) != 1 else "")
        return (f"  {'GC':<8} {len(pauses)} {many}, median "
                f"{percentile(pauses, 50):.1f} ms, longest {max(pauses):.1f} ms")


@dataclass(frozen=True)
class _UIRun:
    """What one run of the live app measured."""

    elapsed: float
    frames: int
    jitter: list[float]
    scans: int
    overruns: int
    collections: FullCollections


def with_ui(seconds: float, period_us: int = PERIOD_US, size: tuple[int, int] = SIZE,
            keys: tuple[str, ...] = ()) -> list[str]:
    """The live app, headless: scans in their thread, the UI polling and rendering; `keys`
    pressed in turn every DIALOG_EVERY_S meanwhile, as an operator would."""
    from hmi.session.live import BENCH_JITTER
    from hmi.ui.app import PlcHmiApp
    from hmi.ui.driver import LiveDriver

    session = valve_session(period_us)
    app = PlcHmiApp(session, live=True)

    async def measure() -> _UIRun:
        async with app.run_test(size=size) as pilot:
            await asyncio.sleep(SETTLE_S)
            driver = app.driver
            assert isinstance(driver, LiveDriver)  # live=True
            runner = driver.runner
            # the app's runner keeps no lateness samples (a runtime's figures are in constant
            # memory): the bench gives it room for this window's, read from the first
            runner.jitter_us = deque(maxlen=BENCH_JITTER)
            scans0, overruns0 = session.engine.scan, runner.overruns
            start, frames0 = time.perf_counter(), app.frames_shown
            with FullCollections() as collections:
                if keys:
                    pressed = 0
                    while time.perf_counter() - start < seconds:
                        await pilot.press(keys[pressed % len(keys)])
                        pressed += 1
                        await asyncio.sleep(DIALOG_EVERY_S)
                else:
                    await asyncio.sleep(seconds)  # the measurement: let the live app run
            return _UIRun(elapsed=time.perf_counter() - start,
                          frames=app.frames_shown - frames0,
                          jitter=list(runner.jitter_us),
                          scans=session.engine.scan - scans0,
                          overruns=runner.overruns - overruns0,
                          collections=collections)

    result = asyncio.run(measure())
    elapsed, frames = result.elapsed, result.frames
    label = "dialogs" if keys else "with UI"
    return [
        jitter_line(label, result.jitter, result.scans, elapsed, period_us,
                    result.overruns),
        f"  {'UI':<8} {frames} frames in {elapsed:.1f} s: {frames / elapsed:.1f} frames/s "
        f"(cap {app.refresh_hz:g}/s), app {size[0]}x{size[1]} headless",
        result.collections.line(),
    ]


def run(args: argparse.Namespace) -> None:
    quick = getattr(args, "quick", False)
    base_s = QUICK_BASELINE_SECONDS if quick else BASELINE_SECONDS
    ui_s = QUICK_UI_SECONDS if quick else UI_SECONDS
    print(f"  {PROJECT.name}, scan period {PERIOD_US // 1000} ms; baseline {base_s:g} s, "
          f"with the UI {ui_s:g} s (wall clock)", flush=True)
    print(baseline(base_s), flush=True)
    for line in with_ui(ui_s):
        print(line, flush=True)
    print(f"  then {ui_s:g} s more, the fault dialog opened and closed (f, escape) every "
          f"{DIALOG_EVERY_S:g} s:", flush=True)
    for line in with_ui(ui_s, keys=DIALOG_KEYS):
        print(line, flush=True)

"""``plchmi bench ui``: the HMI running headless, live, against the wall clock.

The scan runs in its thread at the given period while the Textual app polls, builds frames
and renders them (headless: the terminal output is discarded, the work is not). Reported:

- scan jitter: how late each scan started against its schedule (p50, p99, max), and the
  overruns (scans more than a period late, after which the runner re-anchors);
- the UI refresh rate: frames handed to the panels per second (the app caps it at 20);
- with ``--baseline``, the same scan loop without the UI first, to show what the UI costs.

All of it shares one Python process, hence one GIL: the UI cannot run in parallel with a
scan, only between scans. The jitter with the UI on is the honest figure for that design.
"""

from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path

from hmi.timefmt import DURATION_HINT, parse_duration

HELP = "run the HMI headless at a 10 ms scan for 30 s; print scan jitter and UI refresh rate"
DEFAULT_PROJECT = Path("projects/cispi_valve")


def _duration(text: str) -> int:
    try:
        return parse_duration(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {DURATION_HINT}") from None


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 120x36") from None
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("project", nargs="?", default=str(DEFAULT_PROJECT),
                        help="project folder (default: projects/cispi_valve)")
    parser.add_argument("--period", type=_duration, default=10_000, metavar="TIME",
                        help="scan period (default 10ms)")
    parser.add_argument("--for", dest="duration", type=_duration, default=30_000_000,
                        metavar="TIME", help="wall-clock time to measure (default 30s)")
    parser.add_argument("--size", type=_size, default=(120, 36), metavar="WxH",
                        help="terminal size of the headless app (default 120x36)")
    parser.add_argument("--baseline", action="store_true",
                        help="first measure the scan loop alone, without the UI")


def percentile(values: list[float], p: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(p / 100 * (len(ordered) - 1))))
    return ordered[index]


def _controller(project_path: str, period_us: int):
    from hmi.engine.runner import Controller
    from hmi.engine.scan import Engine
    from hmi.plant.sim import SimPlant
    from hmi.project.loader import load_project

    project = load_project(project_path)
    return Controller(Engine(project, SimPlant(project)), period_us)


def _jitter_line(label: str, jitter: list[float], scans: int, seconds: float,
                 period_us: int, overruns: int) -> str:
    expected = seconds * 1e6 / period_us
    return (f"{label:<10} scans {scans} in {seconds:.1f} s ({scans / expected:.1%} of "
            f"{expected:.0f} scheduled)  jitter p50 {percentile(jitter, 50):.0f} µs  "
            f"p99 {percentile(jitter, 99):.0f} µs  max {max(jitter, default=0):.0f} µs  "
            f"overruns {overruns}")


def baseline(project: str, period_us: int, seconds: float) -> str:
    from hmi.engine.live import LiveRunner

    controller = _controller(project, period_us)
    runner = LiveRunner(controller)
    runner.start()
    time.sleep(seconds)  # the measurement itself: the runner paces by the wall clock
    runner.stop()
    return _jitter_line("no UI", list(runner.jitter_us), controller.engine.scan, seconds,
                        period_us, runner.overruns)


def with_ui(project: str, period_us: int, seconds: float, size: tuple[int, int]) -> list[str]:
    from hmi.ui.app import PlcHmiApp

    controller = _controller(project, period_us)
    app = PlcHmiApp(controller, live=True)
    result: dict = {}

    async def measure() -> None:
        async with app.run_test(size=size):
            runner = app.driver.runner
            await asyncio.sleep(0.5)  # let the app finish mounting and its first layout
            start, frames0 = time.perf_counter(), app.frames_shown
            samples0, scans0, overruns0 = (len(runner.jitter_us), controller.engine.scan,
                                           runner.overruns)
            await asyncio.sleep(seconds)  # the measurement: let the live app run
            elapsed = time.perf_counter() - start
            result.update(elapsed=elapsed, frames=app.frames_shown - frames0,
                          jitter=list(runner.jitter_us)[samples0:],
                          scans=controller.engine.scan - scans0,
                          overruns=runner.overruns - overruns0)

    asyncio.run(measure())
    elapsed = result["elapsed"]
    frames = result["frames"]
    return [
        _jitter_line("with UI", result["jitter"], result["scans"], elapsed, period_us,
                     result["overruns"]),
        f"{'UI':<10} {frames} frames in {elapsed:.1f} s: {frames / elapsed:.1f} frames/s "
        f"(cap {app.refresh_hz:g}/s)",
    ]


def run(args: argparse.Namespace) -> int:
    seconds = args.duration / 1e6
    print(f"plchmi bench ui: {args.project}, scan period {args.period / 1000:g} ms, "
          f"{seconds:g} s wall per measurement, app {args.size[0]}x{args.size[1]} headless")
    if args.baseline:
        print(baseline(args.project, args.period, seconds), flush=True)
    for line in with_ui(args.project, args.period, seconds, args.size):
        print(line)
    return 0

"""The bench sections (startup, engine, campaign): what they measure is what they
say. Figures themselves are never asserted (speed is measured by `plchmi bench`, not here)."""

from __future__ import annotations

import os
import sys

import pytest

from hmi.bench import NAMES, goal_line, sections
from hmi.bench.engine import RUNS, engine_rate, median_run, session_rate
from hmi.bench.startup import first_frame
from hmi.project.loader import load_project
from tests.conftest import PROJECTS


def test_the_sections_of_issue_18_are_listed():
    assert {"startup", "engine", "campaign", "corrector"} <= set(sections())


def test_the_names_the_parser_shows_are_the_sections():
    assert tuple(sections()) == NAMES


def test_first_frame_waits_for_every_marker_and_gives_up_without_them():
    env = dict(os.environ)
    shown = first_frame([sys.executable, "-c", "print('Signal'); print('fsc')"],
                        (b"Signal", b"fsc"), env, timeout_s=20)
    assert shown.wall_s is not None and 0 < shown.wall_s < 20
    missing = first_frame([sys.executable, "-c", "print('Signal')"], (b"Signal", b"fsc"),
                          env, timeout_s=2)
    assert missing.wall_s is None and missing.cpu_s is None


def test_first_frame_reads_the_cpu_time_the_process_had_used():
    """A process that works 0.3 s of CPU before its frame: the CPU figure sees that work
    (in clock ticks), whatever the load makes of the wall time."""
    busy = ("import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3:\n"
            "    pass\nprint('Signal fsc', flush=True)")
    shown = first_frame([sys.executable, "-c", busy], (b"Signal", b"fsc"), dict(os.environ),
                        timeout_s=60)
    assert shown.wall_s is not None and shown.cpu_s is not None
    assert 0.25 <= shown.cpu_s <= shown.wall_s + 0.05


def test_the_engine_rates_count_the_scans_of_a_plchmi_run():
    project = load_project(PROJECTS / "cispi_valve")
    period = project.scan_period_us
    scans, wall, cpu = session_rate(project, 100 * period)
    assert scans == 101 and wall > 0 and cpu >= 0
    scans, wall, cpu = engine_rate(project, 100 * period)
    assert scans == 101 and wall > 0 and cpu >= 0
    scans, wall, cpu = engine_rate(project, 100 * period, snapshots=False)
    assert scans == 101 and wall > 0 and cpu >= 0


def test_an_engine_figure_is_the_median_run_after_an_untimed_one():
    """The first run pays one-time costs (it is the slowest here) and is not counted; of the
    timed runs the median by wall time is given, not the best."""
    walls = iter([9.0] + [float(w) for w in range(RUNS, 0, -1)])
    calls = []

    def measure():
        calls.append(1)
        return 100, next(walls), 1.0
    assert median_run(measure) == (100, float((RUNS + 1) // 2), 1.0)
    assert len(calls) == RUNS + 1


def test_the_goal_line_says_met_or_not():
    assert "NOT met" in goal_line(10_500, 100_000, "scans/s")
    assert ": met" in goal_line(120_000, 100_000, "scans/s")
    assert ": met" in goal_line(0.4, 0.5, "s", higher_is_better=False)


def test_first_frame_starts_the_process_in_the_folder_asked(tmp_path):
    """bench startup --against: `python -m hmi.cli` imports the hmi of its working folder."""
    shown = first_frame([sys.executable, "-c", "import os; print('Signal', os.getcwd())"],
                        (b"Signal", str(tmp_path).encode()), dict(os.environ),
                        timeout_s=20, cwd=tmp_path)
    assert shown.wall_s is not None


def test_against_takes_a_plchmi_checkout_only(tmp_path):
    from hmi.bench.startup import ROOT, checkouts
    from hmi.errors import UsageError

    assert [tree.root for tree in checkouts(None)] == [ROOT]
    assert [tree.root for tree in checkouts(str(ROOT))] == [ROOT, ROOT]
    with pytest.raises(UsageError, match="not a plchmi checkout"):
        checkouts(str(tmp_path))

"""The bench sections of issue 18 (startup, engine, campaign): what they measure is what they
say. Figures themselves are never asserted (speed is measured by `plchmi bench`, not here)."""

from __future__ import annotations

import os
import sys

from hmi.bench import NAMES, goal_line, sections
from hmi.bench.engine import engine_rate, session_rate
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
    assert shown is not None and 0 < shown < 20
    missing = first_frame([sys.executable, "-c", "print('Signal')"], (b"Signal", b"fsc"),
                          env, timeout_s=2)
    assert missing is None


def test_the_engine_rates_count_the_scans_of_a_plchmi_run():
    project = load_project(PROJECTS / "cispi_valve")
    period = project.scan_period_us
    scans, wall, cpu = session_rate(project, 100 * period)
    assert scans == 101 and wall > 0 and cpu >= 0
    scans, wall, cpu = engine_rate(project, 100 * period)
    assert scans == 101 and wall > 0 and cpu >= 0


def test_the_goal_line_says_met_or_not():
    assert "NOT met" in goal_line(10_500, 100_000, "scans/s")
    assert ": met" in goal_line(120_000, 100_000, "scans/s")
    assert ": met" in goal_line(0.4, 0.5, "s", higher_is_better=False)

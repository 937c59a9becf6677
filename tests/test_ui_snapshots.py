"""Snapshot tests of the operator screen in its main states (pytest-textual-snapshot).

Each scenario (tests/ui_scenarios.py) presses the operator's keys in virtual time with
wall-clock figures hidden, so the SVG is identical on every run. After an intended change of
the display, look at the report, then accept with `pytest --snapshot-update`.
"""

from __future__ import annotations

import pytest
from ui_scenarios import SCENARIOS


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.name)
def test_screen(snap_compare, scenario):
    assert snap_compare(scenario.make(), terminal_size=scenario.size, run_before=scenario.run)

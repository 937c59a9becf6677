"""Every example project, with its normal control and no fault, runs ten virtual minutes
without a single alarm. An alarm in normal operation is a nuisance alarm (ISA-18.2): an
operator who learns to acknowledge it without reading stops reading the ones that matter.
(The palletizer raised "Elevator: raise refused, the load is at the plate" (P1) at every new
pallet: its program ordered a raise for one scan with the empty pallet already at the eye.)
"""

from __future__ import annotations

import pytest

from tests.conftest import PROJECTS, make_session

EXAMPLES = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())
TEN_MINUTES_US = 600_000_000


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_normal_program_raises_no_alarm_in_ten_minutes(name):
    session = make_session(PROJECTS / name)
    raised: list[str] = []

    def scanned(snap) -> None:
        raised.extend(f"{snap.time_us / 1e6:.3f} s P{a.priority} {a.text}" for a in snap.alarms
                      if a.raised_us == snap.time_us)

    last = session.run_for(TEN_MINUTES_US, on_scan=scanned, on_quiet=lambda scan: None)
    assert last.snapshot.time_us >= TEN_MINUTES_US
    everything = [f"P{a.priority} {a.text}" for a in session.alarms.alarms.values()]
    assert not raised and not everything, raised[:5] or everything[:5]

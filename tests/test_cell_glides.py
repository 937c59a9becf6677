"""The box-handling cells' glides (hmi.plant.sim.cell) change nothing: a cell that glides
through the steps it can vouch for ends every step exactly where the same cell computing every
physics step in full does — boxes to the nanometre, travels and their stall clocks, flags,
counters, events, sensors — under random orders and faults, and in closed loop with each
project's own control law and fault scenarios."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.plant.sim.cell import SteppedCell
from hmi.plant.sim.palletizer import Palletizer
from hmi.plant.sim.sorter import SortingCell
from hmi.project.loader import load_project
from hmi.project.scenarios import find_scenario
from tests.conftest import PROJECTS
from tests.plant_steps import run_twins

MS = 1_000
S = 1_000_000


def _full(cls: type[SteppedCell]) -> type[SteppedCell]:
    """The same model computing every physics step in full (no glide is ever planned)."""
    return type(f"Full{cls.__name__}", (cls,), {"_plan_glide": lambda self, dt: None})


FullSorter, FullPalletizer = _full(SortingCell), _full(Palletizer)


def physics(cell: SteppedCell, sensors: dict | None = None) -> dict:
    """Everything the cell's physics holds, but the glide itself and the reporting caches
    (`sensors`: the cell's `sensors()` already read at this instant, not computed again),
    the motion its reads owe carried first (SteppedCell.settle)."""
    cell.settle()
    state = {k: v for k, v in vars(cell).items()
             if k not in ("_glide", "_vouched", "_state_cache", "_counter_cache", "source")}
    source = cell.source
    state["source"] = (source.next_due, source.next_high, source.count, list(source.queued))
    state["sensors"] = cell.sensors() if sensors is None else sensors
    state["state"] = cell.state()
    return state


def twins(kind: str, params: dict) -> tuple[SteppedCell, SteppedCell]:
    if kind == "sorter":
        return SortingCell("S", params), FullSorter("S", params)
    return Palletizer("P", params), FullPalletizer("P", params)


FAULTS = {"sorter": sorted(SortingCell.FAULTS), "palletizer": sorted(Palletizer.FAULTS)}
PARAMS = {"sorter": {"first_box": 0, "interval_min": 2 * S, "interval_max": 6 * S},
          "palletizer": {"first_box": 0, "interval_min": 1 * S, "interval_max": 3 * S}}


@st.composite
def runs(draw, kind: str):
    """Orders held for a while each (every actuator on with some chance), read every
    `sample` µs (a scan period, or an odd one that ends between physics steps), and a few
    faults injected on the way."""
    actuators = (SortingCell if kind == "sorter" else Palletizer).ACTUATORS
    holds = draw(st.lists(st.tuples(
        st.integers(20 * MS, 3 * S),
        st.lists(st.sampled_from(actuators), max_size=4, unique=True)),
        min_size=4, max_size=14))
    sample = draw(st.sampled_from((5 * MS, 10 * MS, 7 * MS, 23 * MS, 1 * MS)))
    faults = draw(st.lists(st.tuples(st.sampled_from(FAULTS[kind]), st.integers(0, 20 * S)),
                           max_size=2))
    return holds, sample, faults


def drive(kind: str, holds, sample: int, faults) -> None:
    glide, full = twins(kind, PARAMS[kind])
    for code, at in faults:
        glide.inject(code, at)
        full.inject(code, at)
    reads = 0
    for duration, on in holds:
        orders = {name: name in on for name in glide.ACTUATORS}
        glide.write(glide.t, orders)
        full.write(full.t, orders)
        end = glide.t + duration
        while glide.t < end:
            now = min(end, glide.t + sample)
            # the plant's read (SteppedCell.sense: its gliding shortcut), or an advance then
            # the sensors read right after it (SteppedCell.read_sensors), in turn
            reads += 1
            if reads % 2:
                sensed = dict(glide.sense(now))
            else:
                glide.advance(now)
                sensed = dict(glide.read_sensors())
            full.advance(now)
            expected = full.sensors()
            assert sensed == expected, f"at {now} us"
            assert physics(glide) == physics(full, expected), f"at {now} us"
    assert glide.events == full.events


@settings(max_examples=40, deadline=None)
@given(runs("sorter"))
def test_the_sorting_cell_glides_exactly_as_it_steps(run):
    drive("sorter", *run)


@settings(max_examples=40, deadline=None)
@given(runs("palletizer"))
def test_the_palletizer_glides_exactly_as_it_steps(run):
    drive("palletizer", *run)


@pytest.mark.parametrize(("project", "scenario"), [
    ("sorting", None), ("sorting", "table_jam"), ("sorting", "left_blocked"),
    ("palletizer", None), ("palletizer", "elevator_jam"),
    ("palletizer", "layer_eye_stuck0")])
def test_in_closed_loop_the_gliding_plant_runs_scan_for_scan_as_the_full_one(project, scenario):
    """The project's law drives both plants: every scan's snapshot (inputs, outputs, plant
    state, counters, events) and the cells' whole physics are the same."""
    loaded = load_project(PROJECTS / project)
    injections = find_scenario(loaded, scenario).injections if scenario else ()
    a, b = run_twins(loaded, {SortingCell: FullSorter, Palletizer: FullPalletizer},
                     injections, 60 * S // loaded.scan_period_us)
    cell_a, cell_b = a.devices[0], b.devices[0]
    assert type(cell_b) in (FullSorter, FullPalletizer)
    assert physics(cell_a) == physics(cell_b)
    assert cell_a.count["arrived"] > 3  # the run did handle boxes


@pytest.mark.parametrize(("kind", "orders"), [("sorter", ("CONV_E",)), ("palletizer", ("FEED",))])
def test_a_change_by_hand_then_touch_steps_in_full_from_there(kind, orders):
    """A glide trusts the cell to change only through its own methods (checking
    everything at every step cost a quarter of the cell's time); whoever moves a box by hand
    says so with touch(), and the gliding cell then goes on exactly as the full one."""
    glide, full = twins(kind, PARAMS[kind])
    for cell in (glide, full):
        cell.write(0, {name: name in orders for name in cell.ACTUATORS})
        cell.advance(600 * MS)
    assert glide._glide is not None  # the box is gliding on the belt
    for cell in (glide, full):  # by hand: 40 mm on, or just short of the feed's end stop
        if kind == "sorter":
            cell.boxes[0].lo += 40 * 1_000_000
        else:
            cell.feed[0].lo = cell.feed_len - cell.box_len - 1_000_000
        cell.touch()
    for now in range(610 * MS, 4 * S, 10 * MS):
        sensed = dict(glide.sense(now))
        full.advance(now)
        assert sensed == full.sensors(), f"at {now} us"
        assert physics(glide) == physics(full), f"at {now} us"
    assert glide.events == full.events

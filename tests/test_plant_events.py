"""A simulated plant's write says whether an event waits (SimPlant.write_vector: the
engine's scan then asks neither take_events at a quiet scan): it says none waits exactly
when take_events would give nothing, under random reads, writes, faults and repairs on
every example project's plant; and a plant whose take_events is replaced is always asked."""

from __future__ import annotations

import contextlib
from functools import cache

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.engine.scan import Engine
from hmi.errors import UsageError
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import Injection
from hmi.project.loader import load_project
from hmi.project.model import Project
from tests.conftest import PROJECTS

NAMES = ("cispi_valve", "sorting", "palletizer", "conveyor_robot", "cispi_subsystem")


@cache
def load(name: str) -> Project:
    return load_project(PROJECTS / name)


def steps():
    """Scans of 1 to 200 ms, each writing random outputs, some with a fault injected or a
    repair first."""
    return st.lists(st.tuples(st.integers(1_000, 200_000), st.integers(0, 2**16 - 1),
                              st.integers(0, 20), st.integers(0, 2_000_000)),
                    min_size=1, max_size=80)


@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=30, deadline=None)
@given(run=steps())
def test_the_write_says_no_event_waits_exactly_when_none_does(name, run):
    project = load(name)
    plant = SimPlant(project)
    engine = Engine(project, plant)  # (only its image, bindings and output names)
    names = engine.output_scan.names
    faults = plant.faults()
    now = 0
    for step, bits, fault, after in run:
        now += step
        if fault < len(faults) and fault % 3 == 0:
            device, code, _ = faults[fault]
            plant.inject(Injection(code, now + after, device))
        elif fault == 20:
            with contextlib.suppress(UsageError):  # (a model without repairs refuses)
                plant.repair(now)
        plant.read_into(now, engine.image, engine._bindings)
        values = tuple(bool(bits >> k & 1) for k in range(len(names)))
        said = plant.write_vector(now, names, values)
        taken = plant.take_events()
        assert said == (taken == ()), (now, said, taken)


def test_a_replaced_take_events_is_asked_at_every_scan():
    project = load("cispi_valve")
    plant = SimPlant(project)
    plant.take_events = lambda: ()  # type: ignore[method-assign]
    engine = Engine(project, plant)
    plant.read_into(0, engine.image, engine._bindings)
    assert plant.write_vector(0, engine.output_scan.names, (False, False)) is False


def test_a_read_replaced_on_one_plant_is_read_through_until_it_is_given_back():
    """SimPlant.read set on the plant (a test's lost link, mid-run), then given back as
    monkeypatch's undo does (its own bound method again) or deleted: read_into reads
    through the replacement exactly while it is set, and another plant is not touched."""
    project = load("cispi_valve")
    plant, other = SimPlant(project), SimPlant(project)
    engine = Engine(project, plant)
    image, bindings = engine.image, engine._bindings
    plant.read_into(0, image, bindings)  # (the read plan made: the fast path from here)
    own = plant.read
    asked: list[int] = []

    def lost(now_us: int) -> dict[str, bool]:
        asked.append(now_us)
        return dict.fromkeys(plant.input_names, True)

    plant.read = lost  # type: ignore[method-assign]
    plant.read_into(10_000, image, bindings)
    assert asked == [10_000]
    assert all(image[slot] for _, slot in bindings)
    assert other.read is not lost and other._read_replaced is None
    plant.read = own  # type: ignore[method-assign]  # (monkeypatch's undo)
    plant.read_into(20_000, image, bindings)
    assert asked == [10_000] and plant._read_replaced is None
    assert image[bindings[0][1]] == plant.read(20_000)[bindings[0][0]]
    plant.read = lost  # type: ignore[method-assign]
    del plant.read
    plant.read_into(30_000, image, bindings)
    assert asked == [10_000]
    assert SimPlant.read is type(plant).read  # (the class's own: the read plan's test)

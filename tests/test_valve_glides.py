"""The valve's glide (hmi.plant.sim.valve: between two boundaries of its dynamics the valve
moves in a straight line, or its stall clock runs, in one step and with the sensors it kept)
changes nothing: a valve that glides ends every advance and every read exactly where the same
valve stepping through its loop in full does — position, time, stall clock, armed faults,
glitches, counters, events, sensors — under random orders, sample times, faults and repairs,
and in closed loop with the valve projects' own laws and faults."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.plant.sim.valve import Valve
from hmi.project.injection import parse_injection
from tests.examples import example
from tests.plant_steps import run_twins

MS = 1_000
S = 1_000_000


class FullValve(Valve):
    """The same model stepping through its loop in full at every advance (no glide)."""

    def _plan_glide(self) -> None:
        return None


def physics(valve: Valve, sensors: Any = None) -> dict[str, Any]:
    """Everything the valve's physics holds, but the glide itself and the reporting caches,
    with what it reports (`sensors`: its sensors already read at this instant)."""
    state = {k: v for k, v in vars(valve).items()
             if k not in ("_glide", "_state_cache", "_counter_cache")}
    state["sensors"] = dict(valve.sensors() if sensors is None else sensors)
    state["state"] = valve.state()
    state["counters"] = valve.counters()
    return state


ORDERS = ({}, {"O": True}, {"C": True}, {"C": True, "O": True})


@st.composite
def runs(draw):
    """A valve's parameters (a travel of microseconds too: then every boundary is read at its
    very instant), orders held for a while each and read every `sample` µs (a scan period,
    an odd one, or 1 µs for a short while), faults injected on the way, perhaps a repair."""
    travel = draw(st.integers(8, 300) | st.integers(300, 3 * S))
    params = {"travel": travel,
              "switch_band": draw(st.integers(0, travel // 3)),
              "stall_tolerance": draw(st.integers(1, 300) | st.integers(300, 2 * S)),
              "glitch": draw(st.integers(1, 300) | st.integers(300, 500 * MS)),
              "block_at": draw(st.sampled_from((0.05, 0.5, 0.78, 0.95))),
              "initial": draw(st.sampled_from(("closed", "open"))),
              # the switches' own dynamics (a project's tolerances): none, or a delay and
              # a bounce, per edge or alike at every edge
              "delay": draw(st.sampled_from((0, 0, 1, 5 * MS, 37))),
              "bounce": draw(st.sampled_from((0, 0, 1, 2, 20 * MS, 333))),
              "bounce_seed": draw(st.integers(0, 5)),
              "bounce_pattern": draw(st.sampled_from(("each", "same")))}
    holds = []
    for _ in range(draw(st.integers(3, 10))):
        sample = draw(st.sampled_from((10 * MS, 7 * MS, 23 * MS, 333 * MS, 1, 3)))
        longest = 3 * S if sample >= MS else 3 * MS
        holds.append((draw(st.integers(1, longest)), draw(st.sampled_from(ORDERS)), sample))
    span = sum(duration for duration, _, _ in holds)
    faults = draw(st.lists(st.tuples(st.sampled_from(sorted(Valve.FAULTS)),
                                     st.integers(0, span)), max_size=3))
    # faults injected on the way (inside a glide: it ends where the fault is due)
    late = draw(st.lists(st.tuples(st.sampled_from(sorted(Valve.FAULTS)),
                                   st.integers(0, span), st.integers(0, 3 * S)), max_size=2))
    repair = draw(st.none() | st.integers(0, span))
    return params, holds, faults, repair, late


def drive(params, holds, faults, repair: int | None, late=()) -> int:
    """Both valves through the run; returns how many reads the gliding one answered from a
    glide it was already in. `late`: (fault, when it is injected, how long after it is
    due)."""
    glide, full = Valve("V", params), FullValve("V", params)
    for code, at in faults:
        glide.inject(code, at)
        full.inject(code, at)
    reads = glided = 0
    for duration, orders, sample in holds:
        for valve in (glide, full):
            valve.write(valve.t, {"C": orders.get("C", False), "O": orders.get("O", False)})
            valve.advance(valve.t)  # (read again at the very instant of the write)
        assert physics(glide) == physics(full), f"orders at {glide.t} us"
        end = glide.t + duration
        while glide.t < end:
            now = min(end, glide.t + sample)
            if repair is not None and glide.t < repair <= now:
                assert glide.repair(repair) == full.repair(repair)
            for code, when, after in late:
                if glide.t <= when < now:
                    glide.inject(code, glide.t + after)
                    full.inject(code, full.t + after)
            reads += 1
            # the plant's read (Valve.sense: the glide's shortcut), an advance then the
            # sensors read right after it (the pump advances a valve, the plant then reads
            # it), or an advance then sensors() as a test reads them, in turn
            glided += glide._glide is not None and now < glide._glide[0]
            if reads % 3 == 0:
                sensed = dict(glide.sense(now))
            elif reads % 3 == 1:
                glide.advance(now)
                sensed = dict(glide.read_sensors())
            else:
                glide.advance(now)
                sensed = glide.sensors()
            full.advance(now)
            expected = full.sensors()
            assert sensed == expected, f"at {now} us"
            assert physics(glide, sensed) == physics(full, expected), f"at {now} us"
    assert glide.events == full.events
    return glided


@settings(max_examples=150, deadline=None)
@given(runs())
def test_the_valve_glides_exactly_as_it_steps(run):
    drive(*run)


def test_a_cycle_read_every_scan_is_mostly_glides():
    """The shortcut is taken (else the twin test above would compare the loop with itself):
    opening and closing read every 10 ms, all but the reads at a boundary glide."""
    holds = [(2100 * MS, {"O": True}, 10 * MS), (1 * S, {}, 10 * MS),
             (2100 * MS, {"C": True}, 10 * MS), (1 * S, {}, 10 * MS)]
    glided = drive({}, holds, [], None)
    assert glided > 0.9 * (6200 // 10)


def test_a_change_by_hand_then_touch_steps_in_full_from_there():
    """A glide trusts the valve to change only through its own methods; whoever moves it by
    hand says so with touch(), and the gliding valve then goes on exactly as the full one."""
    glide, full = Valve("V", {}), FullValve("V", {})
    for valve in (glide, full):
        valve.write(0, {"C": False, "O": True})
        valve.advance(500 * MS)
    assert glide._glide is not None and glide._glide[1] == 1  # opening, gliding
    for valve in (glide, full):
        valve.pos = valve.travel - valve.band - 5 * MS  # 5 ms short of the open switch
        valve.touch()
    for now in range(510 * MS, 2 * S, 10 * MS):
        sensed = dict(glide.sense(now))
        full.advance(now)
        assert sensed == full.sensors(), f"at {now} us"
        assert physics(glide, sensed) == physics(full), f"at {now} us"
    assert glide.events == full.events
    assert [e.kind for e in glide.events] == ["end_stop_overrun"]


# (project, faults): every kind of valve fault the campaign injects, at its instants
CLOSED_LOOP = [
    ("cispi_valve", ()), ("cispi_valve", ("F1@12s", "F11@20s")),
    ("cispi_valve", ("F4@10s",)), ("cispi_valve", ("F5@8.2s",)),
    ("cispi_valve", ("F6@12s",)), ("cispi_valve", ("F7@14.5s", "F10@20s")),
    ("cispi_valve", ("F8@8.2s", "F9@17.5s")), ("cispi_valve", ("F12@12s",)),
    ("cispi_valve", ("F13@10.4s",)), ("cispi_valve", ("F13@8.2s",)),
    ("cispi_subsystem", ("V1.F13@26.5s",)), ("cispi_subsystem", ("V2.F4@20s",)),
]


@pytest.mark.parametrize(("project", "faults"), CLOSED_LOOP)
def test_in_closed_loop_the_gliding_valves_run_scan_for_scan_as_the_full_ones(project, faults):
    """The project's law drives both plants (faults injected in both): every scan's inputs,
    outputs, plant state, counters and events, and the valves' whole physics, are the same."""
    loaded = example(project)
    a, b = run_twins(loaded, {Valve: FullValve}, map(parse_injection, faults),
                     30 * S // loaded.scan_period_us)
    valves = [(x, y) for x, y in zip(a.devices, b.devices, strict=True)
              if isinstance(x, Valve)]
    assert valves
    for x, y in valves:
        assert physics(x) == physics(y)
        assert type(y) is FullValve and x.opens >= 1  # the valves did move

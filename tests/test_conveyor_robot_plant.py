"""The simulated conveyor and robot of 002 §4: transport, hand-over, interruptions, faults."""

from __future__ import annotations

from hmi.plant.sim.conveyor import Conveyor
from hmi.plant.sim.robot import Robot

MS = 1_000
S = 1_000_000


def conveyor(**params) -> Conveyor:
    return Conveyor("C1", {"transport": 3_500 * MS, **params})


def robot(**params) -> Robot:
    return Robot("R1", {"work": 2_500 * MS, "return_time": 500 * MS, **params})


def first_time(device, sensor: str, value: bool, until: int, step: int = 10 * MS) -> int | None:
    """The first sample time (every `step`) at which `sensor` reads `value`."""
    t = device.t
    while t < until:
        t += step
        device.advance(t)
        if device.sensors()[sensor] == value:
            return t
    return None


def test_a_pallet_travels_in_the_transport_time_and_waits_at_b():
    c = conveyor()
    c.write(0, {"d": True, "release": False})
    assert first_time(c, "B", True, 10 * S, step=1 * MS) == 3_500 * MS
    c.advance(8 * S)
    assert c.sensors() == {"B": True, "halted": False}
    (record,) = c.task_records()
    assert (record.start_us, record.end_us, record.work_us) == (0, 3_500 * MS, 3_500 * MS)
    assert c.counters() == {"pallets": 1, "handed": 0}


def test_release_hands_the_pallet_over_and_the_next_one_can_be_pushed():
    c = conveyor(initial="loaded")
    assert c.sensors()["B"]
    c.write(1 * S, {"d": True, "release": True})  # as the cell's join does: both at once
    assert not c.sensors()["B"] and c.pallet == 0
    assert c.counters()["handed"] == 1 and c.events == []


def test_a_stop_delays_the_pallet_by_exactly_its_duration():
    c = conveyor()
    c.inject("stop", 1 * S, 2 * S)
    c.write(0, {"d": True, "release": False})
    halted = []
    for t in range(10 * MS, 6 * S, 10 * MS):
        c.advance(t)
        if c.sensors()["halted"]:
            halted.append(t)
    assert halted[0] == 1 * S and halted[-1] == 2_990 * MS  # halted during [1 s, 3 s)
    (record,) = c.task_records()
    assert (record.end_us, record.work_us) == (5_500 * MS, 3_500 * MS)


def test_a_stop_without_duration_is_for_good():
    c = conveyor()
    c.inject("stop", 1 * S)
    c.write(0, {"d": True, "release": False})
    c.advance(100 * S)
    assert c.sensors() == {"B": False, "halted": True}
    (record,) = c.task_records()
    assert record.end_us is None and record.work_us == 1 * S


def test_a_slipping_belt_moves_at_the_slip_speed_exactly():
    c = conveyor(slip_speed=0.5)
    c.inject("slip", 1 * S)
    c.write(0, {"d": True, "release": False})
    assert first_time(c, "B", True, 20 * S, step=1 * MS) == 6 * S  # 1 s + 2.5 s at half speed
    assert not c.sensors()["halted"]
    assert c.task_records()[0].work_us == 6 * S  # slipping is slow work, not interruption


def test_pushing_onto_an_occupied_belt_is_damage():
    c = conveyor()
    c.write(0, {"d": True, "release": False})
    c.write(1 * S, {"d": False, "release": False})
    c.write(2 * S, {"d": True, "release": False})
    (event,) = c.events
    assert event.kind == "pallet_collision" and event.damage and event.time_us == 2 * S


def test_the_robot_works_reports_the_end_and_returns_home():
    r = robot()
    assert r.sensors() == {"e": True, "R": False, "halted": False}
    r.write(0, {"G": True})
    assert not r.sensors()["e"]
    assert first_time(r, "R", True, 10 * S, step=1 * MS) == 2_500 * MS
    r.advance(4 * S)
    assert r.sensors()["R"]  # holds the end until G drops
    r.write(4 * S, {"G": False})
    assert first_time(r, "e", True, 10 * S, step=1 * MS) == 4_500 * MS
    assert r.counters() == {"transfers": 1}
    assert r.task_records()[0].work_us == 2_500 * MS


def test_a_robot_stop_suspends_the_work():
    r = robot()
    r.inject("stop", 1 * S, 1_500 * MS)
    r.write(0, {"G": True})
    r.advance(1 * S)
    assert r.sensors()["halted"]
    assert first_time(r, "R", True, 10 * S, step=1 * MS) == 4 * S
    assert not r.sensors()["halted"]


def test_skip_ends_the_task_at_once_and_arms_for_an_idle_robot():
    r = robot()
    r.inject("skip", 1 * S)
    r.write(0, {"G": True})
    r.advance(1 * S)
    assert r.sensors()["R"] and r.task_records()[0].end_us == 1 * S
    idle = robot()
    idle.inject("skip", 1 * S)
    idle.advance(2 * S)
    idle.write(2 * S, {"G": True})
    assert idle.sensors()["R"] and idle.task_records()[0].work_us == 0


def test_dropping_the_order_midway_aborts_and_an_order_while_busy_is_ignored():
    r = robot()
    r.write(0, {"G": True})
    r.write(1 * S, {"G": False})
    assert [e.kind for e in r.events] == ["order_dropped_midway"]
    assert r.task_records()[0].aborted
    r.write(1_200 * MS, {"G": True})  # still returning home
    assert r.events[-1].kind == "order_ignored" and not any(e.damage for e in r.events)

"""The simulated valve: motion, end switches, damage events and each fault's physical effect."""

from __future__ import annotations

import pytest

from hmi.plant.sim.valve import Valve

MS = 1_000
S = 1_000_000


def valve(**params) -> Valve:
    return Valve("V1", {"travel": 2 * S, "switch_band": 40 * MS, "stall_tolerance": 1 * S,
                        "glitch": 300 * MS, **params})


def drive(v: Valve, until: int, C=False, O=False, step=10 * MS):
    """Hold the orders from v.t to `until`, sampling sensors every `step`; return samples."""
    samples = []
    v.write(v.t, {"C": C, "O": O})
    t = v.t
    while t < until:
        t = min(until, t + step)
        v.advance(t)
        samples.append((t, v.sensors()["fsc"], v.sensors()["fso"], v.pos))
    return samples


def open_fully(v: Valve, limit=3 * S):
    """Open like the functional program: order O until fso (at most `limit`), then drop it."""
    v.write(v.t, {"C": False, "O": True})
    end = v.t + limit
    while not v.sensors()["fso"] and v.t < end:
        v.advance(v.t + 10 * MS)
    v.write(v.t, {"C": False, "O": False})


def close_fully(v: Valve, limit=3 * S):
    v.write(v.t, {"C": True, "O": False})
    end = v.t + limit
    while not v.sensors()["fsc"] and v.t < end:
        v.advance(v.t + 10 * MS)
    v.write(v.t, {"C": False, "O": False})


def test_starts_closed_and_travels_in_the_travel_time():
    v = valve()
    assert v.sensors() == {"fsc": True, "fso": False}
    drive(v, 1 * S, O=True)
    assert v.pos == 1 * S and v.sensors() == {"fsc": False, "fso": False}
    drive(v, 1960 * MS, O=True)
    assert v.sensors() == {"fsc": False, "fso": True}  # switch made 40 ms before the end


def test_stops_where_it_is_when_the_order_drops():
    v = valve()
    drive(v, 500 * MS, O=True)
    drive(v, 3 * S)
    assert v.pos == 500 * MS
    assert any(e.kind == "order_dropped_midway" and not e.damage for e in v.events)


def test_both_orders_move_nothing_and_are_damage():
    v = valve()
    drive(v, 500 * MS, O=True)
    drive(v, 1 * S, O=True, C=True)
    assert v.pos == 500 * MS
    damage = [e for e in v.events if e.damage]
    assert [e.kind for e in damage] == ["both_orders"] and damage[0].time_us == 500 * MS


def test_order_held_against_end_stop_beyond_tolerance_is_damage():
    v = valve()
    drive(v, 2 * S, O=True)  # reaches the mechanical stop at 2 s
    assert not [e for e in v.events if e.damage]
    drive(v, 3 * S, O=True)  # exactly 1 s against the stop: still tolerated
    assert not [e for e in v.events if e.damage]
    drive(v, 3100 * MS, O=True)
    damage = [e for e in v.events if e.damage]
    assert [e.kind for e in damage] == ["end_stop_overrun"]
    assert damage[0].time_us == 3 * S + 1  # first microsecond beyond the tolerance


def test_cycles_are_counted_when_the_valve_closes_after_opening():
    v = valve()
    for _ in range(3):
        open_fully(v)
        close_fully(v)
    assert v.counters() == {"cycles": 3, "opens": 3, "closes": 3}
    assert not [e for e in v.events if e.damage]


@pytest.mark.parametrize("code,sensor,value", [
    ("F1", "fsc", False), ("F2", "fsc", True), ("F3", "fso", False), ("F4", "fso", True)])
def test_stuck_sensors(code, sensor, value):
    v = valve()
    v.inject(code, 1 * S)
    drive(v, 1 * S)
    samples = drive(v, 5 * S, O=True) + drive(v, 9 * S, C=True)
    index = 1 if sensor == "fsc" else 2
    assert {s[index] for s in samples} == {value}
    assert v.pos == 0  # the valve itself moved normally (opened and closed again)


def test_f5_valve_stuck_closed_never_leaves_the_closed_position():
    v = valve()
    v.inject("F5", 0)
    drive(v, 3 * S, O=True)
    assert v.pos == 0 and v.sensors()["fsc"]
    stall = [e for e in v.events if e.kind == "stall"]
    assert stall and stall[0].time_us == 1 * S + 1


def test_f5_injected_while_open_lets_the_valve_close_then_sticks():
    v = valve()
    open_fully(v)
    v.inject("F5", v.t)
    close_fully(v)
    drive(v, v.t + 2 * S, O=True)
    assert v.sensors()["fsc"] and not v.sensors()["fso"]


def test_f6_valve_stuck_open():
    v = valve()
    open_fully(v)
    v.inject("F6", v.t)
    drive(v, v.t + 2 * S, C=True)
    assert v.sensors()["fso"] and not v.sensors()["fsc"]


@pytest.mark.parametrize("code,sensor,glitch_value", [
    ("F7", "fsc", True), ("F9", "fso", True)])
def test_unexpected_rise_is_a_glitch_while_the_sensor_should_read_0(code, sensor, glitch_value):
    v = valve()
    open_fully(v) if sensor == "fsc" else None  # fsc must truly be 0 (valve open)
    start = v.t + 100 * MS
    v.inject(code, start)
    samples = drive(v, start + 1 * S)
    index = 1 if sensor == "fsc" else 2
    high = [t for t, *vals, _ in samples if vals[index - 1] is glitch_value]
    assert high[0] == start and high[-1] == start + 290 * MS  # 300 ms glitch, 10 ms samples
    assert not [e for e in v.events if e.damage]


@pytest.mark.parametrize("code,sensor", [("F8", "fsc"), ("F10", "fso")])
def test_unexpected_fall_is_a_glitch_while_the_sensor_should_read_1(code, sensor):
    v = valve()
    if sensor == "fso":
        open_fully(v)
    start = v.t + 100 * MS
    v.inject(code, start)
    samples = drive(v, start + 1 * S)
    index = 1 if sensor == "fsc" else 2
    low = [t for t, *vals, _ in samples if vals[index - 1] is False]
    assert low[0] == start and len(low) == 30


def test_f7_waits_until_fsc_should_read_0():
    v = valve()
    v.inject("F7", 0)  # valve closed: fsc is truly 1, nothing visible yet
    drive(v, 1 * S)
    assert v.sensors()["fsc"] and "fsc" not in v.glitches
    drive(v, 1200 * MS, O=True)  # leaving the closed zone arms the glitch
    # The switch zone ends 40 ms of travel after the start: the glitch starts right there.
    assert v.glitches["fsc"] == (True, 1_040_001, 1_340_001)
    assert v.sensors()["fsc"] is True and v.pos == 200 * MS


def test_f11_unexpected_movement_from_closed_to_open():
    v = valve()
    v.inject("F11", 1 * S)
    drive(v, 4 * S)  # no order at all
    assert v.sensors() == {"fsc": False, "fso": True} and v.pos == 2 * S


def test_f12_unexpected_movement_from_open_to_closed():
    v = valve()
    open_fully(v)
    v.inject("F12", v.t + 1 * S)
    drive(v, v.t + 4 * S)
    assert v.sensors() == {"fsc": True, "fso": False} and v.pos == 0


def test_f13_jams_between_positions_at_the_next_movement():
    v = valve()
    v.inject("F13", 0)
    drive(v, 3 * S, O=True)
    assert v.pos == 1 * S and v.jammed  # block_at 0.5 of travel
    assert v.sensors() == {"fsc": False, "fso": False}
    assert any(e.kind == "stall" and e.damage for e in v.events)


def test_f13_while_moving_jams_immediately():
    v = valve()
    drive(v, 700 * MS, O=True)
    v.inject("F13", 700 * MS)
    drive(v, 3 * S, O=True)
    assert v.pos == 700 * MS


def test_every_declared_fault_is_injectable():
    assert sorted(Valve.FAULTS, key=lambda c: int(c[1:])) == [f"F{i}" for i in range(1, 14)]
    for code in Valve.FAULTS:
        v = valve()
        v.inject(code, 0)
        open_fully(v)
        assert code in v.active_faults


# -- the switches' own dynamics: delay and bounce (a project's tolerances) -----------------


def readings(v: Valve, until: int, step: int = 100) -> list[tuple[int, bool, bool]]:
    """(time, fsc, fso) at every change of the reading, sampled every `step` µs."""
    out: list[tuple[int, bool, bool]] = []
    t = v.t
    while t < until:
        t = min(until, t + step)
        v.advance(t)
        s = v.sensors()
        if not out or out[-1][1:] != (s["fsc"], s["fso"]):
            out.append((t, s["fsc"], s["fso"]))
    return out


def test_a_delayed_switch_reports_each_change_that_late():
    v = valve(delay=7 * MS)
    v.write(0, {"C": False, "O": True})
    changes = readings(v, 2 * S, step=1)
    # the contact of fsc opens after 40 ms + 1 µs of travel, fso closes at 1.96 s
    assert changes[1] == (40 * MS + 1 + 7 * MS, False, False)
    assert changes[2] == (1960 * MS + 7 * MS, False, True)
    assert v.true_fso() and v.true_fsc() is False


def test_a_bouncing_switch_flips_then_settles_exactly_bounce_after_its_change():
    v = valve(bounce=20 * MS, bounce_seed=4)
    v.write(0, {"C": False, "O": True})
    changes = readings(v, 2 * S, step=1)
    breaks = [c for c in changes if c[0] < 1 * S]
    assert breaks[1][0] == 40 * MS + 1  # the first flip at the contact's change
    assert len(breaks) >= 4 and breaks[-1] == (40 * MS + 1 + 20 * MS, False, False)
    makes = [c for c in changes if c[0] > 1 * S]
    assert makes[0] == (1960 * MS, False, True)
    assert makes[-1] == (1980 * MS, False, True) and len(makes) >= 3


def test_bounce_patterns_each_edge_its_own_or_every_edge_alike():
    def makes(pattern: str) -> list[list[int]]:
        v = valve(bounce=20 * MS, bounce_seed=1, bounce_pattern=pattern)
        out = []
        for _ in range(4):
            v.write(v.t, {"C": False, "O": True})
            start = v.t
            changes = [t for t, _, _ in readings(v, start + 2 * S, step=1)][1:]
            out.append([t - changes[0] for t in changes])  # from fsc's break on
            v.write(v.t, {"C": False, "O": False})
            close_fully(v)
            v.advance(v.t + 100 * MS)
        return out

    same = makes("same")[1:]  # (the first opening starts at the end stop, 40 ms further)
    assert all(flips == same[0] for flips in same)
    each = makes("each")
    assert len({tuple(flips) for flips in each}) > 1
    assert makes("each") == each  # seeded: the same run again


def test_a_stuck_switch_or_a_glitch_overrides_the_bounce():
    v = valve(bounce=20 * MS, delay=3 * MS)
    v.inject("F2", 1)  # fsc stuck at 1 before the valve leaves
    v.write(0, {"C": False, "O": True})
    assert all(fsc for _, fsc, _ in readings(v, 1 * S, step=1))

"""The simulated palletizer: feeding, pushing rows, clamping, layers onto the pallet, the
elevator, damage events and faults."""

from __future__ import annotations

import pytest

from hmi.plant.sim.boxes import MM
from hmi.plant.sim.palletizer import ACTUATORS, SENSORS, Palletizer
from tests import plant_steps as steps

MS = 1_000
S = 1_000_000
FAST = {"first_box": 0, "interval_min": 1 * S, "interval_max": 1 * S}


def pal(**params) -> Palletizer:
    return Palletizer("P", {**FAST, **params})


def hold(p: Palletizer, until: int, **orders) -> None:
    steps.order(p, ACTUATORS, orders)
    while p.t < until:
        p.advance(min(until, p.t + 10 * MS))


def hold_until(p: Palletizer, sensor: str, value: bool = True, limit: int = 30 * S,
               **orders) -> int:
    return steps.hold_until(p, ACTUATORS, sensor, value, limit, 10 * MS, orders)


def damage(p: Palletizer) -> list[str]:
    return steps.damage(p)


def push_one(p: Palletizer) -> None:
    """Feed a box to the pusher, push it onto the plate, bring the pusher home."""
    hold_until(p, "box_ready", FEED=1)
    hold_until(p, "pusher_out", PUSH=1)
    hold_until(p, "pusher_home", RETRACT=1)


def build_layer(p: Palletizer, boxes: int = 3) -> None:
    for _ in range(boxes):
        push_one(p)


def raise_empty_pallet(p: Palletizer) -> None:
    hold_until(p, "layer_eye", ELEV_UP=1)
    hold(p, p.t)


def test_boxes_come_to_the_pusher_and_wait_there():
    p = pal()
    assert p.sensors()["pusher_home"] and p.sensors()["plate_closed"]
    assert p.sensors()["clamp_open"] and p.sensors()["elev_bottom"]
    assert p.sensors()["pallet_empty"]
    t = hold_until(p, "box_ready", FEED=1)
    assert t == pytest.approx(3_993_333, abs=10 * MS)  # (1500 - 2 - 300) mm at 300 mm/s
    hold(p, t + 5 * S, FEED=1)
    assert next(b.lo for b in p.feed) == 1200 * MM  # against the end stop
    assert not damage(p)


def test_each_push_shifts_the_row_and_a_fourth_drops_the_far_box():
    p = pal()
    build_layer(p, 3)
    assert len(p.row) == 3 and p.counters()["pushed"] == 3 and not damage(p)
    push_one(p)
    assert damage(p) == ["box_dropped"] and len(p.row) == 3


def test_feeding_into_the_pusher_while_it_is_out_is_damage():
    p = pal()
    hold_until(p, "box_ready", FEED=1)
    hold_until(p, "pusher_out", PUSH=1)
    hold(p, p.t + 3 * S, FEED=1, PUSH=1)
    assert damage(p) == ["box_against_pusher"]


def test_pushing_onto_the_open_plate_drops_the_box():
    p = pal()
    hold_until(p, "plate_open", PLATE_OPEN=1)
    hold_until(p, "box_ready", FEED=1)
    hold_until(p, "pusher_out", PUSH=1)
    assert damage(p) == ["box_dropped"]


def test_a_clamped_layer_placed_at_the_eye_lands_on_the_pallet():
    p = pal()
    raise_empty_pallet(p)
    build_layer(p)
    hold_until(p, "clamp_closed", CLAMP=1)
    hold_until(p, "plate_open", CLAMP=1, PLATE_OPEN=1)
    assert len(p.hanging) == 3 and not p.row
    hold_until(p, "clamp_open")
    assert p.layers == [3] and p.counters()["layers"] == 1 and not damage(p)
    assert p.sensors()["layer_eye"]  # the new layer stands in the plate's plane
    hold_until(p, "layer_eye", False, ELEV_DOWN=1)
    hold_until(p, "plate_closed", PLATE_CLOSE=1)
    assert not damage(p)


def test_opening_the_plate_under_an_unclamped_row_drops_it():
    p = pal()
    build_layer(p, 2)
    hold(p, p.t + 2 * S, PLATE_OPEN=1)
    assert damage(p) == ["layer_dropped"] and p.counters()["lost"] == 2


def test_letting_go_of_the_layer_high_above_the_load_drops_it():
    p = pal()
    build_layer(p)
    hold_until(p, "clamp_closed", CLAMP=1)
    hold_until(p, "plate_open", CLAMP=1, PLATE_OPEN=1)
    hold_until(p, "clamp_open")  # the pallet is still at the bottom
    assert damage(p) == ["layer_dropped"] and not p.layers


def test_raising_the_load_into_the_plate_crushes_it():
    p = pal()
    t = hold_until(p, "layer_eye", ELEV_UP=1)
    hold(p, t + 150 * MS, ELEV_UP=1)  # 15 mm from the eye to the plate at 100 mm/s
    assert not damage(p)
    hold(p, t + 250 * MS, ELEV_UP=1)
    assert damage(p) == ["load_crushed"]
    assert p.load_top() == p.plate_level


def test_closing_the_plate_on_the_placed_layer_is_damage():
    p = pal()
    raise_empty_pallet(p)
    build_layer(p)
    hold_until(p, "clamp_closed", CLAMP=1)
    hold_until(p, "plate_open", CLAMP=1, PLATE_OPEN=1)
    hold_until(p, "clamp_open")
    hold(p, p.t + 1 * S, PLATE_CLOSE=1)
    assert damage(p) == ["plate_into_layer"]


def test_pushing_with_the_clamp_closed_hits_it():
    p = pal()
    hold_until(p, "clamp_closed", CLAMP=1)
    hold_until(p, "pusher_out", CLAMP=1, PUSH=1)
    assert damage(p) == ["pusher_against_clamp"]


def test_a_loaded_pallet_is_exchanged_at_the_bottom():
    p = pal()
    raise_empty_pallet(p)
    build_layer(p)
    hold_until(p, "clamp_closed", CLAMP=1)
    hold_until(p, "plate_open", CLAMP=1, PLATE_OPEN=1)
    hold_until(p, "clamp_open")
    bottom = hold_until(p, "elev_bottom", ELEV_DOWN=1)
    assert not p.sensors()["pallet_empty"]
    t = hold_until(p, "pallet_empty")
    assert t - bottom == pytest.approx(2 * S, abs=20 * MS)  # exchange_time, elevator still
    assert p.counters()["pallets"] == 1 and p.counters()["boxes_palletized"] == 3
    assert not damage(p)


def test_the_elevator_held_down_at_the_bottom_is_damage_past_the_tolerance():
    p = pal()
    hold(p, 1 * S, ELEV_DOWN=1)
    assert not damage(p)
    hold(p, 1100 * MS, ELEV_DOWN=1)
    assert damage(p) == ["elevator_overrun"]


def test_both_directions_together():
    p = pal()
    hold(p, 100 * MS, PUSH=1, RETRACT=1, PLATE_OPEN=1, PLATE_CLOSE=1, ELEV_UP=1, ELEV_DOWN=1)
    assert sorted(damage(p)) == ["elevator_both_ways", "plate_both_ways", "pusher_both_ways"]


@pytest.mark.parametrize("code,order,sensor", [
    ("pusher_jam", "PUSH", "pusher_home"), ("plate_jam", "PLATE_OPEN", "plate_closed"),
    ("clamp_jam", "CLAMP", "clamp_open"), ("elevator_jam", "ELEV_UP", "elev_bottom")])
def test_jammed_actuators_stay_where_they_are(code, order, sensor):
    p = pal()
    p.inject(code, 0)
    hold(p, 3 * S, **{order: 1})
    assert p.sensors()[sensor]


def test_a_jammed_feed_brings_no_box():
    p = pal()
    p.inject("feed_jam", 0)
    hold(p, 10 * S, FEED=1)
    assert not p.sensors()["box_ready"]


@pytest.mark.parametrize("sensor", SENSORS)
def test_stuck_sensors(sensor):
    for value in (0, 1):
        p = pal()
        p.inject(f"{sensor}_stuck{value}", 0)
        hold(p, 6 * S, FEED=1)
        assert p.sensors()[sensor] is bool(value)


def test_every_declared_fault_is_injectable_and_runs_are_deterministic():
    assert len(Palletizer.FAULTS) == 5 + 2 * len(SENSORS)
    for code in Palletizer.FAULTS:
        p = pal()
        p.inject(code, 0)
        hold(p, 10 * MS, FEED=1)
        assert code in p.active_faults

    def run():
        p = pal()
        build_layer(p, 4)
        return [(e.time_us, e.kind) for e in p.events], p.counters()
    assert run() == run()

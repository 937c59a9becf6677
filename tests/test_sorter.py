"""The simulated sorting cell: boxes, sensors, the turntable, damage events and faults."""

from __future__ import annotations

import pytest

from hmi.plant.sim.boxes import MM, Box
from hmi.plant.sim.sorter import ACTUATORS, SENSORS, SortingCell
from tests import plant_steps as steps

MS = 1_000
S = 1_000_000
ONE_BOX = {"first_box": 0, "interval_min": 1000 * S, "interval_max": 1000 * S}


def cell(**params) -> SortingCell:
    return SortingCell("S", {**ONE_BOX, **params})


def hold(c: SortingCell, until: int, **orders) -> list[dict[str, bool]]:
    """Hold these orders (the others off) until `until`, sampling sensors every 5 ms."""
    steps.order(c, ACTUATORS, orders)
    samples = []
    while c.t < until:
        c.advance(min(until, c.t + 5 * MS))
        samples.append(c.sensors())
    return samples


def hold_until(c: SortingCell, sensor: str, value: bool = True, limit: int = 20 * S,
               **orders) -> int:
    return steps.hold_until(c, ACTUATORS, sensor, value, limit, 5 * MS, orders)


def damage(c: SortingCell) -> list[str]:
    return steps.damage(c)


def load(c: SortingCell) -> None:
    """What the functional program does: bring the box to the end, roll it onto the table."""
    hold_until(c, "entry_end", CONV_E=1)
    hold_until(c, "tt_back", CONV_E=1, ROLL_P=1)
    hold_until(c, "tt_back", False, CONV_E=1, ROLL_P=1)
    hold(c, c.t)


def test_a_box_arrives_and_reaches_the_entry_end_at_conveyor_speed():
    c = cell()
    assert c.sensors()["tt_0"] and not c.sensors()["tt_90"]
    hold(c, 5 * MS)
    assert c.boxes and c.sensors()["at_entry"]
    t = hold_until(c, "entry_end", CONV_E=1)
    # The box's front must travel 2000 - 10 - 400 = 1590 mm at 300 mm/s.
    assert t == pytest.approx(5_300_000, abs=10 * MS)
    assert not damage(c)


@pytest.mark.parametrize("p_high,high_seen", [(0.0, False), (1.0, True)])
def test_height_sensors(p_high, high_seen):
    c = cell(p_high=p_high)
    samples = hold(c, 8 * S, CONV_E=1)
    assert any(s["low"] for s in samples)
    assert any(s["high"] for s in samples) is high_seen


def test_loading_puts_the_box_on_the_table_clear_of_both_edges():
    c = cell()
    load(c)
    (b,) = c.boxes
    assert b.segment == "table" and 10 * MM <= b.lo <= 12 * MM
    s = c.sensors()
    assert not s["tt_back"] and not s["tt_front"] and not s["entry_end"]


def test_turning_with_a_box_half_on_the_table_shears_it():
    c = cell()
    hold_until(c, "entry_end", CONV_E=1)
    hold(c, c.t + 700 * MS, CONV_E=1, ROLL_P=1)  # the box now lies across the edge
    assert c.sensors()["tt_back"]
    hold(c, c.t + 500 * MS, ROT90=1)
    assert damage(c) == ["box_sheared"] and not c.boxes
    assert c.counters()["lost"] == 1


def test_turning_with_the_box_entirely_on_the_table_is_fine_and_unloads_right():
    c = cell(p_high=1.0)
    load(c)
    hold_until(c, "tt_90", ROT90=1)
    assert c.boxes[0].segment == "table"
    hold_until(c, "tt_front", ROLL_P=1, CONV_R=1)
    hold_until(c, "tt_front", False, ROLL_P=1, CONV_R=1)
    hold_until(c, "right_end", CONV_R=1)
    hold(c, c.t + 1 * S, CONV_R=1)
    assert c.counters()["sorted_right"] == 1 and c.counters()["missorted"] == 0
    assert not damage(c) and not c.boxes


def test_a_low_box_sent_right_is_missorted_not_damage():
    c = cell(p_high=0.0)
    load(c)
    hold_until(c, "tt_90", ROT90=1)
    hold(c, c.t + 6 * S, ROLL_P=1, CONV_R=1)
    assert c.counters()["sorted_right"] == 1 and c.counters()["missorted"] == 1
    assert not damage(c)
    assert [e.kind for e in c.events] == ["missorted"]


def test_unloading_left_with_the_rollers_backward():
    c = cell()
    load(c)
    hold_until(c, "tt_90", ROT90=1)
    hold(c, c.t + 6 * S, ROLL_M=1, CONV_L=1)
    assert c.counters()["sorted_left"] == 1 and not damage(c)


def test_a_box_barely_across_the_edge_is_pushed_off_not_sheared():
    c = cell()
    hold(c, 10 * MS)
    c.boxes[0].lo = c.entry_len - c.box_len + 15 * MM  # 15 mm onto the table (margin 20)
    hold(c, 2 * S, ROT90=1)
    assert not damage(c) and c.boxes and c.sensors()["tt_90"]


def test_coming_into_line_with_a_box_overhanging_onto_another_is_a_collision():
    c = cell()
    hold(c, 10 * MS)
    c.boxes[0].segment, c.boxes[0].lo = "right", 0  # waiting at the start of the right exit
    hold_until(c, "tt_90", ROT90=1)
    hold(c, c.t + 600 * MS, ROT0=1)  # half way back
    b = Box(99, c.box_len, False, "table", c.table_len - c.box_len + 50 * MM)
    c.boxes.append(b)  # overhangs the front edge by 50 mm
    hold_until(c, "tt_90", ROT90=1)
    assert damage(c) == ["box_collision"] and b not in c.boxes


def test_feeding_a_box_into_the_turned_table_is_damage():
    c = cell()
    hold_until(c, "tt_90", ROT90=1)
    hold(c, 10 * S, CONV_E=1)
    assert damage(c) == ["box_against_table"]
    assert c.boxes[0].lo + c.boxes[0].length == c.entry_len  # stopped against the table


def test_rolling_off_the_far_side_at_0_degrees_drops_the_box():
    c = cell()
    load(c)
    hold(c, c.t + 3 * S, ROLL_P=1)
    assert damage(c) == ["box_dropped"] and not c.boxes


def test_rolling_between_positions_drops_the_box():
    c = cell()
    load(c)
    hold(c, c.t + 600 * MS, ROT90=1)  # half way
    assert not c.sensors()["tt_0"] and not c.sensors()["tt_90"]
    hold(c, c.t + 3 * S, ROLL_M=1)
    assert damage(c) == ["box_dropped"]


def test_rolling_backward_at_0_degrees_crushes_the_box_against_the_next_one():
    c = cell(interval_min=3 * S, interval_max=3 * S)
    load(c)
    hold_until(c, "entry_end", CONV_E=1)  # the next box waits at the end of the entry
    hold(c, c.t + 2 * S, CONV_E=1, ROLL_M=1)
    assert damage(c) == ["boxes_crushed"]


def test_both_directions_together_are_damage_and_move_nothing():
    c = cell()
    hold(c, 1 * S, ROT90=1, ROT0=1, ROLL_P=1, ROLL_M=1)
    assert sorted(damage(c)) == ["rollers_both_ways", "turn_both_ways"]
    assert c.turn.pos == 0


def test_a_turn_order_held_at_the_end_stop_beyond_the_tolerance_is_damage():
    c = cell()
    t = hold_until(c, "tt_90", ROT90=1)
    hold(c, t + 1 * S, ROT90=1)
    assert not damage(c)
    hold(c, t + 1300 * MS, ROT90=1)
    assert damage(c) == ["turn_overrun"]


def test_the_cell_is_deterministic():
    def run():
        c = SortingCell("S", {"seed": 7})
        hold(c, 60 * S, CONV_E=1)
        return [(e.time_us, e.kind) for e in c.events], [(b.ident, b.lo) for b in c.boxes]
    assert run() == run()


# -- faults ----------------------------------------------------------------------------------

def test_table_jam_stalls_the_turn_and_is_damage_past_the_tolerance():
    c = cell()
    c.inject("table_jam", 0)
    hold(c, 2 * S, ROT90=1)
    assert c.sensors()["tt_0"] and c.turn.pos == 0
    assert damage(c) == ["turn_stall"]


def test_a_jammed_entry_conveyor_does_not_move_its_boxes():
    c = cell()
    hold(c, 10 * MS)
    c.inject("entry_jam", c.t)
    hold(c, 3 * S, CONV_E=1)
    assert [(b.segment, b.lo) for b in c.boxes] == [("entry", 0)]


def test_jammed_rollers_leave_the_box_on_the_table():
    c = cell()
    load(c)
    hold_until(c, "tt_90", ROT90=1)
    c.inject("rollers_jam", c.t)
    before = c.boxes[0].lo
    hold(c, c.t + 3 * S, ROLL_P=1, CONV_R=1)
    assert c.boxes[0].segment == "table" and c.boxes[0].lo == before


def test_a_blocked_exit_piles_boxes_up_instead_of_delivering_them():
    c = cell(p_high=1.0)
    c.inject("right_blocked", 0)
    load(c)
    hold_until(c, "tt_90", ROT90=1)
    hold(c, c.t + 8 * S, ROLL_P=1, CONV_R=1)
    assert c.counters()["sorted_right"] == 0
    assert c.sensors()["right_end"] and c.boxes[0].segment == "right"


@pytest.mark.parametrize("sensor", SENSORS)
def test_stuck_sensors(sensor):
    for value in (0, 1):
        c = cell()
        c.inject(f"{sensor}_stuck{value}", 1 * S)
        samples = hold(c, 8 * S, CONV_E=1)
        assert {s[sensor] for s in samples[200:]} == {bool(value)}


def test_every_declared_fault_is_injectable():
    assert len(SortingCell.FAULTS) == 7 + 2 * len(SENSORS)
    for code in SortingCell.FAULTS:
        c = cell()
        c.inject(code, 0)
        hold(c, 10 * MS, CONV_E=1)
        assert code in c.active_faults

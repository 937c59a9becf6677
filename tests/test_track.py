"""The plant components shared by the cells: boxes on a line of conveyors, the box source,
two-way travels."""

from __future__ import annotations

import itertools

from hmi.plant.sim.boxes import MM, Box, BoxSource
from hmi.plant.sim.track import EXIT, OPEN, WALL, Line, Segment, advance, covered
from hmi.plant.sim.travel import Travel, direction

S = 1_000_000


def box(ident: int, segment: str, lo_mm: float, length_mm: float = 400) -> Box:
    return Box(ident, round(length_mm * MM), False, segment, round(lo_mm * MM))


def test_a_box_moves_at_its_segments_speed_exactly():
    line = Line((Segment("belt", 0, 2000 * MM, 1, 300),), WALL, WALL)
    b = box(1, "belt", 0)
    advance(line, [b], 1 * S)
    assert b.lo == 300 * MM  # 300 mm/s for 1 s, in integer nanometres


def test_boxes_accumulate_against_the_wall_and_each_other():
    line = Line((Segment("belt", 0, 1000 * MM, 1, 300),), WALL, WALL)
    a, b = box(1, "belt", 500), box(2, "belt", 0)
    walls = []
    for _ in range(1000):
        walls += advance(line, [a, b], 5000).walls
    assert a.lo == 600 * MM and b.lo == 200 * MM  # touching, the front one at the wall
    assert walls and all(w[0] is a for w in walls)


def test_a_box_is_carried_by_the_segment_under_its_centre():
    line = Line((Segment("belt", 0, 1000 * MM, 1, 300), Segment("table", 1000 * MM, 500 * MM,
                                                               1, 0)), WALL, OPEN)
    b = box(1, "belt", 500)
    for _ in range(400):
        advance(line, [b], 5000)
    # Its centre crossed onto the stopped table: it stays across the edge.
    assert b.segment == "table" and b.lo == -200 * MM
    assert covered(line, [b], 990 * MM) and covered(line, [b], 1010 * MM)


def test_a_box_falls_once_its_centre_passes_an_open_end_and_exits_leave():
    line = Line((Segment("belt", 0, 1000 * MM, 1, 400),), OPEN, EXIT)
    b = box(1, "belt", 500)
    out = advance(line, [b], 300_000)  # front reaches 1020 mm: delivered
    assert out.delivered == [(b, "high")]
    line = Line((Segment("t", 0, 500 * MM, 1, 400),), OPEN, OPEN)
    b = box(2, "t", 200)
    assert not advance(line, [b], 100_000).fallen  # centre at 440 mm
    assert advance(line, [b], 200_000).fallen == [(b, "high")]


def test_touching_boxes_driven_toward_each_other_are_crushed():
    line = Line((Segment("a", 0, 1000 * MM, 1, 300), Segment("b", 1000 * MM, 1000 * MM, 1,
                                                            -300)), WALL, WALL)
    left, right = box(1, "a", 600), box(2, "b", 0)  # touching at 1000 mm
    out = advance(line, [left, right], 5000)
    assert out.crushed == [(left, right)]
    assert left.lo == 600 * MM and right.lo == 0


def test_a_reversed_segment_maps_its_axis_against_the_line():
    seg = Segment("left", 0, 1500 * MM, -1, 400)  # covers [-1500, 0] mm, moves boxes down
    line = Line((seg,), EXIT, OPEN)
    b = box(1, "left", 0)
    assert line.place(b) == -400 * MM
    advance(line, [b], 1 * S)
    assert b.lo == 400 * MM  # 400 mm further from the table along its own axis


def test_the_box_source_is_a_fixed_schedule():
    def schedule(seed: int) -> list[tuple[int, bool]]:
        source = BoxSource(seed, 500_000, 4 * S, 7 * S, 0.5)
        source.collect(120 * S)
        return list(source.queued)
    first = schedule(1)
    assert first == schedule(1) and first != schedule(2)
    assert first[0][0] == 500_000
    gaps = [b[0] - a[0] for a, b in itertools.pairwise(first)]
    assert all(4 * S <= g <= 7 * S and g % 1000 == 0 for g in gaps)
    assert {high for _, high in first} == {True, False}


def test_travel_moves_stalls_and_reports_a_stall_once():
    t = Travel(1 * S, 20_000)
    assert t.at_low and not t.at_high
    t.step(600_000, 1)
    assert t.pos == 600_000
    t.step(600_000, 1)
    assert t.at_high and t.stall_us == 200_000
    assert not t.stalled_beyond(1 * S)
    t.step(1 * S, 1)
    assert t.stalled_beyond(1 * S) and not t.stalled_beyond(1 * S)
    t.release()
    assert t.stall_us == 0


def test_travel_stops_at_an_obstacle_and_a_jam_moves_nothing():
    t = Travel(1 * S, 20_000)
    t.step(1 * S, 1, limit=300_000)
    assert t.pos == 300_000 and t.stall_us == 700_000
    t.step(10_000, 1, limit=200_000)  # the obstacle is below: no motion backwards
    assert t.pos == 300_000
    t.jammed = True
    t.step(1 * S, -1)
    assert t.pos == 300_000


def test_direction_of_two_orders():
    assert [direction(a, b) for a, b in ((1, 0), (0, 1), (0, 0), (1, 1))] == [1, -1, 0, 0]

"""The sorting-by-height cell of 004 §5.3 (the Factory I/O scene), as one simulated device.

Layout (lengths are parameters, in mm; defaults in brackets)::

                      left exit (CONV_L) [1500]
                               |
    entry conveyor (CONV_E) [2000]  ==>  [turntable 520]  (0°: in line with the entry)
                               |
                      right exit (CONV_R) [1500]

Boxes [400 long, low 150 / high 300 mm] are placed at the start of the entry conveyor on a
seeded schedule (:mod:`hmi.plant.sim.boxes`). The height sensors (`low` sees every box, `high`
only high ones) look across the entry conveyor at 1800 mm. The turntable receives a box at 0°
(rollers forward, ROLL_P, pull it off the entry conveyor), turns to 90° (ROT90; ROT0 turns it
back), then its rollers send the box to the right exit (ROLL_P) or the left exit (ROLL_M).
Boxes leave at the far end of an exit (taken by the next machine) and are counted there,
sorted or missorted (low boxes belong left, high boxes right).

Sensors are light beams 10 mm (`sensor_offset`) inside each edge: `entry_end` before the
entry conveyor's end, `tt_back`/`tt_front` inside the table's two edges (they turn with it;
at 90° the back edge faces the left exit), `left_in`/`right_in` at the start of each exit,
`left_end`/`right_end` at their far ends; `tt_0`/`tt_90` are the turntable's end switches.

Physics (:mod:`hmi.plant.sim.track`): a box is carried by the surface under its centre; boxes
accumulate against each other; the turntable connects to the entry conveyor only at 0° and to
the exits only at 90° (within `turn_band` of its end).

Damage events (objective, recorded once per occurrence):
  rollers_both_ways / turn_both_ways  ROLL_P and ROLL_M, or ROT90 and ROT0, ordered together
  turn_overrun    a rotation order held against its end stop beyond `stall_tolerance`
  turn_stall      a rotation order held on a jammed turntable beyond `stall_tolerance`
  box_sheared     the table turned out of line while a box lay across one of its edges
                  (more than `shear_margin` on each side)
  box_against_table  the entry conveyor drove a box into the side of a turntable not at 0°
  box_dropped     a box fell off an edge of the table with no conveyor in line there
  boxes_crushed   two touching boxes driven toward each other
  box_collision   the table came into line with a box overhanging an edge onto another box
Not damage: missorted (a box delivered to the wrong exit).

Faults: entry_jam, rollers_jam, table_jam, left_jam, right_jam (that drive does not move);
left_blocked / right_blocked (boxes are no longer taken away at that exit's end: they pile up);
and for every sensor S, S_stuck0 / S_stuck1.
"""

from __future__ import annotations

import itertools
from collections.abc import Hashable
from typing import Any

from hmi.plant.sim.boxes import MM, Box, BoxSource
from hmi.plant.sim.cell import SteppedCell
from hmi.plant.sim.track import (
    EXIT,
    NEVER,
    OPEN,
    TOUCH,
    WALL,
    Line,
    Segment,
    advance,
    beam_steps,
)
from hmi.plant.sim.travel import Travel, direction, free_steps
from hmi.project.device_models import SORTING_CELL
from hmi.timefmt import seconds

SENSORS = SORTING_CELL.sensors
ACTUATORS = SORTING_CELL.actuators

def _mm(value: float) -> int:
    return round(value * MM)


class SortingCell(SteppedCell, model=SORTING_CELL):
    def __init__(self, name: str, params: dict[str, Any]):
        super().__init__(name, params)
        p = self.params
        self.entry_len = _mm(p["entry_length"])
        self.table_len = _mm(p["table_length"])
        self.exit_len = _mm(p["exit_length"])
        self.box_len = _mm(p["box_length"])
        self.offset = _mm(p["sensor_offset"])
        self.height_at = _mm(p["height_sensor_at"])
        self.margin = _mm(p["shear_margin"])
        self.gap = _mm(p["min_gap"])
        self.speeds = {name: int(p[name]) for name in ("entry_speed", "roller_speed",
                                                       "exit_speed")}
        self.sees_low = p["low_box"] >= p["low_beam"]
        self.sees_high = {True: p["high_box"] >= p["high_beam"],
                          False: p["low_box"] >= p["high_beam"]}
        self.turn = Travel(int(p["turn_time"]), int(p["turn_band"]))
        self.source = BoxSource(int(p["seed"]), int(p["first_box"]), int(p["interval_min"]),
                                int(p["interval_max"]), float(p["p_high"]))
        self.boxes: list[Box] = []
        self.contacts: set[tuple[str, int, int]] = set()
        self.both = {"rollers": False, "turn": False}
        self.count = dict.fromkeys(("arrived", "sorted_left", "sorted_right", "missorted",
                                    "lost"), 0)
        self.lines: list[Line] = []
        self.alignment = self._alignment()
        self._build_lines()

    # -- geometry ---------------------------------------------------------------------------
    def _alignment(self) -> int:
        """0 or 90 when the table is in line with the entry or with the exits, else -1."""
        if self.turn.at_low:
            return 0
        if self.turn.at_high:
            return 90
        return -1

    def _segment(self, name: str, start: int, direction_: int) -> Segment:
        o = self.orders
        if name == "entry":
            speed = self.speeds["entry_speed"] if o["CONV_E"] and "entry_jam" not in self.jams \
                else 0
            return Segment(name, start, self.entry_len, direction_, speed)
        if name == "table":
            roll = 0 if "rollers_jam" in self.jams else direction(o["ROLL_P"], o["ROLL_M"])
            return Segment(name, start, self.table_len, direction_,
                           roll * self.speeds["roller_speed"])
        side = name  # left / right
        running = o["CONV_L" if side == "left" else "CONV_R"] and f"{side}_jam" not in self.jams
        return Segment(name, start, self.exit_len, direction_,
                       self.speeds["exit_speed"] if running else 0)

    def _build_lines(self) -> None:
        """The lines of conveyors as the table's position connects them now."""
        e, t = self.entry_len, self.table_len
        left_end = WALL if "left_blocked" in self.jams else EXIT
        right_end = WALL if "right_blocked" in self.jams else EXIT
        if self.alignment == 0:
            lines = [Line((self._segment("entry", 0, 1), self._segment("table", e, 1)),
                          WALL, OPEN)]
        else:
            lines = [Line((self._segment("entry", 0, 1),), WALL, WALL)]
        if self.alignment == 90:
            lines.append(Line((self._segment("left", 0, -1), self._segment("table", 0, 1),
                               self._segment("right", t, 1)), left_end, right_end))
        else:
            lines.append(Line((self._segment("left", 0, -1),), left_end, OPEN))
            lines.append(Line((self._segment("right", t, 1),), OPEN, right_end))
            if self.alignment != 0:
                lines.append(Line((self._segment("table", 0, 1),), OPEN, OPEN))
        self.lines = lines
        self.beams = self._beams()

    def _on(self, line: Line) -> list[Box]:
        segs = line.by_segment
        return [b for b in self.boxes if b.segment in segs]

    def _beams(self) -> dict[str, tuple[int, int]]:
        """Each beam sensor as (index of its line, line coordinate), for the lines now."""
        o, t, x, e = self.offset, self.table_len, self.exit_len, self.entry_len
        spots = {"at_entry": ("entry", self.box_len // 2), "height": ("entry", self.height_at),
                 "entry_end": ("entry", e - o), "tt_back": ("table", o),
                 "tt_front": ("table", t - o), "left_in": ("left", o),
                 "left_end": ("left", x - o), "right_in": ("right", o),
                 "right_end": ("right", x - o)}
        beams = {}
        for sensor, (segment, at) in spots.items():
            for index, line in enumerate(self.lines):
                seg = line.by_segment.get(segment)
                if seg is not None:
                    beams[sensor] = (index, seg.start + at if seg.direction > 0
                                     else seg.start - at)
        return beams

    # -- sensors ----------------------------------------------------------------------------
    def true_sensors(self) -> dict[str, bool]:
        spans: list[list[tuple[int, int, Box]]] = [[] for _ in self.lines]
        for index, line in enumerate(self.lines):
            for box in self._on(line):
                lo = line.place(box)
                spans[index].append((lo, lo + box.length, box))
        seen = {}
        under_height: list[Box] = []
        for sensor, (index, x) in self.beams.items():
            hit = [box for lo, hi, box in spans[index] if lo <= x <= hi]
            if sensor == "height":
                under_height = hit
            else:
                seen[sensor] = bool(hit)
        seen["low"] = self.sees_low and bool(under_height)
        seen["high"] = any(self.sees_high[b.high] for b in under_height)
        seen["tt_0"] = self.turn.at_low
        seen["tt_90"] = self.turn.at_high
        return seen

    # -- physics ----------------------------------------------------------------------------
    def _plan_glide(self, dt: int) -> _Glide | None:
        return _Glide.plan(self, dt)

    def _step(self, dt: int) -> None:
        drive = direction(self.orders["ROT90"], self.orders["ROT0"])
        self.turn.step(dt, drive)
        if drive and self.turn.stalled_beyond(int(self.params["stall_tolerance"])):
            tolerance = seconds(self.params["stall_tolerance"])
            if self.turn.jammed:
                self.record(self.t, "turn_stall", True, f"rotation order held on a jammed "
                            f"turntable for more than {tolerance} s")
            else:
                end = "90°" if drive > 0 else "0°"
                self.record(self.t, "turn_overrun", True, f"rotation order held against the "
                            f"{end} end stop for more than {tolerance} s")
        alignment = self._alignment()
        if alignment != self.alignment:
            if self.alignment != -1:
                self._shear()
            self.alignment = alignment
            self._build_lines()
            if alignment != -1:
                self._collide_on_alignment()
        contacts: set[tuple[str, int, int]] = set()
        for line in self.lines:
            if line.moving:
                contacts |= self._move(line, dt)
        self.contacts = contacts
        self._feed()

    def _shear(self) -> None:
        """The table leaves a line: boxes across its edges (in the old line) are sheared."""
        for line in self.lines:
            table = line.by_segment.get("table")
            if table is None or len(line.segments) == 1:
                continue
            for box in list(self._on(line)):
                lo = line.place(box)
                hi = lo + box.length
                for edge in (table.low, table.high):
                    if lo < edge < hi and min(edge - lo, hi - edge) >= self.margin:
                        where = "entry" if self.alignment == 0 else (
                            "left exit" if edge == table.low else "right exit")
                        self._lose(box, "box_sheared", f"{box.kind} box {box.ident} sheared "
                                   f"between the turning table and the {where}")
                        break

    def _collide_on_alignment(self) -> None:
        """The table comes into line: a box overhanging its edge onto another box is hit."""
        for line in self.lines:
            if "table" not in line.by_segment or len(line.segments) == 1:
                continue
            placed = sorted(((line.place(b), b) for b in self._on(line)),
                            key=lambda item: item[0])
            for (x1, b1), (x2, b2) in itertools.pairwise(placed):
                if x1 + b1.length - x2 > TOUCH and b1 in self.boxes and b2 in self.boxes:
                    hit = b1 if b1.segment == "table" else b2
                    self._lose(hit, "box_collision", f"{hit.kind} box {hit.ident} overhanging "
                               "the table hit a box as the table came into line")

    def _move(self, line: Line, dt: int) -> set[tuple[str, int, int]]:
        """Move the boxes of one line; return the contacts (crushes, walls) now held."""
        boxes = self._on(line)
        outcome = advance(line, boxes, dt)
        contacts = set()
        for a, b in outcome.crushed:
            key = ("crush", a.ident, b.ident)
            contacts.add(key)
            if key not in self.contacts:
                self.record(self.t, "boxes_crushed", True, f"boxes {a.ident} and {b.ident} "
                            "pressed together by drives running toward each other")
        for box, end in outcome.walls:
            key = ("wall", box.ident, 0)
            contacts.add(key)
            if end == "high" and line.segments[-1].name == "entry" and key not in self.contacts:
                self.record(self.t, "box_against_table", True, f"{box.kind} box {box.ident} "
                            "driven into the side of the turntable (table not at 0°)")
        for box, _end in outcome.fallen:
            self._lose(box, "box_dropped", f"{box.kind} box {box.ident} fell off the "
                       f"{'far' if self.alignment == 0 else 'unaligned'} edge of the turntable")
        for box, end in outcome.delivered:
            self.boxes.remove(box)
            side = "left" if end == "low" else "right"
            self.count[f"sorted_{side}"] += 1
            if box.high != (side == "right"):
                self.count["missorted"] += 1
                self.record(self.t, "missorted", False, f"{box.kind} box {box.ident} "
                            f"delivered to the {side} exit")
        return contacts

    def _lose(self, box: Box, kind: str, detail: str) -> None:
        if box in self.boxes:
            self.boxes.remove(box)
            self.count["lost"] += 1
            self.record(self.t, kind, True, detail)

    def _feed(self) -> None:
        self.source.collect(self.t)
        if not self.source.queued:
            return
        room = self.box_len + self.gap
        if any(b.segment == "entry" and b.lo < room for b in self.boxes):
            return
        ident, high, due = self.source.pop()
        self.boxes.append(Box(ident, self.box_len, high, "entry", 0, due))
        self.count["arrived"] += 1

    # -- orders and faults -------------------------------------------------------------------
    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        o = self.orders
        for key, a, b, text in (("rollers", "ROLL_P", "ROLL_M", "rollers forward and backward"),
                                ("turn", "ROT90", "ROT0", "turn to 90° and back to 0°")):
            both = o[a] and o[b]
            if both and not self.both[key]:
                self.record(t, f"{key}_both_ways", True, f"{text} ordered together")
            self.both[key] = both
        if "ROT90" in changed or "ROT0" in changed:
            self.turn.release()
        self._build_lines()
        self._glide = None

    def _jams_changed(self) -> None:
        if self.turn.jammed and "table_jam" not in self.jams:
            self.turn.release()  # repaired: a stall starts counting again
        self.turn.jammed = "table_jam" in self.jams
        self._build_lines()
        self._glide = None

    # -- reporting --------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        self.settle()
        where = {"entry": 0, "table": 0, "left": 0, "right": 0}
        for box in self.boxes:
            where[box.segment] += 1
        return {"angle": round(90 * self.turn.pos / self.turn.travel, 1), **where,
                "queued": len(self.source.queued)}

    def counters(self) -> dict[str, int]:
        return dict(self.count)

    def state_key(self) -> Hashable:
        self.settle()
        return (self.turn.pos, len(self.source.queued), tuple([b.segment for b in self.boxes]))

    def counters_key(self) -> Hashable:
        return tuple(self.count.values())



class _Glide:
    """A run of physics steps that are plain translations, found after a normal step.

    Why: boxes glide along the conveyors most of the time, and a step of :meth:`_step` then
    only adds `speed * dt` to each box's position, and the table's turn (if ordered) only adds
    `dt` to its position, or to its stall clock while it is held at an end or jammed;
    everything else it checks (the table coming into or out of line, an end switch, a stall
    running out, boxes touching, walls, exits, drops, a box's centre reaching another surface,
    a box due from the source) cannot happen for a number of steps that integer arithmetic on
    the positions gives exactly, and no light beam or end switch changes either. For those
    steps the cell moves the boxes and the table and keeps the sensors it computed. Anything
    done to the cell otherwise (new orders, a fault, a repair, a box or the table moved or a
    box added by hand: :meth:`SteppedCell.touch`) ends the glide.
    """

    __slots__ = ("boxes", "dt", "lines", "movers", "sensors", "stalling", "steps", "turning")

    def __init__(self, cell: SortingCell, dt: int, steps: int,
                 movers: list[tuple[Box, int]], turning: int, stalling: bool):
        self.dt = dt
        self.steps = steps
        self.movers = movers  # (box, its position's change per step on its own axis)
        self.turning = turning  # +1 / -1: the table turns freely that way at every step
        self.stalling = stalling  # a turn order held without motion: its stall clock runs
        self.boxes = cell.boxes
        self.lines = cell.lines  # rebuilt (a new list) whenever the conveyors change
        self.sensors = cell.true_sensors()

    def holds(self, cell: SortingCell) -> bool:
        """The cell holds the boxes and lines the glide moves on (else a state was restored
        from copies; a change by hand ends the glide: SteppedCell.touch)."""
        return cell.boxes is self.boxes and cell.lines is self.lines

    def carry(self, cell: SortingCell, count: int) -> None:
        """`count` steps: each box on a running surface moves on, the table turns on (or its
        stall clock runs); nothing else happens."""
        for box, delta in self.movers:
            box.lo += delta * count
        turn = cell.turn
        if self.turning:  # full steps' motion (Travel.step)
            turn.pos += self.turning * self.dt * count
            turn.stall_us = 0
            turn.stall_reported = False
        elif self.stalling:
            turn.stall_us += self.dt * count

    @classmethod
    def plan(cls, cell: SortingCell, dt: int) -> _Glide | None:
        """How many steps of `dt` from now are plain translations (None: not even one)."""
        if cell.contacts:
            return None
        source = cell.source
        if source.queued:
            return None
        steps = (source.next_due - 1 - cell.t) // dt  # steps ending before the next box
        if steps <= 0:
            return None
        drive = direction(cell.orders["ROT90"], cell.orders["ROT0"])
        turn = cell.turn
        turning, stalling = 0, False
        if turn.can_move(drive):  # short of an end switch, of the end, of either end
            turning = drive
            steps = min(steps, free_steps(turn, drive, dt, (), NEVER))
        elif drive:  # held at an end or jammed: short of the stall being reported
            stalling = True
            if not turn.stall_reported:
                tolerance = int(cell.params["stall_tolerance"])
                steps = min(steps, (tolerance - turn.stall_us) // dt)
        if steps <= 0:
            return None
        beams: dict[int, list[int]] = {}
        for index, x in cell.beams.values():
            beams.setdefault(index, []).append(x)
        movers: list[tuple[Box, int]] = []
        for index, line in enumerate(cell.lines):
            boxes = cell._on(line)
            if not boxes or not line.moving:
                continue  # boxes that do not move: nothing changes there
            placed = sorted(((line.place(b), b) for b in boxes), key=lambda item: item[0])
            moves = []
            for x, box in placed:
                centre = x + box.length // 2
                seg = line.segment_at(centre)
                if seg is None or seg.name != box.segment:
                    return None
                d = seg.velocity * dt
                moves.append(d)
                steps = min(steps, _within(centre, d, seg.low, seg.high - 1))
                hi = x + box.length
                if line.high_end != OPEN:  # the front stays short of an exit or wall
                    limit = line.high - 1 if line.high_end == EXIT else line.high
                    steps = min(steps, _within(hi, d, -NEVER, limit))
                if line.low_end != OPEN:
                    limit = line.low + 1 if line.low_end == EXIT else line.low
                    steps = min(steps, _within(x, d, limit, NEVER))
                for beam in beams.get(index, ()):
                    steps = min(steps, beam_steps(x, hi, beam, d) - 1)
                if steps <= 0:
                    return None
                movers.append((box, seg.speed * dt))
            for k in range(len(placed) - 1):  # boxes closing in stay apart (not touching)
                closing = moves[k] - moves[k + 1]
                if closing > 0:
                    gap = placed[k + 1][0] - (placed[k][0] + placed[k][1].length)
                    steps = min(steps, (gap - TOUCH - 1) // closing)
                    if steps <= 0:
                        return None
        return cls(cell, dt, steps, movers, turning, stalling)


def _within(x: int, d: int, low: int, high: int) -> int:
    """How many steps of d keep x in [low, high] (x is in it now, else 0)."""
    if not low <= x <= high:
        return 0
    if d > 0:
        return (high - x) // d
    if d < 0:
        return (x - low) // -d
    return NEVER


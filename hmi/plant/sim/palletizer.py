"""The palletizer of Riera et al. (001, the ITS PLC scene), as one simulated device.

    feed conveyor (FEED) ==> [pusher zone]      the pusher (PUSH / RETRACT) pushes the box in
                                 |              its zone sideways onto the layer plate, where
                            layer plate         each push shifts the row by one box; a full
                      (PLATE_OPEN / PLATE_CLOSE)  row (`per_layer` boxes) is one layer
                     clamp (CLAMP) around it    the clamp grips the layer, the plate slides
                                 |              open, the elevator brings the pallet's top just
                       pallet on the elevator   under it, the clamp lets go: the layer lands
                        (ELEV_UP / ELEV_DOWN)   on the pallet; the elevator lowers one layer

Boxes arrive on the feed conveyor on a seeded schedule (:mod:`hmi.plant.sim.boxes`) and stop
against its end stop in the pusher zone (`box_ready`). The pusher, the plate and the clamp
are travels between two end switches (:mod:`hmi.plant.sim.travel`): pusher_home/pusher_out,
plate_closed/plate_open, clamp_open/clamp_closed (the clamp is spring-opened: CLAMP off opens
it). The elevator's position is in µs of motor time at `elevator_speed`; `layer_eye` is a
light beam `eye_offset` mm under the plate that sees the top of the load on the pallet;
`elev_bottom` is its low end switch. At the bottom, an elevator left still for
`exchange_time` has its loaded pallet taken away and an empty one put in its place
(`pallet_empty`).

Damage events (objective, once per occurrence):
  pusher_both_ways / plate_both_ways / elevator_both_ways  both directions ordered together
  box_against_pusher  the feed drove a box into the pusher while it was out of home
  pusher_against_clamp  the pusher was out (past half its stroke) while the clamp was not open
  box_dropped     a box pushed onto an open plate, or off the far end of a full row
  layer_dropped   the plate slid open under boxes the clamp did not hold, or the clamp let a
                  layer fall from higher than `max_drop` onto the load
  plate_into_layer  the plate closed against a layer standing in its way
  load_crushed    the elevator pressed the load against the plate or the held layer beyond
                  `crush_tolerance`
  elevator_overrun  ELEV_DOWN held at the bottom beyond `stall_tolerance`
  elevator_stall  an elevator order held on a jammed elevator beyond `stall_tolerance`
Not damage: partial_layer (a layer of fewer than `per_layer` boxes placed on the pallet).

Faults: feed_jam, pusher_jam, plate_jam, clamp_jam, elevator_jam (that drive does not move);
and for every sensor S, S_stuck0 / S_stuck1.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any

from hmi.plant.sim.boxes import MM, Box, BoxSource
from hmi.plant.sim.cell import SteppedCell
from hmi.plant.sim.track import NEVER, WALL, Line, Segment, advance, beam_steps
from hmi.plant.sim.travel import Travel, direction, free_steps
from hmi.project.device_models import PALLETIZER
from hmi.timefmt import seconds

SENSORS = PALLETIZER.sensors
ACTUATORS = PALLETIZER.actuators
TRANSFER = 0.9  # fraction of the pusher's stroke where the box leaves the feed for the plate

class Palletizer(SteppedCell, model=PALLETIZER):
    def __init__(self, name: str, params: dict[str, Any]):
        super().__init__(name, params)
        p = self.params
        self.feed_len = round(p["feed_length"] * MM)
        self.box_len = round(p["box_length"] * MM)
        self.layer_h = round(p["box_height"] * MM)
        self.per_layer = int(p["per_layer"])
        self.pallet_h = round(p["pallet_height"] * MM)
        self.lift_speed = int(p["elevator_speed"])  # nm per µs of motor time
        lift = round(p["lift_range"] * MM)
        self.plate_level = lift + self.pallet_h  # an empty pallet at the top meets the plate
        self.eye = round(p["eye_offset"] * MM)
        self.max_drop = round(p["max_drop"] * MM)
        band = int(p["band"])
        self.pusher = Travel(int(p["push_time"]), band)
        self.plate = Travel(int(p["plate_time"]), band)
        self.clamp = Travel(int(p["clamp_time"]), band)
        self.lift = Travel(lift // self.lift_speed, band,
                           pos=min(round(p["initial_height"] * MM), lift) // self.lift_speed)
        self.source = BoxSource(int(p["seed"]), int(p["first_box"]), int(p["interval_min"]),
                                int(p["interval_max"]), 0.0)
        self.feed: list[Box] = []
        self.pushing: Box | None = None  # the box in front of the moving pusher
        self.row: list[Box] = []  # on the plate, index 0 next to the pusher
        self.hanging: list[Box] = []  # a layer held by the clamp over the open plate
        self.gripped = False
        self.layers: list[int] = []  # boxes per layer on the pallet
        self.flags: set[str] = set()  # situations already reported while they last
        self.both: dict[str, bool] = {}
        self.idle_bottom_us = 0
        self._lines: dict[tuple[int, int], Line] = {}  # the feed's line per (speed, length)
        self.count = dict.fromkeys(("arrived", "pushed", "layers", "pallets",
                                    "boxes_palletized", "lost"), 0)

    # -- geometry ---------------------------------------------------------------------------
    def load_top(self) -> int:
        """Height (nm from the elevator's bottom) of the top of the pallet and its layers."""
        top: int = (self.lift.pos * self.lift_speed + self.pallet_h
                    + len(self.layers) * self.layer_h)
        return top

    def _feed_line(self) -> Line:
        speed = int(self.params["feed_speed"]) if self.orders["FEED"] and \
            "feed_jam" not in self.jams else 0
        length = self.feed_len if self.pusher.at_low else self.feed_len - self.box_len
        line = self._lines.get((speed, length))  # a line is immutable: built once per shape
        if line is None:
            line = self._lines[speed, length] = Line((Segment("feed", 0, length, 1, speed),),
                                                     WALL, WALL)
        return line

    def _in_zone(self) -> Box | None:
        """The box against the end stop, in front of the pusher (within 2 mm of the stop)."""
        for box in self.feed:
            if box.lo + box.length >= self.feed_len - 2 * MM:
                return box
        return None

    # -- sensors ----------------------------------------------------------------------------
    def true_sensors(self) -> dict[str, bool]:
        half = self.box_len // 2
        return {
            "box_in": any(b.lo <= half <= b.lo + b.length for b in self.feed),
            "box_ready": self.pushing is not None or self._in_zone() is not None,
            "pusher_home": self.pusher.at_low,
            "pusher_out": self.pusher.at_high,
            "plate_closed": self.plate.at_low,
            "plate_open": self.plate.at_high,
            "clamp_open": self.clamp.at_low,
            "clamp_closed": self.clamp.at_high,
            "layer_eye": self.load_top() >= self.plate_level - self.eye,
            "elev_bottom": self.lift.at_low,
            "pallet_empty": not self.layers,
        }

    # -- physics ----------------------------------------------------------------------------
    def _plan_glide(self, dt: int) -> _Glide | None:
        return _Glide.plan(self, dt)

    def _step(self, dt: int) -> None:
        o = self.orders
        self._move_pusher(dt, direction(o["PUSH"], o["RETRACT"]))
        self._move_clamp(dt, 1 if o["CLAMP"] else -1)
        self._move_plate(dt, direction(o["PLATE_OPEN"], o["PLATE_CLOSE"]))
        self._move_lift(dt, direction(o["ELEV_UP"], o["ELEV_DOWN"]))
        self._move_feed(dt)
        self._arrive()
        self._check_collisions()

    def _move_pusher(self, dt: int, drive: int) -> None:
        was_home = self.pusher.at_low
        before = self.pusher.pos
        self.pusher.step(dt, drive)
        if was_home and not self.pusher.at_low:
            self._pusher_leaves_home()
        point = int(self.pusher.travel * TRANSFER)
        if before < point <= self.pusher.pos and self.pushing is not None:
            box, self.pushing = self.pushing, None
            self._onto_plate(box)
        if self.pusher.at_low and self.pushing is not None:  # pulled back before the transfer
            box, self.pushing = self.pushing, None
            box.lo = self.feed_len - box.length
            self.feed.append(box)

    def _pusher_leaves_home(self) -> None:
        box = self._in_zone()
        if box is not None:
            self.feed.remove(box)
            self.pushing = box
        wall = self.feed_len - self.box_len
        for other in list(self.feed):  # a box half into the zone is struck by the blade
            if other.lo + other.length > wall:
                self.feed.remove(other)
                self._lose(1, "box_against_pusher", f"box {other.ident} struck by the "
                           "pusher: it was half into the pusher zone")

    def _onto_plate(self, box: Box) -> None:
        self.count["pushed"] += 1
        if not self.plate.at_low:
            self._lose(1, "box_dropped", f"box {box.ident} pushed onto the open layer plate "
                       "and fell")
            return
        self.row.insert(0, box)
        if len(self.row) > self.per_layer:
            far = self.row.pop()
            self._lose(1, "box_dropped", f"box {far.ident} pushed off the far end of a full "
                       "row")

    def _move_clamp(self, dt: int, drive: int) -> None:
        was_closed = self.clamp.at_high
        self.clamp.step(dt, drive)
        if self.clamp.at_high and not was_closed and self.row and self.plate.at_low:
            self.gripped = True
        if was_closed and not self.clamp.at_high:
            self.gripped = False
            if self.hanging:
                self._release_layer()

    def _release_layer(self) -> None:
        layer, self.hanging = self.hanging, []
        drop = self.plate_level - self.load_top()
        if drop > self.max_drop:
            self._lose(len(layer), "layer_dropped", f"a layer of {len(layer)} boxes let go "
                       f"{drop // MM} mm above the load")
            return
        self.layers.append(len(layer))
        self.count["layers"] += 1
        if len(layer) < self.per_layer:
            self.record(self.t, "partial_layer", False, f"a layer of {len(layer)} boxes "
                        f"(of {self.per_layer}) placed on the pallet")

    def _move_plate(self, dt: int, drive: int) -> None:
        half = self.plate.travel // 2
        before = self.plate.pos
        self.plate.step(dt, drive)
        if before < half <= self.plate.pos and self.row:  # the row loses its support
            if self.gripped:
                self.hanging, self.row = self.row, []
            else:
                self._lose(len(self.row), "layer_dropped", f"the plate opened under "
                           f"{len(self.row)} boxes the clamp did not hold")
                self.row = []
        if drive < 0 and self.load_top() > self.plate_level and self.plate.pos < before:
            self._once("plate_into_layer", True, "the layer plate closed against the layer "
                       "standing on the pallet")
        else:
            self.flags.discard("plate_into_layer")
        if self.plate.at_low and self.hanging:  # the plate slid back under the held layer
            self.row, self.hanging = self.hanging, []

    def _move_lift(self, dt: int, drive: int) -> None:
        limit = None
        if drive > 0:  # the load cannot rise through the plate or the held layer
            room = self.plate_level - self.load_top()
            limit = self.lift.pos + max(room, 0) // self.lift_speed
        self.lift.step(dt, drive, limit)
        if drive and self.lift.jammed:
            if self.lift.stalled_beyond(int(self.params["stall_tolerance"])):
                self.record(self.t, "elevator_stall", True, "elevator order held on a jammed "
                            f"elevator for more than {seconds(self.params['stall_tolerance'])} s")
        elif drive > 0 and self.lift.stalled_beyond(int(self.params["crush_tolerance"])):
            what = "the held layer" if self.hanging else "the layer plate"
            self.record(self.t, "load_crushed", True, f"the elevator pressed the load against "
                        f"{what} for more than {seconds(self.params['crush_tolerance'])} s")
        if drive < 0 and self.lift.stalled_beyond(int(self.params["stall_tolerance"])):
            self.record(self.t, "elevator_overrun", True, "ELEV_DOWN held at the bottom for "
                        f"more than {seconds(self.params['stall_tolerance'])} s")
        if drive == 0 and self.lift.at_low:
            self.idle_bottom_us += dt
            if self.layers and self.idle_bottom_us >= int(self.params["exchange_time"]):
                self.count["pallets"] += 1
                self.count["boxes_palletized"] += sum(self.layers)
                self.layers = []
        else:
            self.idle_bottom_us = 0

    def _move_feed(self, dt: int) -> None:
        line = self._feed_line()
        if not line.segments[0].speed:
            self.flags.discard("box_against_pusher")
            return
        outcome = advance(line, self.feed, dt)
        if outcome.walls and not self.pusher.at_low:
            box = outcome.walls[0][0]
            self._once("box_against_pusher", True, f"the feed drove box {box.ident} into the "
                       "pusher while it was out")
        else:
            self.flags.discard("box_against_pusher")

    def _arrive(self) -> None:
        self.source.collect(self.t)
        if not self.source.queued:
            return
        if any(b.lo < self.box_len + self.box_len // 2 for b in self.feed):
            return
        ident, _, due = self.source.pop()
        self.feed.append(Box(ident, self.box_len, False, "feed", 0, due))
        self.count["arrived"] += 1

    def _check_collisions(self) -> None:
        if self.pusher.pos > self.pusher.travel // 2 and not self.clamp.at_low:
            self._once("pusher_against_clamp", True, "the pusher was out while the clamp was "
                       "not open")
        else:
            self.flags.discard("pusher_against_clamp")

    def _once(self, kind: str, damage: bool, detail: str) -> None:
        if kind not in self.flags:
            self.flags.add(kind)
            self.record(self.t, kind, damage, detail)

    def _lose(self, boxes: int, kind: str, detail: str) -> None:
        self.count["lost"] += boxes
        self.record(self.t, kind, True, detail)

    # -- orders and faults -------------------------------------------------------------------
    def _orders_changed(self, t: int, changed: dict[str, bool]) -> None:
        o = self.orders
        for key, a, b in (("pusher", "PUSH", "RETRACT"), ("plate", "PLATE_OPEN", "PLATE_CLOSE"),
                          ("elevator", "ELEV_UP", "ELEV_DOWN")):
            both = o[a] and o[b]
            if both and not self.both.get(key):
                self.record(t, f"{key}_both_ways", True, f"{a} and {b} ordered together")
            self.both[key] = both
        if "ELEV_UP" in changed or "ELEV_DOWN" in changed:
            self.lift.release()
        self._glide = None

    def _jams_changed(self) -> None:
        for code, travel in (("pusher_jam", self.pusher), ("plate_jam", self.plate),
                             ("clamp_jam", self.clamp), ("elevator_jam", self.lift)):
            if travel.jammed and code not in self.jams:
                travel.release()  # repaired: a stall starts counting again
            travel.jammed = code in self.jams
        self._glide = None

    # -- reporting --------------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        self.settle()
        return {
            "feed": len(self.feed) + (self.pushing is not None),
            "row": len(self.row),
            "hanging": len(self.hanging),
            "pallet_layers": len(self.layers),
            "elevator_mm": self.lift.pos * self.lift_speed // MM,
            "pusher": self.pusher.percent,
            "plate": self.plate.percent,
            "clamp": self.clamp.percent,
            "queued": len(self.source.queued),
        }

    def counters(self) -> dict[str, int]:
        return dict(self.count)

    def state_key(self) -> Hashable:
        self.settle()
        return (len(self.feed), self.pushing is None, len(self.row), len(self.hanging),
                len(self.layers), self.lift.pos, self.pusher.pos, self.plate.pos, self.clamp.pos,
                len(self.source.queued))

    def counters_key(self) -> Hashable:
        return tuple(self.count.values())



class _Glide:
    """A run of physics steps in which things only move on: boxes on the feed, travels.

    Why: most of a palletizer's time the pusher, the plate, the clamp and the elevator are at
    rest (held at an end, or not driven), and a step of :meth:`Palletizer._step` then only
    moves the free boxes on the feed by `speed * dt`, adds `dt` to the clocks of the orders
    held against an end stop (and to the elevator's time idle at the bottom), and repeats
    what it already decided (a flag raised stays raised, one cleared stays clear). Integer
    arithmetic on the positions and clocks gives how many steps stay so: no box reaching
    another, the end stop, the light beam or the pusher zone, no stall or exchange time
    running out, no box due from the source. For those steps the cell does just that and
    keeps its sensors. New orders, a fault, a repair or a change by hand
    (:meth:`SteppedCell.touch`) end the glide.
    """

    __slots__ = ("clocks", "discard", "dt", "feed", "idle", "movers", "moving", "sensors",
                 "steps")

    def __init__(self, cell: Palletizer, dt: int, steps: int, movers: list[tuple[Box, int]],
                 clocks: list[Travel], moving: list[tuple[Travel, int]], idle: bool,
                 wall_hit: bool):
        self.dt = dt
        self.steps = steps
        self.clocks = clocks  # travels held against an end: their stall time runs
        self.idle = idle  # the elevator idles at the bottom: its idle time runs
        # The flags a step clears, the same at every step of the glide: what they test (the
        # front box pressed against the end stop, the pusher home or past half its stroke,
        # the clamp open) stays as it is, the glide ends before any of it changes.
        discard = ["plate_into_layer"]  # no plate motion against the layer
        if not (wall_hit and not cell.pusher.at_low):
            discard.append("box_against_pusher")
        if not (cell.pusher.pos > cell.pusher.travel // 2 and not cell.clamp.at_low):
            discard.append("pusher_against_clamp")
        self.discard = tuple(discard)
        self.feed = cell.feed
        self.movers = movers  # (box, its move per step)
        self.moving = moving  # (travel, drive): travels short of every mark they pass
        self.sensors = cell.true_sensors()

    def holds(self, cell: Palletizer) -> bool:
        """The cell holds the feed the glide moves (else a state was restored from copies;
        a change by hand ends the glide: SteppedCell.touch)."""
        return cell.feed is self.feed

    def carry(self, cell: Palletizer, count: int) -> None:
        """`count` steps of _step when only clocks and gliding boxes change: each adds the
        same to a position or a clock, and the flags it sets or clears are the same at every
        one of them (nothing they test changes during the glide)."""
        dt = self.dt * count
        for box, delta in self.movers:
            box.lo += delta * count
        for travel in self.clocks:
            travel.stall_us += dt
        for travel, drive in self.moving:  # full steps' motion (Travel.step)
            travel.pos += drive * dt
            travel.stall_us = 0
            travel.stall_reported = False
        if self.idle:
            cell.idle_bottom_us += dt
        cell.flags.difference_update(self.discard)

    @classmethod
    def plan(cls, cell: Palletizer, dt: int) -> _Glide | None:
        """How many steps of `dt` from now change only clocks and gliding boxes."""
        o = cell.orders
        clocks: list[Travel] = []  # held against an end: their stall time runs
        moving: list[tuple[Travel, int]] = []  # (travel, drive) moving freely
        steps = NEVER
        pusher, plate, lift = cell.pusher, cell.plate, cell.lift
        plate_drive = direction(o["PLATE_OPEN"], o["PLATE_CLOSE"])
        if plate_drive < 0 and plate.can_move(-1) and cell.load_top() > cell.plate_level:
            return None  # the plate closes against the layer: an event at every step
        for travel, drive, marks in (
                (pusher, direction(o["PUSH"], o["RETRACT"]),
                 (int(pusher.travel * TRANSFER), pusher.travel // 2 + 1)),
                (cell.clamp, 1 if o["CLAMP"] else -1, ()),
                (plate, plate_drive, (plate.travel // 2,))):
            if travel.can_move(drive):
                moving.append((travel, drive))
                steps = min(steps, free_steps(travel, drive, dt, marks, NEVER))
            elif drive:
                clocks.append(travel)
        drive = direction(o["ELEV_UP"], o["ELEV_DOWN"])
        if drive:
            # The load meets the plate at `top` (the lift's limit), the eye sees it from
            # `eye`, and it rises above the plate past `above` (positions of the lift).
            base = cell.pallet_h + len(cell.layers) * cell.layer_h
            speed = cell.lift_speed
            top = (cell.plate_level - base) // speed
            eye = -(-(cell.plate_level - cell.eye - base) // speed)
            above = top + 1
            limit = lift.pos + max(cell.plate_level - cell.load_top(), 0) // speed
            if lift.can_move(drive) and (drive < 0 or limit > lift.pos):
                moving.append((lift, drive))
                steps = min(steps, free_steps(lift, drive, dt, (top, eye, above), NEVER))
            else:
                clocks.append(lift)
                tolerances = []
                if lift.jammed:
                    tolerances.append(int(cell.params["stall_tolerance"]))
                elif drive > 0:
                    tolerances.append(int(cell.params["crush_tolerance"]))
                if drive < 0:
                    tolerances.append(int(cell.params["stall_tolerance"]))
                if not lift.stall_reported:
                    for tolerance in tolerances:
                        steps = min(steps, (tolerance - lift.stall_us) // dt)
        idle = drive == 0 and lift.at_low
        if idle and cell.layers:
            steps = min(steps, (int(cell.params["exchange_time"]) - 1 - cell.idle_bottom_us)
                        // dt)
        source = cell.source
        steps = min(steps, (source.next_due - 1 - cell.t) // dt)
        line = cell._feed_line()
        segment = line.segments[0]
        d = segment.velocity * dt
        movers: list[tuple[Box, int]] = []
        wall_hit = False
        room = cell.box_len + cell.box_len // 2
        if d:
            half = cell.box_len // 2
            zone = cell.feed_len - 2 * MM
            ahead, ahead_static = line.high, True  # the next thing up: the end stop first
            for k, box in enumerate(sorted(cell.feed, key=lambda b: b.lo, reverse=True)):
                hi = box.lo + box.length
                static = ahead_static and hi == ahead  # pressed against it: stays
                if static:
                    wall_hit = wall_hit or k == 0
                else:
                    if hi > ahead:
                        return None
                    if ahead_static:  # it reaches what is ahead (a box gliding too keeps
                        steps = min(steps, (ahead - hi) // d)  # its distance)
                    steps = min(steps, beam_steps(box.lo, hi, half, d) - 1)
                    if hi < zone:  # the pusher zone
                        steps = min(steps, (zone - 1 - hi) // d)
                    movers.append((box, segment.speed * dt))
                ahead, ahead_static = box.lo, static
            if wall_hit and not cell.pusher.at_low and "box_against_pusher" not in cell.flags:
                return None
        if source.queued:  # a queued box waits while a box is in the way at the entrance
            moves = {id(b): delta for b, delta in movers}
            blocked = 0  # for how many steps: a box that stays, or the last one to move on
            for b in cell.feed:
                if b.lo < room:
                    delta = moves.get(id(b), 0)
                    if not delta:
                        blocked = NEVER
                        break
                    blocked = max(blocked, (room - 1 - b.lo) // delta)
            if blocked <= 0:
                return None  # it is placed at the next step
            steps = min(steps, blocked)
        if steps <= 0:
            return None
        return cls(cell, dt, steps, movers, clocks, moving, idle, wall_hit)

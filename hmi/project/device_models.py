"""The simulated device models a project can name, as data: ports, parameters, faults, counters.

The loader checks a project's `plant:` section against this catalogue (a model's name, the
parameters it takes and their ranges, the ports a variable may be bound to, the faults a
scenario may inject, the counters a campaign may count) without importing any simulation: a
project that names a valve loads without the palletizer's physics, and project/ stays below
plant/ (tests/test_layers.py). Each model in hmi/plant/sim/ implements one entry and says
which (``class Valve(SimDevice, model=VALVE)``); tests/test_plant_contract.py checks that
both sides name the same models and counters.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from hmi.timefmt import format_duration

Problems = list[tuple[str, str, str]]  # (parameter, what is wrong, what was expected)


@dataclass(frozen=True)
class ParamSpec:
    """One model parameter: its type ("duration", "number", "bool", "choice", "device"),
    default, help. A "device" parameter names another device of the plant (a pipe or a shaft
    the PLC does not see); its `choices` are the models it may name."""

    kind: str
    default: Any
    help: str
    choices: tuple[str, ...] = ()
    minimum: float | None = None  # (a duration: 0 allows a zero duration)
    maximum: float | None = None
    # A physical quantity a real device varies in (travel time, speed, bounce): a project
    # may declare the range it is built for (`tolerances:`, hmi/project/tolerances.py).
    tolerable: bool = False
    # Parameters that vary in proportion with this one (a slower valve crosses its end
    # switch's band more slowly too: `travel` scales `switch_band`).
    scales: tuple[str, ...] = ()
    # It matters only once a fault is injected (where F13 jams the valve): fault-free runs
    # across the band leave it at its value, and it is varied for that fault alone.
    faults_only: bool = False
    fault: str = ""  # the fault it acts through (faults_only)


@dataclass(frozen=True)
class FaultSpec:
    code: str
    description: str
    component: str  # the part that fails: a sensor port name or "actuator"


def _no_problems(values: Mapping[str, Any]) -> Problems:
    return []


@dataclass(frozen=True)
class Movement:
    """One operation of a device that maintenance times: an order and the end sensor that
    says it is done (the valve's open order O and its open end switch fso). The historian
    records, per movement, the time from the order's rising edge to the sensor's (its
    travel time) and the count of movements completed (hmi.history.catalogue)."""

    name: str  # in the operator's words: "opening"
    order: str  # the actuator port whose rising edge starts it
    end: str  # the sensor port whose rising edge ends it


@dataclass(frozen=True)
class DeviceModel:
    """What a project may say about one model, and what the loader checks it against."""

    name: str
    description: str
    sensors: tuple[str, ...]  # ports the PLC reads
    actuators: tuple[str, ...]  # ports the PLC writes
    params: Mapping[str, ParamSpec]
    faults: Mapping[str, FaultSpec]
    counters: tuple[str, ...]  # work achieved, as the plant reports it (SimPlant.counters)
    # Values that do not fit together (each alone passed its ParamSpec), given every
    # parameter's value (the defaults and the project's).
    problems: Callable[[Mapping[str, Any]], Problems] = _no_problems
    interruption_fault: str | None = None  # the fault that interrupts its task (sweeps)
    movements: tuple[Movement, ...] = ()  # what maintenance times (travel, operations)

    def param_problems(self, params: Mapping[str, Any]) -> Problems:
        """(parameter, what is wrong, what was expected), reported at the parameter."""
        return self.problems({**{k: p.default for k, p in self.params.items()}, **params})


def jam_and_stuck_faults(jams: dict[str, str], sensors: tuple[str, ...]
                         ) -> dict[str, FaultSpec]:
    """The usual fault list of a cell model: each drive's jam, each sensor stuck at 0 or 1."""
    faults = {code: FaultSpec(code, text, "actuator") for code, text in jams.items()}
    for sensor in sensors:
        for value in (0, 1):
            code = f"{sensor}_stuck{value}"
            faults[code] = FaultSpec(code, f"sensor {sensor} stuck at {value}", sensor)
    return faults


def interval_problems(values: Mapping[str, Any]) -> Problems:
    """A box schedule's parameters (hmi/plant/sim/boxes.py): the source draws whole
    milliseconds between interval_min and interval_max."""
    low, high = values["interval_min"], values["interval_max"]
    if low < 1000:
        return [("interval_min", f"the shortest interval between boxes is "
                 f"{format_duration(low)}", "at least 1ms")]
    if low > high:
        return [("interval_max", f"interval_max ({format_duration(high)}) is shorter than "
                 f"interval_min ({format_duration(low)})", "interval_min <= interval_max")]
    return []


def tank_problems(values: Mapping[str, Any]) -> Problems:
    problems = []
    if not values["low"] < values["high"]:
        problems.append(("high", f"the high switch ({values['high']:g} L) is not above the "
                         f"low one ({values['low']:g} L)", "low < high"))
    if values["high"] > values["capacity"]:
        problems.append(("high", f"the high switch ({values['high']:g} L) is above the "
                         f"capacity ({values['capacity']:g} L)", "high <= capacity"))
    if values["initial"] > values["capacity"]:
        problems.append(("initial", f"the initial volume ({values['initial']:g} L) is above "
                         f"the capacity ({values['capacity']:g} L)", "initial <= capacity"))
    return problems


# -- valve (hmi/plant/sim/valve.py) ------------------------------------------------------------

VALVE = DeviceModel(
    name="valve",
    description="motorised valve, orders C (close) and O (open), end switches fsc and fso",
    sensors=("fsc", "fso"),
    actuators=("C", "O"),
    params={
        "travel": ParamSpec("duration", 2_000_000, "time to go from one end to the other",
                            tolerable=True, scales=("switch_band",)),
        "switch_band": ParamSpec("duration", 40_000,
                                 "end switch made within this much travel of its end"),
        "stall_tolerance": ParamSpec("duration", 1_000_000,
                                     "an order held without motion longer than this is damage"),
        "glitch": ParamSpec("duration", 300_000, "length of an unexpected sensor change"),
        "block_at": ParamSpec("number", 0.5, "fraction of travel where F13 jams the valve",
                              minimum=0.05, maximum=0.95, tolerable=True, faults_only=True,
                              fault="F13"),
        "initial": ParamSpec("choice", "closed", "initial position", ("closed", "open")),
        "delay": ParamSpec("duration", 0, "an end switch reports each change this late",
                           minimum=0, tolerable=True),
        "bounce": ParamSpec("duration", 0, "an end switch chatters this long after each "
                            "change before it settles", minimum=0, tolerable=True),
        "bounce_seed": ParamSpec("number", 0, "seed of the bounce's flips", minimum=0,
                                 maximum=2**31),
        "bounce_pattern": ParamSpec("choice", "each", "'each': every switch change bounces "
                                    "its own way; 'same': every make (and every break) of a "
                                    "switch alike", ("each", "same")),
    },
    faults={
        "F1": FaultSpec("F1", "sensor fsc stuck at 0", "fsc"),
        "F2": FaultSpec("F2", "sensor fsc stuck at 1", "fsc"),
        "F3": FaultSpec("F3", "sensor fso stuck at 0", "fso"),
        "F4": FaultSpec("F4", "sensor fso stuck at 1", "fso"),
        "F5": FaultSpec("F5", "valve stuck at the closed (fsc) position", "actuator"),
        "F6": FaultSpec("F6", "valve stuck at the open (fso) position", "actuator"),
        "F7": FaultSpec("F7", "unexpected fsc from 0 to 1", "fsc"),
        "F8": FaultSpec("F8", "unexpected fsc from 1 to 0", "fsc"),
        "F9": FaultSpec("F9", "unexpected fso from 0 to 1", "fso"),
        "F10": FaultSpec("F10", "unexpected fso from 1 to 0", "fso"),
        "F11": FaultSpec("F11", "unexpected movement from fsc to fso", "actuator"),
        "F12": FaultSpec("F12", "unexpected movement from fso to fsc", "actuator"),
        "F13": FaultSpec("F13", "valve blocked between fsc and fso", "actuator"),
    },
    counters=("cycles", "opens", "closes"),
    movements=(Movement("opening", "O", "fso"), Movement("closing", "C", "fsc")),
)

# -- conveyor and robot (hmi/plant/sim/conveyor.py, robot.py) --------------------------------

CONVEYOR = DeviceModel(
    name="conveyor",
    description="belt conveyor: pusher order d, release order, end sensor B, halt sensor",
    sensors=("B", "halted"),
    actuators=("d", "release"),
    params={
        "transport": ParamSpec("duration", 3_500_000,
                               "travel time of a pallet from the pusher to B at full speed",
                               tolerable=True),
        "slip_speed": ParamSpec("number", 0.5, "belt speed while slipping (fault slip), as a "
                                "fraction of full speed", minimum=0.05, maximum=1.0),
        "initial": ParamSpec("choice", "empty", "'loaded': a pallet waits at B at start",
                             ("empty", "loaded")),
    },
    faults={
        "stop": FaultSpec("stop", "conveyor halted (for the injected duration, else for good)",
                          "actuator"),
        "slip": FaultSpec("slip", "belt slipping: pallets move at slip_speed (for the injected "
                          "duration, else for good)", "actuator"),
    },
    counters=("pallets", "handed"),
    movements=(Movement("transfer", "d", "B"),),
    interruption_fault="stop",
)

ROBOT = DeviceModel(
    name="robot",
    description="transfer robot: order G, free sensor e, end sensor R, halt sensor",
    sensors=("e", "R", "halted"),
    actuators=("G",),
    params={
        "work": ParamSpec("duration", 2_500_000, "duration of a transfer (the robot task)",
                          tolerable=True),
        "return_time": ParamSpec("duration", 500_000, "time to return home after G drops",
                                 tolerable=True),
    },
    faults={
        "stop": FaultSpec("stop", "robot paused (for the injected duration, else for good)",
                          "actuator"),
        "skip": FaultSpec("skip", "part missing: the robot ends its task at once", "actuator"),
    },
    counters=("transfers",),
    movements=(Movement("transfer", "G", "R"),),
    interruption_fault="stop",
)

# -- pump and tank (hmi/plant/sim/pump.py, tank.py) -------------------------------------------

PUMP = DeviceModel(
    name="pump",
    description="pump: run order P, running feedback run; draws from a tank, two valved lines",
    sensors=("run",),
    actuators=("P",),
    params={
        "flow": ParamSpec("number", 10.0, "delivery with a line fully open, in L/s",
                          minimum=0.1, maximum=1000, tolerable=True),
        "suction": ParamSpec("device", None, "the tank it draws from", ("tank",)),
        "valve_a": ParamSpec("device", None, "the valve on discharge line a", ("valve",)),
        "to_a": ParamSpec("device", None, "the tank line a leads into", ("tank",)),
        "valve_b": ParamSpec("device", None, "the valve on discharge line b", ("valve",)),
        "to_b": ParamSpec("device", None, "the tank line b leads into", ("tank",)),
        "min_opening": ParamSpec("number", 0.05, "below this total opening of its lines "
                                 "the pump is dead-headed", minimum=0.0, maximum=1.0),
        "dry_level": ParamSpec("number", 5.0, "below this many litres in the suction tank "
                               "the pump draws air", minimum=0),
        "deadhead_tolerance": ParamSpec("duration", 1_000_000, "running against closed "
                                        "valves longer than this is damage"),
        "dry_tolerance": ParamSpec("duration", 2_000_000, "running dry longer than this is "
                                   "damage"),
    },
    faults={
        "no_start": FaultSpec("no_start", "pump does not start (motor or contactor failure)",
                              "actuator"),
        "welded": FaultSpec("welded", "pump contactor welded: it does not stop", "actuator"),
    },
    counters=("starts",),
    movements=(Movement("start", "P", "run"),),
)

TANK = DeviceModel(
    name="tank",
    description="tank with low and high level switches and a gravity drain",
    sensors=("low", "high"),
    actuators=(),
    params={
        "capacity": ParamSpec("number", 100.0, "volume in litres at which it spills over",
                              minimum=1),
        "initial": ParamSpec("number", 0.0, "volume at start, in litres", minimum=0),
        "low": ParamSpec("number", 20.0, "height of the low switch, in litres", minimum=0),
        "high": ParamSpec("number", 80.0, "height of the high switch, in litres", minimum=0),
        "drain": ParamSpec("number", 0.0, "gravity drain through the hand valve, in L/s",
                           minimum=0, maximum=1000, tolerable=True),
        "drain_to": ParamSpec("device", None, "the tank the drain runs into (default: out of "
                              "the cell)", ("tank",)),
    },
    faults={
        "low_stuck0": FaultSpec("low_stuck0", "low level switch stuck at 0", "low"),
        "low_stuck1": FaultSpec("low_stuck1", "low level switch stuck at 1", "low"),
        "high_stuck0": FaultSpec("high_stuck0", "high level switch stuck at 0", "high"),
        "high_stuck1": FaultSpec("high_stuck1", "high level switch stuck at 1", "high"),
    },
    counters=("fills",),
    problems=tank_problems,
)

# -- sorting cell (hmi/plant/sim/sorter.py) ---------------------------------------------------

SORTER_SENSORS = ("at_entry", "low", "high", "entry_end", "tt_back", "tt_front", "tt_0", "tt_90",
                  "left_in", "left_end", "right_in", "right_end")
SORTER_ACTUATORS = ("CONV_E", "ROLL_P", "ROLL_M", "ROT90", "ROT0", "CONV_L", "CONV_R")

_SORTER_JAMS = {
    "entry_jam": "entry conveyor jammed (does not move)",
    "rollers_jam": "turntable rollers jammed (do not turn)",
    "table_jam": "turntable jammed (does not rotate)",
    "left_jam": "left exit conveyor jammed (does not move)",
    "right_jam": "right exit conveyor jammed (does not move)",
    "left_blocked": "left exit blocked at its end (boxes are no longer taken away)",
    "right_blocked": "right exit blocked at its end (boxes are no longer taken away)",
}


def _length(default: float, text: str, low: float = 10, high: float = 20_000) -> ParamSpec:
    return ParamSpec("number", default, text + " (mm)", minimum=low, maximum=high)


SORTING_CELL = DeviceModel(
    name="sorting_cell",
    description="box sorting by height: entry conveyor, turntable, left and right exits",
    sensors=SORTER_SENSORS,
    actuators=SORTER_ACTUATORS,
    params={
        "entry_length": _length(2000, "length of the entry conveyor"),
        "table_length": _length(520, "length of the turntable along its rollers"),
        "exit_length": _length(1500, "length of each exit conveyor"),
        "box_length": _length(400, "length of a box"),
        "height_sensor_at": _length(1800, "position of the height sensors on the entry"),
        "sensor_offset": _length(10, "edge sensors sit this far inside their edge", 1, 100),
        "shear_margin": _length(20, "a box across an edge by more than this on both sides "
                                "is sheared when the table turns", 1, 200),
        "min_gap": _length(150, "room a new box needs behind the last one", 0, 2000),
        "entry_speed": ParamSpec("number", 300, "entry conveyor speed (mm/s)", minimum=10,
                                 maximum=3000, tolerable=True),
        "roller_speed": ParamSpec("number", 300, "turntable roller speed (mm/s)", minimum=10,
                                  maximum=3000, tolerable=True),
        "exit_speed": ParamSpec("number", 400, "exit conveyor speed (mm/s)", minimum=10,
                                maximum=3000, tolerable=True),
        "turn_time": ParamSpec("duration", 1_200_000, "time for the table to turn 90°",
                               tolerable=True, scales=("turn_band",)),
        "turn_band": ParamSpec("duration", 20_000,
                               "an end switch is made (and the table in line) within this"),
        "stall_tolerance": ParamSpec("duration", 1_000_000,
                                     "a rotation order held without motion beyond this is "
                                     "damage"),
        "first_box": ParamSpec("duration", 500_000, "when the first box is due"),
        "interval_min": ParamSpec("duration", 4_000_000, "shortest time between two boxes"),
        "interval_max": ParamSpec("duration", 7_000_000, "longest time between two boxes"),
        "p_high": ParamSpec("number", 0.5, "probability that a box is high", minimum=0,
                            maximum=1),
        "seed": ParamSpec("number", 1, "seed of the box schedule", minimum=0, maximum=2**31),
        "low_box": _length(150, "height of a low box", 20, 1000),
        "high_box": _length(300, "height of a high box", 20, 1000),
        "low_beam": _length(50, "height of the low sensor's beam", 1, 1000),
        "high_beam": _length(220, "height of the high sensor's beam", 1, 1000),
    },
    faults=jam_and_stuck_faults(_SORTER_JAMS, SORTER_SENSORS),
    counters=("arrived", "sorted_left", "sorted_right", "missorted", "lost"),
    movements=(Movement("turn to 90°", "ROT90", "tt_90"),
               Movement("turn back to 0°", "ROT0", "tt_0")),
    problems=interval_problems,
)

# -- palletizer (hmi/plant/sim/palletizer.py) -------------------------------------------------

PALLETIZER_SENSORS = ("box_in", "box_ready", "pusher_home", "pusher_out", "plate_closed",
                      "plate_open", "clamp_open", "clamp_closed", "layer_eye", "elev_bottom",
                      "pallet_empty")
PALLETIZER_ACTUATORS = ("CLAMP", "PLATE_CLOSE", "PLATE_OPEN", "ELEV_DOWN", "ELEV_UP", "RETRACT",
                        "PUSH", "FEED")

_PALLETIZER_JAMS = {
    "feed_jam": "feed conveyor jammed (does not move)",
    "pusher_jam": "pusher jammed (does not move)",
    "plate_jam": "layer plate jammed (does not move)",
    "clamp_jam": "clamp jammed (does not move)",
    "elevator_jam": "elevator jammed (does not move)",
}


def _number(default: float, text: str, low: float, high: float,
            tolerable: bool = False) -> ParamSpec:
    return ParamSpec("number", default, text, minimum=low, maximum=high, tolerable=tolerable)


PALLETIZER = DeviceModel(
    name="palletizer",
    description="palletizer: feed conveyor, pusher, layer plate, clamp, elevator",
    sensors=PALLETIZER_SENSORS,
    actuators=PALLETIZER_ACTUATORS,
    params={
        "feed_length": _number(1500, "length of the feed conveyor (mm)", 500, 20_000),
        "feed_speed": _number(300, "feed conveyor speed (mm/s)", 10, 3000, tolerable=True),
        "box_length": _number(300, "length of a box along the feed (mm)", 50, 2000),
        "box_height": _number(200, "height of a box, hence of a layer (mm)", 20, 2000),
        "per_layer": _number(3, "boxes in a full row on the plate (one layer)", 1, 12),
        "lift_range": _number(1000, "elevator travel (mm)", 100, 10_000),
        "pallet_height": _number(150, "height of an empty pallet (mm)", 10, 1000),
        "elevator_speed": _number(100, "elevator speed (mm/s)", 10, 2000, tolerable=True),
        "eye_offset": _number(15, "the layer eye looks this far under the plate (mm)", 1, 200),
        "max_drop": _number(30, "a layer let go from higher than this is damage (mm)", 1, 500),
        "push_time": ParamSpec("duration", 1_000_000, "pusher stroke time", tolerable=True),
        "plate_time": ParamSpec("duration", 1_000_000, "time for the plate to open or close",
                                tolerable=True),
        "clamp_time": ParamSpec("duration", 500_000, "time for the clamp to close or open",
                                tolerable=True),
        "band": ParamSpec("duration", 20_000, "end switches are made within this much travel"),
        "crush_tolerance": ParamSpec("duration", 50_000, "the load pressed against the plate "
                                     "longer than this is damage"),
        "stall_tolerance": ParamSpec("duration", 1_000_000, "an elevator order held without "
                                     "motion (at the bottom, or jammed) longer than this is "
                                     "damage"),
        "exchange_time": ParamSpec("duration", 2_000_000, "time to exchange a loaded pallet "
                                   "for an empty one at the bottom"),
        "first_box": ParamSpec("duration", 500_000, "when the first box is due"),
        "interval_min": ParamSpec("duration", 4_000_000, "shortest time between two boxes"),
        "interval_max": ParamSpec("duration", 8_000_000, "longest time between two boxes"),
        "seed": _number(1, "seed of the box schedule", 0, 2**31),
        "initial_height": _number(0, "initial elevator height (mm from the bottom)", 0, 10_000),
    },
    faults=jam_and_stuck_faults(_PALLETIZER_JAMS, PALLETIZER_SENSORS),
    counters=("arrived", "pushed", "layers", "pallets", "boxes_palletized", "lost"),
    movements=(Movement("push", "PUSH", "pusher_out"),
               Movement("retract", "RETRACT", "pusher_home"),
               Movement("plate opening", "PLATE_OPEN", "plate_open"),
               Movement("plate closing", "PLATE_CLOSE", "plate_closed"),
               Movement("clamping", "CLAMP", "clamp_closed")),
    problems=interval_problems,
)

# Model name (as written in a project) -> its description; hmi/plant/sim/models.py names the
# class implementing each.
DEVICE_MODELS: Mapping[str, DeviceModel] = {
    m.name: m for m in (VALVE, CONVEYOR, ROBOT, SORTING_CELL, PALLETIZER, PUMP, TANK)}

"""The pump and tank models of the CISPI subsystem (hmi/plant/sim/pump.py, hmi/plant/sim/tank.py):
water is conserved, switches follow the level (or their fault), flows follow the valves'
openings, and the damage events come when the physics says, not before."""

from __future__ import annotations

import textwrap
from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hmi.errors import ProjectError
from hmi.plant.sim.pump import Pump, opening
from hmi.plant.sim.tank import NL_PER_L, Tank
from hmi.plant.sim.valve import Valve
from hmi.project.loader import load_project

S = 1_000_000
MS = 1_000


def rig(t1: float = 95, t2: float = 20, drain: float = 4, **pump):
    """T1 -> P -> V1 -> T2 and P -> V2 -> T1, T2 draining into T1: the subsystem's layout."""
    tanks = {"T1": Tank("T1", {"capacity": 120, "initial": t1, "low": 20, "high": 60}),
             "T2": Tank("T2", {"capacity": 100, "initial": t2, "low": 40, "high": 70,
                               "drain": drain, "drain_to": "T1"})}
    valves = {"V1": Valve("V1", {}), "V2": Valve("V2", {})}
    p = Pump("P", {"flow": 15, "suction": "T1", "valve_a": "V1", "to_a": "T2",
                   "valve_b": "V2", "to_b": "T1", **pump})
    devices = {**tanks, **valves, "P": p}
    for device in devices.values():
        device.link(devices)
    return devices


def run(devices, until: int, step: int = 10 * MS, start: int = 0) -> None:
    for t in range(start, until + 1, step):
        for device in devices.values():
            device.advance(t)


def total(devices) -> int:
    return devices["T1"].volume + devices["T2"].volume


def test_the_drain_moves_water_from_t2_to_t1_and_conserves_it():
    d = rig()
    before = total(d)
    run(d, 3 * S)
    assert d["T2"].volume == 20 * NL_PER_L - 12 * NL_PER_L  # 4 L/s for 3 s
    assert total(d) == before
    run(d, 10 * S, start=3 * S)
    assert d["T2"].volume == 0 and total(d) == before  # it stops when empty


def test_switches_follow_the_level_unless_stuck():
    d = rig(t2=75, drain=0)
    t2 = d["T2"]
    assert t2.sensors() == {"low": True, "high": True}
    t2.inject("high_stuck0", 1 * S)
    t2.inject("low_stuck1", 1 * S)
    t2.advance(1 * S)
    t2.take(70 * NL_PER_L)
    assert t2.sensors() == {"low": True, "high": False}


def test_overflow_is_recorded_once_per_episode_and_the_excess_spills():
    t2 = Tank("T2", {"capacity": 100, "initial": 95, "low": 40, "high": 70})
    t2.add(1 * S, 10 * NL_PER_L)
    t2.add(2 * S, 1 * NL_PER_L)
    assert t2.volume == 100 * NL_PER_L and t2.spilled == 6 * NL_PER_L
    assert [(e.kind, e.damage, e.time_us) for e in t2.events] == [("overflow", True, S)]
    t2.take(40 * NL_PER_L)  # back under the high switch: a new episode may come
    t2.add(3 * S, 50 * NL_PER_L)
    assert len(t2.events) == 2


def test_a_fill_is_counted_once_even_if_the_level_wavers_at_the_switch():
    t2 = Tank("T2", {"capacity": 100, "initial": 60, "low": 40, "high": 70})
    t2.add(0, 995 * NL_PER_L // 100)  # 69.95 L
    for _ in range(5):  # the pump and the drain, one after the other, at the switch
        t2.add(0, NL_PER_L // 10)
        t2.take(NL_PER_L // 10)
    assert t2.fills == 1
    t2.take(3 * NL_PER_L)  # 2 % of the capacity under the switch re-arms it
    t2.add(0, 31 * NL_PER_L // 10)
    assert t2.fills == 2


def test_valve_opening_counts_from_the_closed_switch_to_the_open_one():
    v = Valve("V", {})
    assert opening(v) == 0  # pos 0
    v.pos = v.band  # where a closing stops (the switch is made)
    assert opening(v) == 0
    v.pos = v.travel // 2
    assert opening(v) == pytest.approx(0.5)
    v.pos = v.travel - v.band
    assert opening(v) == 1


def test_the_pump_shares_its_flow_between_the_open_lines():
    d = rig(drain=0)
    d["V1"].pos = d["V1"].travel  # V1 open, V2 shut
    d["P"].write(0, {"P": True})
    run(d, 2 * S)
    assert d["T2"].volume == 50 * NL_PER_L  # 20 L + 15 L/s for 2 s
    d["V2"].pos = d["V2"].travel  # both open: half each; V2 returns to T1
    run(d, 4 * S, start=2 * S + 10 * MS)
    assert d["T2"].volume == 65 * NL_PER_L  # + 7.5 L/s for 2 s
    assert total(d) == 115 * NL_PER_L and d["P"].sensors() == {"run": True}


@settings(max_examples=300, deadline=None)
@given(travels=st.tuples(st.integers(8, 5_000_000), st.integers(8, 5_000_000)),
       bands=st.tuples(st.integers(0, 300_000), st.integers(0, 300_000)),
       places=st.tuples(st.floats(0, 1), st.floats(0, 1)),
       flow=st.floats(0.1, 1000), dt=st.integers(1, 50_000),
       min_opening=st.floats(0, 1))
def test_the_pump_computes_in_integers_exactly_what_the_fractions_say(
        travels, bands, places, flow, dt, min_opening):
    """The pump's step works on the openings' numerators over one denominator;
    the reference is the fraction arithmetic it replaced, with `opening`, truncated the same."""
    tanks = {name: Tank(name, {"capacity": 10_000, "initial": 5_000 if name == "S" else 0,
                               "low": 1, "high": 9_999}) for name in ("S", "A", "B")}
    valves = {}
    for name, travel, band, place in zip(("V1", "V2"), travels, bands, places, strict=True):
        v = valves[name] = Valve(name, {"travel": travel, "switch_band": band})
        v.pos = round(place * v.travel)
    p = Pump("P", {"flow": flow, "suction": "S", "valve_a": "V1", "to_a": "A",
                   "valve_b": "V2", "to_b": "B", "min_opening": min_opening})
    devices = {**tanks, **valves, "P": p}
    for device in devices.values():
        device.link(devices)
    fractions = [opening(valves["V1"]), opening(valves["V2"])]
    total_f = sum(fractions, Fraction(0))
    p._check_dead_head(0, dt)
    assert (p.dead_us == dt) == (total_f < Fraction(min_opening))
    p._deliver(0, dt)
    if total_f == 0:
        assert p.delivering == 0 and tanks["A"].volume == tanks["B"].volume == 0
        return
    share = min(Fraction(1), total_f)
    assert p.delivering == int(p.flow * share)
    assert [tanks["A"].volume, tanks["B"].volume] == [
        int(p.flow * dt * share * f / total_f) for f in fractions]


def test_dead_heading_is_damage_after_its_tolerance_only():
    d = rig(drain=0)
    d["P"].write(0, {"P": True})
    run(d, 1 * S)
    assert not d["P"].events  # exactly the tolerance: not yet
    run(d, 1 * S + 10 * MS, start=1 * S + 10 * MS)
    assert [(e.kind, e.damage) for e in d["P"].events] == [("dead_head", True)]
    assert "V1, V2" in d["P"].events[0].detail
    assert d["T2"].volume == 20 * NL_PER_L  # nothing flowed


def test_running_dry_is_damage_after_its_tolerance():
    d = rig(t1=4, drain=0)  # below the pump's dry level (5 L)
    d["V1"].pos = d["V1"].travel
    d["P"].write(0, {"P": True})
    run(d, 3 * S)
    assert [e.kind for e in d["P"].events] == ["dry_run"]
    assert d["T1"].volume == 4 * NL_PER_L  # air, not water


def test_a_pump_that_does_not_start_and_one_that_does_not_stop():
    d = rig()
    d["V1"].pos = d["V1"].travel
    d["P"].inject("no_start", 0)
    d["P"].write(10 * MS, {"P": True})
    assert d["P"].sensors() == {"run": False} and d["P"].events[0].kind == "start_failed"
    w = rig()
    w["V1"].pos = w["V1"].travel
    w["P"].inject("welded", 0)
    w["P"].write(10 * MS, {"P": True})
    w["P"].write(20 * MS, {"P": False})
    assert w["P"].sensors() == {"run": True} and w["P"].events[0].kind == "stop_failed"


# -- the plant section ------------------------------------------------------------------------

PROJECT = """
name: t
scan_period: 10ms
inputs: {l1: low, h1: high}
outputs: {P: pump}
control: {equations: {P: l1}}
plant:
  kind: sim
  devices:
    T1: {model: tank, ports: {low: l1, high: h1}, params: TANK}
    P: {model: pump, params: PUMP}
"""


@pytest.mark.parametrize("tank,pump,fragment,needle", [
    ("{}", "{suction: T9}", "device 'P': parameter 'suction' names 'T9', which is not a "
     "device of the plant (expected one of P, T1)", "T9"),
    ("{}", "{suction: P}", "device 'P': parameter 'suction' names the device itself", "P}"),
    ("{}", "{suction: T1, valve_a: T1}", "device 'P': parameter 'valve_a' names 'T1', a tank "
     "(expected a device of model valve)", "T1}"),
    ("{low: 50, high: 40}", "{}", "tank parameter 'high': the high switch (40 L) is not above "
     "the low one (50 L) (expected low < high)", "40"),
    ("{capacity: 10}", "{}", "tank parameter 'high': the high switch (80 L) is above the "
     "capacity (10 L)", "{capacity"),
])
def test_plant_links_and_parameters_are_checked(tmp_path, tank, pump, fragment, needle):
    text = textwrap.dedent(PROJECT).lstrip().replace("TANK", tank).replace("PUMP", pump)
    (tmp_path / "project.yaml").write_text(text)
    with pytest.raises(ProjectError) as info:
        load_project(tmp_path)
    hit = [str(e) for e in info.value.errors if fragment in str(e)]
    assert hit, [str(e) for e in info.value.errors]
    device = "T1:" if fragment.startswith("tank") else "P:"
    line_no = next(k for k, line in enumerate(text.splitlines(), 1)
                   if line.strip().startswith(device))
    line = text.splitlines()[line_no - 1]
    col = line.index(needle, line.index("params")) + 1
    assert f"project.yaml:{line_no}:{col}: error: " in hit[0]

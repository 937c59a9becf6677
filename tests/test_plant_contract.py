"""The plant contract (hmi.plant.base): declared capabilities, no probing, and the safety rule
the engine holds itself: no `monitor` policy on a real plant unless explicitly allowed."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from hmi.engine.commands import InjectFault, RepairFaults, SetInput, SetPolicy
from hmi.engine.scan import Engine
from hmi.errors import UsageError
from hmi.plant.base import NotSupported, Plant
from hmi.plant.modbus.client import ModbusPlant, ModbusSettings
from hmi.plant.sim.plant import SimPlant
from hmi.project.injection import parse_injection
from tests.conftest import PROJECTS, ROOT
from tests.examples import example

VALVE = PROJECTS / "cispi_valve"


def modbus_plant(read_only: bool = False) -> ModbusPlant:
    """A Modbus plant on a port nobody listens on: constructing it connects nothing."""
    return ModbusPlant(example("cispi_valve"), ModbusSettings(port=1), read_only=read_only)


def test_an_engine_built_directly_on_a_real_plant_refuses_the_monitor_policy():
    project = example("cispi_valve")
    with pytest.raises(UsageError, match="monitor policy passes unsafe orders"):
        Engine(project, modbus_plant(), policy="monitor")
    # explicitly allowed, or observing read-only (nothing written): accepted
    assert Engine(project, modbus_plant(), policy="monitor",
                  allow_monitor_policy=True).policy == "monitor"
    assert Engine(project, modbus_plant(read_only=True)).policy == "monitor"
    # a simulated plant may run it
    assert Engine(project, SimPlant(project), policy="monitor").policy == "monitor"


def test_switching_to_monitor_is_refused_on_a_real_plant_unless_allowed():
    project = example("cispi_valve")
    engine = Engine(project, modbus_plant(), policy="block")
    result = engine.apply(SetPolicy("monitor"))
    assert not result.accepted and "refused on a real plant" in result.message
    assert engine.policy == "block"
    allowed = Engine(project, modbus_plant(), policy="block", allow_monitor_policy=True)
    assert allowed.apply(SetPolicy("monitor")).accepted and allowed.policy == "monitor"


def test_capabilities_are_declared_and_honoured():
    project = example("cispi_valve")
    sim, real = SimPlant(project), modbus_plant()
    assert isinstance(sim, Plant) and isinstance(real, Plant)
    assert (sim.is_real, sim.can_inject, sim.can_repair, sim.can_set_inputs) == \
        (False, True, True, True)
    assert (real.is_real, real.can_inject, real.can_repair, real.can_set_inputs) == \
        (True, False, False, False)
    # the contract's shapes: state and counters are (name, value) tuples, events a tuple
    assert real.state() == () and real.counters() == () and real.take_events() == ()
    assert isinstance(sim.state(), tuple) and all(len(p) == 2 for p in sim.state())
    assert real.faults() == [] and sim.faults()
    assert real.link is not None and sim.link is None
    with pytest.raises(NotSupported):
        real.inject(parse_injection("F5@1s"))
    with pytest.raises(NotSupported):
        real.set_input("fsc", True)


def test_the_engine_refuses_simulation_commands_on_a_real_plant_in_plain_words():
    engine = Engine(example("cispi_valve"), modbus_plant(), policy="block")
    for command, words in ((InjectFault(parse_injection("F5@1s")), "simulated plant"),
                           (RepairFaults(), "simulated plant"),
                           (SetInput("fsc", True), "simulated plant")):
        result = engine.apply(command)
        assert not result.accepted and words in result.message, (command, result)


PROBED = ("plant", "engine")


def _probes(path: Path) -> list[str]:
    """getattr/hasattr calls whose object mentions a plant or the engine."""
    found: list[str] = []
    text = path.read_text(encoding="utf-8")
    if "getattr" not in text and "hasattr" not in text:
        return found  # no such call can be in it: not parsed (most files; 0.6 CPU s)
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                node.func.id in ("getattr", "hasattr") and node.args:
            target = ast.unparse(node.args[0])
            if any(word in target for word in PROBED):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_nobody_probes_a_plant_or_the_engine_with_getattr():
    files = [*sorted((ROOT / "hmi").rglob("*.py"))]
    found = [line for path in files for line in _probes(path)]
    assert found == []


def test_the_model_registry_names_each_model_and_imports_it_on_use():
    from hmi.plant.sim.device import SimDevice
    from hmi.plant.sim.models import MODELS, REGISTRY
    from hmi.project.device_models import DEVICE_MODELS
    assert set(REGISTRY) == set(DEVICE_MODELS)
    for name in REGISTRY:
        cls = MODELS[name]
        assert issubclass(cls, SimDevice) and name == cls.MODEL
        assert cls.SPEC is DEVICE_MODELS[name]
        # The counters the catalogue promises (a campaign's `counter:` is checked against
        # them) are those a device reports.
        assert tuple(cls(name, {}).counters()) == DEVICE_MODELS[name].counters, name
    assert "nope" not in MODELS and MODELS.get("nope") is None


def test_loading_a_project_imports_no_simulated_model():
    """The loader checks devices against the catalogue (hmi/project/device_models.py): no
    simulation is imported until a plant is built."""
    import subprocess
    import sys
    code = ("import json, sys; from hmi.project.loader import load_project; "
            f"load_project({str(VALVE)!r}); "
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('hmi.plant'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout
    assert json.loads(out) == []

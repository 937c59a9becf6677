"""An engine is built in one place (hmi.engine.build): its options are Engine's keyword
parameters, by the same names and defaults, and nothing else in hmi/ calls Engine(...)."""

import ast
import inspect
from dataclasses import fields

from hmi.engine.build import EngineOptions, build_engine
from hmi.engine.scan import Engine
from hmi.paths import PROJECTS
from hmi.plant.sim.plant import SimPlant
from hmi.project.loader import load_project
from tests.test_layers import MODULES


def test_the_options_are_the_engines_keyword_parameters():
    params = list(inspect.signature(Engine.__init__).parameters.values())[3:]  # self, p, p
    assert [(p.name, p.default) for p in params] == \
        [(f.name, f.default) for f in fields(EngineOptions)]


def test_build_engine_passes_every_option_on_and_simulates_by_default():
    project = load_project(PROJECTS / "cispi_valve")
    engine = build_engine(project, options=EngineOptions(
        control="faulty", policy="block", diagnosis="off", compiled=False))
    assert isinstance(engine.plant, SimPlant) and engine.plant.project is project
    assert (engine.control_name, engine.policy) == ("faulty", "block")
    default = build_engine(project)
    assert (default.control_name, default.policy) == (project.default_control, project.policy)
    plant = SimPlant(project)
    assert build_engine(project, plant).plant is plant


def test_nothing_else_in_hmi_builds_an_engine():
    calls = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id == "Engine":
                calls.append(name)
    assert calls == ["hmi.engine.build"]

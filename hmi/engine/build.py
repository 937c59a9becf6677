"""Building an engine: what every caller outside the tests goes through.

An engine is one project on one plant, with choices (the control variant, the filter's
policy, the corrector, the diagnosis) that the command line, the benches, the studies and the
soak each make. They name them in an :class:`EngineOptions` and call :func:`build_engine`:
an engine argument added later is a field here, passed on here, and no caller that does not
use it changes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from hmi.engine.scan import Engine

if TYPE_CHECKING:
    from hmi.plant.base import Plant
    from hmi.project.model import Project


@dataclass(frozen=True)
class EngineOptions:
    """How an engine runs its project: Engine's keyword parameters, by the same names
    (tests/test_engine_build.py checks they stay the same)."""

    control: str | None = None  # None: the project's default variant
    policy: str | None = None  # None: the project's policy
    solver: str | None = None  # the corrector's strategy (None: the project's)
    diagnosis: str = "ftc"
    solver_budget: int | None = None
    allow_monitor_policy: bool = False  # the monitor policy on a real plant
    compiled: bool = True  # the printed scan program (False: the stage objects)
    high_level: bool = True  # the project's high-level diagnosis rules


DEFAULT = EngineOptions()


def build_engine(project: Project, plant: Plant | None = None,
                 options: EngineOptions = DEFAULT) -> Engine:
    """An engine of `project` on `plant` (None: the project's simulated plant)."""
    if plant is None:
        from hmi.plant.sim.plant import SimPlant
        plant = SimPlant(project)
    o = options
    return Engine(project, plant, control=o.control, policy=o.policy, solver=o.solver,
                  diagnosis=o.diagnosis, solver_budget=o.solver_budget,
                  allow_monitor_policy=o.allow_monitor_policy, compiled=o.compiled,
                  high_level=o.high_level)

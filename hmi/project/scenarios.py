"""The `scenarios:` section: named lists of fault injections for the simulated plant.

    scenarios:
      paper:
        description: 002 §4 - the conveyor stops for 2 t.u. after 1 t.u. of work
        inject: [C1.stop@1s+2s]
        for: 12s                   # default run length of `plchmi run --scenario paper`

A scenario is data, kept with the project so that a run the documentation quotes is one
command away and cannot drift: `plchmi run PROJECT --scenario paper`. Injections use the
command line's syntax (`CODE@TIME`, `DEVICE.CODE@TIME`, `CODE@TIME+DURATION`) and are
checked against the plant's devices when the project loads.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from hmi.errors import SourcePos, UsageError
from hmi.project.device_models import DEVICE_MODELS
from hmi.project.injection import Injection, parse_injection
from hmi.project.model import PlantSpec, Scenario
from hmi.project.yamlnodes import YNode

if TYPE_CHECKING:
    from hmi.project.model import Project
    from hmi.project.reader import ProjectReader

SCENARIO_KEYS = {"description", "inject", "for"}
SCENARIO_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_-]*$")
INJECTION_HINT = "FAULT@TIME, DEVICE.FAULT@TIME or FAULT@TIME+DURATION, e.g. C1.stop@1s+2s"


def scenarios_of(project: Project) -> tuple[Scenario, ...]:
    return project.scenarios


def find_scenario(project: Project, name: str) -> Scenario:
    """The scenario called `name`, or a UsageError listing those the project declares."""
    for scenario in scenarios_of(project):
        if scenario.name == name:
            return scenario
    known = ", ".join(s.name for s in scenarios_of(project))
    raise UsageError(f"--scenario {name!r}: " + (f"the project declares {known}" if known
                                                   else "the project declares no scenarios"))


def parse_scenarios(loader: ProjectReader, plant: PlantSpec) -> tuple[Scenario, ...]:
    out = []
    for name, node, kpos in loader.section_items("scenarios"):
        name = str(name)
        if not SCENARIO_NAME_RE.match(name):
            loader.diag.error(kpos, f"{name!r} is not a valid scenario name",
                              "letters, digits, _ and -")
            continue
        scenario = _scenario(loader, name, node, kpos, plant)
        if scenario is not None:
            out.append(scenario)
    return tuple(out)


def _scenario(loader: ProjectReader, name: str, node: YNode, kpos: SourcePos,
              plant: PlantSpec) -> Scenario | None:
    what = f"scenario {name!r}"
    fields = loader.guard(lambda: node.check_keys(what, SCENARIO_KEYS, ["inject"]))
    if fields is None:
        return None
    description = loader.guard(lambda: fields["description"].as_str("description"), "") \
        if "description" in fields else ""
    duration = loader.guard(lambda: fields["for"].as_duration(f"the length of {what}")) \
        if "for" in fields else None
    items = loader.guard(lambda: fields["inject"].as_seq(f"the injections of {what}"))
    if items is None or ("for" in fields and duration is None):
        return None
    injections = []
    ok = True
    for item in items:
        injection = _injection(loader, item, plant)
        if injection is None:
            ok = False
        else:
            injections.append(injection)
    if not ok:
        return None
    return Scenario(name, description or "", tuple(injections), duration, kpos)


def _injection(loader: ProjectReader, item: YNode, plant: PlantSpec) -> Injection | None:
    text = loader.guard(lambda: item.as_str("an injection"))
    if text is None:
        return None
    try:
        injection = parse_injection(text)
    except UsageError:
        loader.diag.error(item.pos, f"{text!r} is not a fault injection", INJECTION_HINT)
        return None
    if plant.kind != "sim":
        loader.diag.error(item.pos, "scenarios inject faults into a simulated plant, and this "
                          f"plant is {plant.kind}", "plant kind: sim")
        return None
    faults = [(d.name, code) for d in plant.devices if d.model in DEVICE_MODELS
              for code in DEVICE_MODELS[d.model].faults]
    several = len(plant.devices) > 1
    matches = [device for device, code in faults if code == injection.code
               and (injection.device is None or device == injection.device)]
    if len(matches) == 1:
        return injection
    if not matches:
        known = ", ".join(sorted(f"{d}.{c}" if several else c for d, c in faults))
        loader.diag.error(item.pos, f"unknown fault {injection.code!r}"
                          + (f" on device {injection.device!r}" if injection.device else ""),
                          "one of " + (known or "(this plant has no faults)"))
    else:
        loader.diag.error(item.pos, f"fault {injection.code!r} exists on several devices",
                          " or ".join(f"{d}.{injection.code}@..." for d in matches))
    return None

"""The `campaign:` section: the fault scenarios of `plchmi campaign` (000 §3.3, Table 1).

    campaign:
      length: 45s          # virtual time of each run
      window: 20s          # Blocked = no completed cycle during the last `window` of a run
      counter: cycles      # the plant counter that counts completed functional cycles
      paper: true          # print 000 Table 1 beside the counts (the valve's; default)
      scenarios:
        - {fault: F1, at: 12s, phase: valve open at rest; symptom at the next closing}
        - {fault: F4, at: 10s, phase: ..., table: false}   # shown, not counted in Table 1

Each scenario injects one fault at one instant, chosen in the phase of the functional cycle
where that fault's symptom appears; the campaign runs it under three configurations and
classifies each run (hmi/studies/campaign.py). Scenarios with `table: false` are extra
evidence printed after the table, so the table keeps one scenario per fault as the paper's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hmi.project.device_models import DEVICE_MODELS
from hmi.project.model import CampaignScenario, CampaignSpec
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from hmi.project.model import PlantSpec, Project
    from hmi.project.reader import ProjectReader


def campaign_of(project: Project) -> CampaignSpec | None:
    return project.campaign


def plant_counters(plant: PlantSpec) -> list[str]:
    """The counters a simulated plant reports, named as SimPlant.counters() names them."""
    names: list[str] = []
    for device in plant.devices:
        model = DEVICE_MODELS.get(device.model)
        if model is None:
            continue
        keys = list(model.counters)
        names += keys if len(plant.devices) == 1 else [f"{device.name}.{k}" for k in keys]
    return names


def parse_campaign(loader: ProjectReader, plant: PlantSpec) -> CampaignSpec | None:
    node = loader.sections.get("campaign")
    if node is None:
        return None
    fields = loader.guard(lambda: node.check_keys(
        "campaign", {"length", "window", "counter", "scenarios", "paper"},
        ["length", "window", "counter", "scenarios"]))
    if fields is None:
        return None
    errors_before = len(loader.diag.errors)
    length = loader.guard(lambda: fields["length"].as_duration("campaign length"))
    window = loader.guard(lambda: fields["window"].as_duration("campaign window"))
    counter = loader.guard(lambda: fields["counter"].as_str("campaign counter"))
    paper = loader.guard(lambda: fields["paper"].as_bool("paper"), True) \
        if "paper" in fields else True
    if length is not None and window is not None and window >= length:
        loader.diag.error(fields["window"].pos, f"the campaign window ({format_duration(window)})"
                          f" is not shorter than a run ({format_duration(length)})",
                          "a window shorter than the run length")
    if plant.kind != "sim":
        loader.diag.error(node.pos, "a fault campaign needs a simulated plant",
                          "plant: kind: sim")
        return None
    counters = plant_counters(plant)
    if counter is not None and counter not in counters:
        loader.diag.error(fields["counter"].pos, f"the plant has no counter {counter!r}",
                          "one of " + ", ".join(counters) if counters else "a plant counter")
    faults = {(d.name, code) for d in plant.devices
              for code in (DEVICE_MODELS[d.model].faults if d.model in DEVICE_MODELS else ())}
    items = loader.guard(lambda: fields["scenarios"].as_seq("campaign scenarios"), [])
    scenarios = []
    for k, item in enumerate(items, start=1):
        what = f"campaign scenario {k}"
        sfields = loader.guard(lambda i=item, w=what: i.check_keys(
            w, {"fault", "at", "phase", "table"}, ["fault", "at"]))
        if sfields is None:
            continue
        text = loader.guard(lambda f=sfields: f["fault"].as_str("fault"))
        at = loader.guard(lambda f=sfields: f["at"].as_duration("injection time",
                                                                allow_zero=True))
        phase = loader.guard(lambda f=sfields: f["phase"].as_str("phase"), "") \
            if "phase" in sfields else ""
        table = loader.guard(lambda f=sfields: f["table"].as_bool("table"), True) \
            if "table" in sfields else True
        if text is None or at is None:
            continue
        device, _, code = text.rpartition(".")
        matches = [(d, c) for d, c in faults if c == code and (not device or d == device)]
        if len(matches) != 1:
            known = ", ".join(sorted({c if len(plant.devices) == 1 else f"{d}.{c}"
                                      for d, c in faults}))
            reason = "is not a fault of the plant" if not matches else "is on several devices"
            loader.diag.error(sfields["fault"].pos, f"{what}: {text!r} {reason}",
                              f"one of {known}")
            continue
        if length is not None and at >= length:
            loader.diag.error(sfields["at"].pos, f"{what} injects at {format_duration(at)}, "
                              f"not before the end of the run ({format_duration(length)})",
                              "an instant inside the run")
            continue
        scenarios.append(CampaignScenario(code, device or None, at, phase, bool(table), item.pos))
    if not items:
        loader.diag.error(fields["scenarios"].pos, "the campaign has no scenario",
                          "- {fault: F1, at: 12s, phase: ...}")
    if len(loader.diag.errors) > errors_before or length is None or window is None \
            or counter is None:
        return None
    tabled = {s.fault for s in scenarios if s.table}
    for device, code in sorted(faults):
        if code not in tabled:
            loader.diag.warning(fields["scenarios"].pos, f"fault {code} of {device} has no "
                                "scenario counted in the campaign table")
    return CampaignSpec(length, window, counter, tuple(scenarios), node.pos, bool(paper))

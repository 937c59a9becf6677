"""Where each named value lives in the engine's image (a flat list indexed by slot).

A flat list makes a scan cheap (compiled expressions index it directly) and a snapshot cheap
(one tuple copy); the layout gives the names back to whoever reads a snapshot.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from hmi.logic.expr import Image
from hmi.project.model import ControlLaw, Grafcet, Project


@dataclass(frozen=True)
class Layout:
    names: tuple[str, ...]
    kinds: tuple[str, ...]
    slots: Mapping[str, int]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    memories: tuple[str, ...]
    timers: tuple[str, ...]
    observers: tuple[str, ...]
    steps: tuple[str, ...]
    step_times: Mapping[str, int]  # step name -> slot of its activity time (us)
    timer_presets: tuple[int, ...] = ()
    extra: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # kind -> names
    # The law's GRAFCET as the project declares it (immutable): what a snapshot's active steps
    # wait for is read from it (hmi.engine.criteria), and their supervision times.
    grafcet: Grafcet | None = field(default=None, compare=False)

    @classmethod
    def build(cls, project: Project, law: ControlLaw,
              extra: Iterable[tuple[str, str]] = ()) -> Layout:
        names: list[str] = []
        kinds: list[str] = []

        def add(name: str, kind: str) -> None:
            names.append(name)
            kinds.append(kind)

        for v in project.inputs:
            add(v.name, "input")
        for v in project.outputs:
            add(v.name, "output")
        for v in project.memories:
            add(v.name, "memory")
        for t in project.timers:
            add(t.name, "timer")
        for o in project.observers:
            add(o.name, "observer")
        steps = tuple(s.name for s in law.grafcet.steps) if law.grafcet else ()
        for s in steps:
            add(s, "step")
        extra_kinds: dict[str, list[str]] = {}
        for name, kind in extra:
            add(name, kind)
            extra_kinds.setdefault(kind, []).append(name)
        step_times = {}
        for s in steps:
            step_times[s] = len(names)
            add(f"{s}.t", "step_time")
        slots = {n: i for i, n in enumerate(names)}
        return cls(
            names=tuple(names), kinds=tuple(kinds), slots=MappingProxyType(slots),
            inputs=tuple(v.name for v in project.inputs),
            outputs=tuple(v.name for v in project.outputs),
            memories=tuple(v.name for v in project.memories),
            timers=tuple(t.name for t in project.timers),
            observers=tuple(o.name for o in project.observers),
            steps=steps, step_times=MappingProxyType(step_times),
            timer_presets=tuple(t.preset_us for t in project.timers),
            extra=MappingProxyType({k: tuple(v) for k, v in extra_kinds.items()}),
            grafcet=law.grafcet,
        )

    def indices(self, names: Iterable[str]) -> tuple[int, ...]:
        return tuple(self.slots[n] for n in names)

    def initial_image(self, project: Project) -> Image:
        image: Image = [False] * len(self.names)
        for slot in self.step_times.values():
            image[slot] = 0
        for v in project.memories:
            image[self.slots[v.name]] = v.safe
        for o in project.observers:
            image[self.slots[o.name]] = o.initial
        for v in project.outputs:
            image[self.slots[v.name]] = v.safe
        return image

"""GRAFCET (IEC 60848) evolution, PLC style.

Interpretation, documented in docs/grafcet.md:
  * A transition is enabled when all its upstream steps are active; it is fireable when it is
    enabled and its receptivity is true, both judged on the image at the start of the scan.
  * All fireable transitions fire together (IEC 60848 rule 4), once per scan: there is no
    search for stability inside a scan, so a chain of true receptivities advances one
    transition per scan, like a PLC's SFC.
  * Firing deactivates the upstream steps and activates the downstream ones; a step both
    deactivated and activated stays active (rule 5) and its step time restarts.
  * Stored actions (set/reset of memories) happen on activation; continuous actions hold
    while their step is active (and their condition is true), computed after evolution.
  * In manual mode the program waits: nothing here runs (no evolution, no step time
    written), and leaving manual mode shifts the activation times by the time it waited
    (:meth:`GrafcetRuntime.shift`, from hmi.engine.control.ControlRuntime.resume).
  * Supervision (S7-GRAPH's): a step declared with `supervision:` and active longer than
    that while the program runs in automatic mode is *overdue* (the program is stuck there:
    hmi.explain.sequence raises an alarm). Kept cheap: `deadline` is the next instant an
    active supervised step becomes overdue; the engine compares the scan's time with it once
    per scan and calls :meth:`GrafcetRuntime.watch` past it; a firing makes it due at once (the
    engine recomputes after that scan's control), a reset and the engine's mode changes
    (:meth:`GrafcetRuntime.supervise`) recompute it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from hmi.logic.expr import Image, Node
from hmi.program.grafcet import lower_continuous, lower_evolution, lower_step_times
from hmi.program.ir import Stmt
from hmi.project.model import Grafcet


class GrafcetRuntime:
    """One GRAFCET's state: its steps live in the image, their activation times here
    (`since`, one entry per step in declaration order, None while inactive). What runs at
    each scan is hmi.program.grafcet's lowering (:attr:`times`, :attr:`evolution`); the
    firings it finds come back to :meth:`fire`."""

    def __init__(self, grafcet: Grafcet, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int]):
        self.grafcet = grafcet
        self.names = tuple(s.name for s in grafcet.steps)
        self.number = {name: k for k, name in enumerate(self.names)}
        self.step_slots = {s.name: slots[s.name] for s in grafcet.steps}
        self.time_slots = {s.name: step_time_slots[s.name] for s in grafcet.steps}
        self.initial = tuple(s.name for s in grafcet.steps if s.initial)
        # (upstream steps' names, downstream steps' names) per transition
        self.transitions = [(tr.sources, tr.targets) for tr in grafcet.transitions]
        self.transition_numbers = tuple(tr.number for tr in grafcet.transitions)
        self.stored: dict[str, list[tuple[int, bool]]] = {}
        continuous: list[tuple[int, int, Node | None]] = []  # step slot, target, condition
        for step in grafcet.steps:
            for action in step.actions:
                if action.kind == "N":
                    continuous.append((self.step_slots[step.name], slots[action.target],
                                       action.condition.root if action.condition else None))
                else:
                    self.stored.setdefault(step.name, []).append(
                        (slots[action.target], action.kind == "S"))
        self.driven = sorted({target for _, target, _ in continuous})
        # The activation time of each step (None: inactive); the list itself is handed to
        # the scan program, so it is only ever changed in place.
        self.since: list[int | None] = [None] * len(self.names)
        self.fired: tuple[int, ...] = ()
        self._active: tuple[str, ...] | None = None  # cache of active(), None: to compute
        # The scan program's parts (hmi.program.grafcet): stage 2's step times, stage 5's
        # evolution and continuous actions.
        self.times: tuple[Stmt, ...] = lower_step_times(
            self.since, [(self.step_slots[n], self.time_slots[n]) for n in self.names])
        self.evolution: tuple[Stmt, ...] = lower_evolution(self, [
            (tuple(self.step_slots[s] for s in tr.sources), tr.receptivity.root)
            for tr in grafcet.transitions]) + lower_continuous(self.driven, continuous)
        # Supervision: each supervised step's time; whether it is watched now (automatic
        # mode, the program running: the engine says, `supervise`); the active supervised
        # steps past their time, in step order; the scan time past which the next becomes
        # overdue (NEVER: none).
        self.supervision = {s.name: s.supervision_us for s in grafcet.steps
                            if s.supervision_us is not None}
        self.watching = True
        self.overdue: tuple[str, ...] = ()
        self.deadline: float = NEVER

    @property
    def activated_at(self) -> dict[str, int]:
        """The active steps' activation times, by name."""
        return {name: since for name, since in zip(self.names, self.since, strict=True)
                if since is not None}

    @activated_at.setter
    def activated_at(self, times: Mapping[str, int]) -> None:
        self.since[:] = [times.get(name) for name in self.names]

    def reset(self, image: Image, now: int) -> None:
        """Back to the initial steps at `now`: every other step inactive, its time 0."""
        for name, slot in self.step_slots.items():
            image[slot] = name in self.initial
        for name, slot in self.time_slots.items():
            if name not in self.initial:
                image[slot] = 0
        self.activated_at = dict.fromkeys(self.initial, now)
        self._active = None
        for name in self.initial:
            self._stored(image, name)
        if self.supervision:
            self.watch(now)

    def shift(self, delta: int) -> None:
        """Every activation time `delta` later: the program waited that long (manual mode,
        hmi.engine.control.ControlRuntime.resume), its step times stopped meanwhile."""
        self.since[:] = [None if since is None else since + delta for since in self.since]

    def fire(self, fire: Sequence[int], image: Image, now: int) -> tuple[int, ...]:
        """Fire the transitions `fire` (indices, in order) together: the scan program found
        them fireable (hmi.program.grafcet)."""
        deactivate: set[str] = set()
        activate: set[str] = set()
        for i in fire:
            sources, targets = self.transitions[i]
            deactivate.update(sources)
            activate.update(targets)
        since = self.since
        for name in deactivate - activate:
            image[self.step_slots[name]] = False
            since[self.number[name]] = None
            image[self.time_slots[name]] = 0
        for name in sorted(activate):
            image[self.step_slots[name]] = True
            since[self.number[name]] = now
            image[self.time_slots[name]] = 0
            self._stored(image, name)
        self.fired = tuple(self.transition_numbers[i] for i in fire)
        self._active = None
        if self.supervision:  # due now: Engine.run watches again after this scan's control
            self.deadline = DUE
        return self.fired
    def supervise(self, watching: bool, now: int) -> None:
        """Whether the supervision times are watched from `now` on (the engine: automatic
        mode, the program running; not while it waits in manual mode, nor in recovery mode,
        nor observing a device), and the overdue steps and deadline as of `now`."""
        self.watching = watching
        if self.supervision:
            self.watch(now)

    def watch(self, now: int) -> None:
        """The overdue steps and the next deadline at `now` (the engine calls this past the
        deadline; a firing and a reset call it too). `overdue` keeps its identity while it
        does not change: the engine tells news by it (hmi.engine.scan.Engine.run)."""
        overdue: list[str] = []
        deadline: float = NEVER
        if self.watching:
            since_of = self.activated_at
            for name, limit in self.supervision.items():
                since = since_of.get(name)
                if since is None:
                    continue
                due = since + limit
                if now > due:
                    overdue.append(name)
                elif due < deadline:
                    deadline = due
        found = tuple(overdue)
        if found != self.overdue:
            self.overdue = found
        self.deadline = deadline

    def _stored(self, image: Image, step: str) -> None:
        for slot, value in self.stored.get(step, ()):
            image[slot] = value

    def active(self, image: Image) -> tuple[str, ...]:
        """The active steps, recomputed only after a change of steps (a firing, a reset, a
        restored state): read at every scan, they change at few."""
        if self._active is None:
            self._active = tuple(name for name, slot in self.step_slots.items()
                                 if image[slot])
        return self._active

    def forget_active(self) -> None:
        """The steps in the image were changed from outside (a restored state)."""
        self._active = None


NEVER = float("inf")  # a deadline that never comes
DUE = -1  # a deadline already past (a firing: the overdue steps are recomputed)

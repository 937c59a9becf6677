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

from hmi.logic.expr import BoolFn, History, Image, Node, compile_bool
from hmi.project.model import Grafcet


class GrafcetRuntime:
    def __init__(self, grafcet: Grafcet, slots: Mapping[str, int],
                 step_time_slots: Mapping[str, int]):
        self.grafcet = grafcet
        self.step_slots = {s.name: slots[s.name] for s in grafcet.steps}
        self.time_slots = {s.name: step_time_slots[s.name] for s in grafcet.steps}
        self.initial = tuple(s.name for s in grafcet.steps if s.initial)
        self.transitions: list[tuple[tuple[int, ...], tuple[str, ...], BoolFn]] = [
            (tuple(self.step_slots[s] for s in tr.sources), tr.targets,
             compile_bool(tr.receptivity, slots, step_time_slots))
            for tr in grafcet.transitions
        ]
        self.transition_numbers = tuple(tr.number for tr in grafcet.transitions)
        self.stored: dict[str, list[tuple[int, bool]]] = {}
        self.continuous: list[tuple[int, int, BoolFn | None]] = []  # step slot, target, cond
        self.continuous_conditions: list[Node | None] = []  # their trees (compiled scan)
        for step in grafcet.steps:
            for action in step.actions:
                if action.kind == "N":
                    cond = (compile_bool(action.condition, slots, step_time_slots)
                            if action.condition else None)
                    self.continuous.append((self.step_slots[step.name], slots[action.target],
                                            cond))
                    self.continuous_conditions.append(
                        action.condition.root if action.condition else None)
                else:
                    self.stored.setdefault(step.name, []).append(
                        (slots[action.target], action.kind == "S"))
        self.driven = sorted({target for _, target, _ in self.continuous})
        self.activated_at: dict[str, int] = {}
        # (time slot, activated at) of each active step, for the compiled scan's stage 2: an
        # inactive step's time slot is 0 and stays 0 until it is activated (fire writes 0 in
        # the slots of the steps it deactivates), so only the active steps' slots move. None
        # when the image's time slots may not say so (a reset leaves the time of a step it
        # deactivates in the image; a restored state): update_times writes them all then.
        self.timed: tuple[tuple[int, int], ...] | None = None
        self.fired: tuple[int, ...] = ()
        self._active: tuple[str, ...] | None = None  # cache of active(), None: to compute
        # Supervision: each supervised step's time; whether it is watched now (automatic
        # mode, the program running: the engine says, `supervise`); the active supervised
        # steps past their time, in step order; the scan time past which the next becomes
        # overdue (NEVER: none).
        self.supervision = {s.name: s.supervision_us for s in grafcet.steps
                            if s.supervision_us is not None}
        self.watching = True
        self.overdue: tuple[str, ...] = ()
        self.deadline: float = NEVER

    def reset(self, image: Image, now: int) -> None:
        for name, slot in self.step_slots.items():
            image[slot] = name in self.initial
        self.activated_at = dict.fromkeys(self.initial, now)
        self.timed = None
        self._active = None
        for name in self.initial:
            self._stored(image, name)
        if self.supervision:
            self.watch(now)

    def update_times(self, image: Image, now: int) -> None:
        for name, slot in self.time_slots.items():
            since = self.activated_at.get(name)
            image[slot] = 0 if since is None else now - since
        self._timed()

    def shift(self, delta: int) -> None:
        """Every activation time `delta` later: the program waited that long (manual mode,
        hmi.engine.control.ControlRuntime.resume), its step times stopped meanwhile."""
        self.activated_at = {name: since + delta for name, since in self.activated_at.items()}
        if self.timed is not None:
            self._timed()

    def _timed(self) -> None:
        """The active steps' (time slot, activation time), in the image's time slots' state
        after update_times or fire (see `timed`)."""
        slots = self.time_slots
        self.timed = tuple((slots[name], since) for name, since in self.activated_at.items())

    def evolve(self, image: Image, history: History, now: int) -> tuple[int, ...]:
        """Fire every fireable transition at once; return the numbers of those fired."""
        fire = []
        for i, (sources, _, receptivity) in enumerate(self.transitions):
            for s in sources:
                if not image[s]:
                    break
            else:
                if receptivity(image, history):
                    fire.append(i)
        if not fire:
            self.fired = ()
            return ()
        return self.fire(fire, image, now)

    def fire(self, fire: Sequence[int], image: Image, now: int) -> tuple[int, ...]:
        """Fire the transitions `fire` (indices, in order) together; the compiled scan
        (hmi.engine.compiled) finds them itself and calls this only when there are some."""
        deactivate: set[str] = set()
        activate: set[str] = set()
        for i in fire:
            sources, targets, _ = self.transitions[i]
            deactivate.update(name for name, slot in self.step_slots.items() if slot in sources)
            activate.update(targets)
        for name in deactivate - activate:
            image[self.step_slots[name]] = False
            self.activated_at.pop(name, None)
            image[self.time_slots[name]] = 0
        for name in sorted(activate):
            image[self.step_slots[name]] = True
            self.activated_at[name] = now
            image[self.time_slots[name]] = 0
            self._stored(image, name)
        self.fired = tuple(self.transition_numbers[i] for i in fire)
        self._active = None
        if self.timed is not None:  # (else the image's times are not all settled yet)
            self._timed()
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

    def apply_continuous(self, image: Image, history: History) -> None:
        for slot in self.driven:
            image[slot] = False
        for step_slot, target, cond in self.continuous:
            if image[step_slot] and (cond is None or cond(image, history)):
                image[target] = True

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
        self.timed = None


NEVER = float("inf")  # a deadline that never comes
DUE = -1  # a deadline already past (a firing: the overdue steps are recomputed)

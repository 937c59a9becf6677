"""Recovery mode in the scan: a declared procedure brings a device back.

The procedures are the project's (hmi.project.recovery). The engine owns one
:class:`RecoveryStage`; while the operator has one running (recovery mode, entered with
:class:`~hmi.engine.commands.StartRecovery`):

* stage 5 takes the procedure's vector instead of the control law's: the outputs it drives
  follow its current step, every other output is at its safe value (production stopped,
  GEMMA A5/A6);
* stage 6 filters that vector with the procedure's own filter: the project's constraints
  but the ones it relaxes, plus its own, never under `monitor` (a recovery is always
  filtered: `monitor` runs it under `correct`). The diagnosers' mask is lifted from the
  outputs it drives: the operator confirmed the device is repaired.

A step ends when its `until` holds (for the step's `for`, if it has one); the last one ends
the procedure (done: everything safe, the cell waits for the operator to leave recovery).
Past its timeout the procedure fails: outputs safe, the operator told. Every scan, in any
mode, the stage also says which procedures the cell needs (their `needed` condition held
long enough).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from hmi.engine.codegen import Vocabulary
from hmi.engine.filter import SafetyFilter, Solver
from hmi.engine.filter_stage import FilterStage
from hmi.engine.layout import Layout
from hmi.program import order
from hmi.program.ir import Stmt
from hmi.program.recovery import lower_needed, lower_procedure
from hmi.project.model import Project, RecoveryProcedure
from hmi.project.recovery import recoveries_of
from hmi.timefmt import seconds


@dataclass(frozen=True)
class RecoveryState:
    """The recovery for the snapshot: what runs (if anything) and what the cell needs."""

    active: str | None = None  # the procedure's name
    device: str = ""
    description: str = ""
    status: str = ""  # running, done, failed
    step: int = 0  # 1-based, while running
    steps: int = 0
    step_text: str = ""
    since_us: int = 0  # when the procedure started
    elapsed_us: int = 0
    timeout_us: int = 0
    message: str = ""  # done / failed: what happened, plainly
    # Procedures the cell needs now: (name, device, description, why in plain words).
    needed: tuple[tuple[str, str, str, str], ...] = ()
    # Every procedure the project declares: (name, device, description, the devices whose
    # outputs it drives).
    procedures: tuple[tuple[str, str, str, tuple[str, ...]], ...] = ()

    @property
    def running(self) -> bool:
        return self.status == "running"


NO_RECOVERY = RecoveryState()


class _Procedure:
    """One compiled procedure."""

    def __init__(self, spec: RecoveryProcedure, project: Project, layout: Layout,
                 filter_args: Solver,
                 mask_flags: Mapping[str, tuple[str, ...]]):
        self.spec = spec
        slots = layout.slots
        index = {name: k for k, name in enumerate(layout.outputs)}
        # stage 5 in recovery mode while it runs, as the scan program (hmi.program.recovery)
        self.program: tuple[Stmt, ...] = ()
        self.driven = tuple(index[o] for o in spec.outputs)
        self.needed_since: int | None = None  # its `needed` condition holds since then
        constraints = tuple(c for c in project.constraints if c.name not in spec.relaxes) \
            + spec.constraints
        self.filter = FilterStage(
            SafetyFilter(replace(project, constraints=constraints), slots, layout.step_times,
                         *filter_args), mask_flags)


class RecoveryStage:
    """The project's recovery procedures and the one running, if any."""

    # the stage's and each procedure's state and handlers (hmi.program.recovery)
    PRINTED = Vocabulary(
        frozenset({"needed_since", "needed", "judge_needed", "held_since", "step",
                   "started_us", "running", "finish", "fail"}),
        frozenset({"moved", "s"}))

    def __init__(self, project: Project, layout: Layout, safe: tuple[bool, ...],
                 filter_args: Solver,
                 mask_flags: Mapping[str, tuple[str, ...]]):
        self.procedures = {spec.name: _Procedure(spec, project, layout, filter_args,
                                                 mask_flags)
                           for spec in recoveries_of(project)}
        self.safe = safe
        for proc in self.procedures.values():
            proc.program = lower_procedure(self, proc.spec, layout.outputs, safe)
        # which procedures the cell needs, as the scan program (hmi.program.recovery)
        self.program = lower_needed(self, [(p, p.spec) for p in self.procedures.values()])
        self.active: _Procedure | None = None
        self.running = False  # status == "running"
        self.status = ""
        self.step = 0
        self.started_us = 0
        self.message = ""
        self.ended_us: int | None = None
        self.held_since: int | None = None  # the current step's `until` holds since then
        self.needed: tuple[tuple[str, str, str, str], ...] = ()
        devices = {v.name: v.device for v in project.outputs if v.device}
        self.catalogue = tuple(
            (p.spec.name, p.spec.device, p.spec.description,
             tuple(dict.fromkeys(devices[o] for o in p.spec.outputs if o in devices)))
            for p in self.procedures.values())
        self._idle = RecoveryState(procedures=self.catalogue)
        self._shown_needed: RecoveryState | None = None

    @property
    def parts(self) -> dict[str, tuple[Stmt, ...]]:
        return {order.RECOVERIES_NEEDED: self.program}

    # -- commands (through the engine) ------------------------------------------------------

    def start(self, name: str, now: int) -> None:
        self.active = self.procedures[name]
        self._status("running")
        self.step = 0
        self.started_us = now
        self.message = ""
        self.ended_us = None
        self.held_since = None

    def stop(self) -> str:
        """Leave recovery: what the procedure had reached, for the operator."""
        proc, status = self.active, self.status
        self.active = None
        self._status("")
        if proc is None:
            return ""
        return {"done": "done", "failed": "failed"}.get(status, "stopped before its end")

    def _status(self, status: str) -> None:
        self.status = status
        self.running = status == "running"

    # -- the scan program's handlers (hmi.program.recovery) ----------------------------------
    def judge_needed(self, now: int) -> None:
        """Which procedures the cell needs now: their condition held for long enough (it
        holds since ``needed_since``, written by the scan program)."""
        needed = []
        for name, proc in self.procedures.items():
            spec, since = proc.spec, proc.needed_since
            if since is not None and spec.needed is not None \
                    and now - since >= spec.needed.for_us:
                needed.append((name, spec.device, spec.description, spec.needed.text))
        self.needed = tuple(needed)

    def finish(self, now: int) -> None:
        """The procedure went past its last step."""
        proc = self.active
        assert proc is not None
        self._status("done")
        self.ended_us = now
        self.message = f"done in {seconds(now - self.started_us)} s: {proc.spec.description}"

    def fail(self, now: int) -> None:
        """The procedure is past its timeout: the outputs are held safe."""
        proc = self.active
        assert proc is not None
        self._status("failed")
        self.ended_us = now
        step = proc.spec.steps[self.step]
        self.message = (f"not done within {seconds(proc.spec.timeout_us)} s (step "
                        f"{self.step + 1}, {step.description.lower()}, did not end): "
                        "outputs held safe")

    @property
    def filter_stage(self) -> FilterStage | None:
        return self.active.filter if self.active is not None else None

    def unmask(self, mask: tuple[bool, ...] | None) -> tuple[bool, ...] | None:
        """The diagnosers' mask without the outputs the running procedure drives."""
        if mask is None or self.active is None:
            return mask
        driven = self.active.driven
        lifted = tuple(m and k not in driven for k, m in enumerate(mask))
        return lifted if any(lifted) else None

    def state(self, now: int) -> RecoveryState:
        proc = self.active
        if proc is None:
            if not self.needed:
                return self._idle
            shown = self._shown_needed  # the same needs: the same state (read every scan)
            if shown is None or shown.needed != self.needed:
                shown = self._shown_needed = RecoveryState(needed=self.needed,
                                                           procedures=self.catalogue)
            return shown
        spec = proc.spec
        step_text = spec.steps[self.step].description if self.status == "running" else ""
        return RecoveryState(spec.name, spec.device, spec.description, self.status,
                             self.step + 1 if self.status == "running" else 0,
                             len(spec.steps), step_text, self.started_us,
                             (self.ended_us if self.ended_us is not None else now)
                             - self.started_us, spec.timeout_us, self.message,
                             self.needed, self.catalogue)

    def capture(self) -> tuple[object, ...]:
        return (self.active, self.status, self.step, self.started_us, self.message,
                self.ended_us, self.held_since, self.needed,
                tuple(p.needed_since for p in self.procedures.values()))

    def restore(self, state: tuple[Any, ...]) -> None:
        (self.active, status, self.step, self.started_us, self.message, self.ended_us,
         self.held_since, self.needed, since) = state
        self._status(status)
        for proc, value in zip(self.procedures.values(), since, strict=True):
            proc.needed_since = value


def recovery_stage(project: Project, layout: Layout, safe: tuple[bool, ...],
                   filter_args: Solver,
                   mask_flags: Mapping[str, tuple[str, ...]]) -> RecoveryStage | None:
    """The project's recovery procedures as a stage (None: it declares none)."""
    return RecoveryStage(project, layout, safe, filter_args, mask_flags) \
        if recoveries_of(project) else None


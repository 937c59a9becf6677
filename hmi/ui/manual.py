"""What the manual-mode dialogs say about the control program (docs/ui.md, "Manual mode").

In manual mode the program waits (hmi.engine.control, ``ControlRuntime.hold``): no step
changes, its step times and memories hold, and leaving manual mode resumes it from the steps
where it waited. The dialog that enters manual mode says so and names those steps; the one
that leaves it names the steps the program resumes from, and the outputs their actions order
again at the next scan (the operator may have moved the plant meanwhile: an order given
again may start again what it started before).
"""

from __future__ import annotations

from hmi.engine.snapshot import Snapshot
from hmi.project.model import ControlLaw, Project
from hmi.timefmt import seconds


def steps_text(law: ControlLaw, active: tuple[str, ...], engineering: bool = True) -> str:
    """'X3 (A pallet waits at B), X11 (Robot transfers the pallet…)': the steps, each with
    its description when it has one; in the operator view the descriptions alone
    ('“A pallet waits at B”')."""
    described = {s.name: s.description for s in law.grafcet.steps} if law.grafcet else {}
    if not engineering:
        return ", ".join(f"\u201c{described[name]}\u201d" if described.get(name) else
                         "a step" for name in active)
    return ", ".join(f"{name} ({described[name]})" if described.get(name) else name
                     for name in active)


def ordered_again(project: Project, law: ControlLaw, active: tuple[str, ...]
                  ) -> tuple[str, ...]:
    """The outputs the continuous actions of the steps `active` order (some under a
    condition), in the project's order."""
    if law.grafcet is None:
        return ()
    targets = {a.target for s in law.grafcet.steps if s.name in active
               for a in s.actions if a.kind == "N"}
    return tuple(v.name for v in project.outputs if v.name in targets)


def enter_lines(project: Project, law: ControlLaw, snap: Snapshot,
                engineering: bool = True) -> list[str]:
    """The program's part of the enter-manual dialog (one sentence a line: each wraps)."""
    if law.grafcet is None:
        return ["The control program waits: its equations are not evaluated and its "
                "memories hold until you leave manual mode; it then resumes from there."]
    where = steps_text(law, snap.active_steps, engineering) or "its initial steps"
    # (the cell keeps running while the dialog is open: the steps are those of its scan,
    # and the program waits at the ones it is in when the operator confirms)
    return ["The control program waits at the steps it is in when you confirm (when this "
            f"opened, at {seconds(snap.time_us)} s: {where}): no step changes, and its step "
            "times and memories hold until you leave manual mode; it then resumes from there."]


def leave_lines(project: Project, law: ControlLaw, snap: Snapshot,
                engineering: bool = True) -> list[str]:
    """The program's part of the leave-manual dialog."""
    if law.grafcet is None:
        return ["The control program resumes with its memories as they were, and drives "
                "the outputs again."]
    active = snap.active_steps
    where = steps_text(law, active, engineering) or "its initial steps"
    lines = [f"The program resumes from {where}, "
             "its step times going on from where they stopped, and drives the outputs "
             "again."]
    again = ordered_again(project, law, active)
    if again:
        lines.append(f"These steps order {', '.join(again)} again at the next scan.")
    return lines

"""What each role may do, per command; fail closed.

A command whose type is not in :data:`REQUIRED` is refused to every role, and so is a role
that is not one of :data:`ROLES` (a typo in a users file never becomes a right). The table
follows the roles as operators meet them: a viewer sees everything and changes nothing; an
operator runs the cell (acknowledge, shelve, comment, fault reset, manual mode, recovery,
the explanation's policies, the simulation's buttons and faults); an engineer may also
change the safety filter's policy and force outputs in manual mode. Releasing a forced
output is an operator's: it returns the output to the program's safe side.
"""

from __future__ import annotations

from hmi.engine.commands import (
    Acknowledge,
    ChoosePolicy,
    Command,
    CommentAlarm,
    EndRecovery,
    FaultReset,
    InjectFault,
    ManualOutput,
    Pause,
    ReleaseDevice,
    RepairFaults,
    Resume,
    SetInput,
    SetMode,
    SetPolicy,
    SetSpeed,
    SetView,
    Shelve,
    StartRecovery,
    StepScans,
    StopDevice,
    Unshelve,
)

ROLES = ("viewer", "operator", "engineer")
RANK = {role: rank for rank, role in enumerate(ROLES)}
DOORS = ("terminal", "browser", "opcua", "cli")

# The least role each command needs.
REQUIRED: dict[type, str] = {
    Pause: "operator", Resume: "operator", StepScans: "operator", SetSpeed: "operator",
    SetMode: "operator", FaultReset: "operator", Acknowledge: "operator",
    StopDevice: "operator", ReleaseDevice: "operator", ChoosePolicy: "operator",
    StartRecovery: "operator", EndRecovery: "operator", Shelve: "operator",
    Unshelve: "operator", CommentAlarm: "operator", SetInput: "operator",
    InjectFault: "operator", RepairFaults: "operator",
    ManualOutput: "operator",  # forcing on/off is an engineer's: required_role
    SetPolicy: "engineer",
    SetView: "viewer",  # what this screen names; nothing in the cell changes
}

_WHAT = {"engineer": "an engineer's", "operator": "an operator's"}


def required_role(command: Command) -> str | None:
    """The least role `command` needs; None: nobody may send it (an unknown command)."""
    if isinstance(command, ManualOutput) and command.value is not None:
        return "engineer"  # forcing an output
    return REQUIRED.get(type(command))


def may(role: str, command: Command) -> bool:
    needed = required_role(command)
    return needed is not None and role in RANK and RANK[role] >= RANK[needed]


def refusal(role: str, command: Command) -> str:
    """Why `role` may not send `command`, in the operator's words."""
    from hmi.engine.commands import describe
    needed = required_role(command)
    if role not in RANK:
        return f"refused: {role!r} is not a role (viewer, operator or engineer)"
    if needed is None:
        return f"refused: {describe(command)} is not a command any role may send"
    if role == "viewer":
        return f"refused: {describe(command)}: a viewer may look but not act"
    return (f"refused: {describe(command)} is {_WHAT[needed]} command "
            f"(signed in as {role})")


def needs_reason(command: Command) -> bool:
    """Commands whose reason is asked for and journalled (EU GMP Annex 11 §9): the filter
    policy, forcing, manual mode, recovery, shelving."""
    return (isinstance(command, (SetPolicy, StartRecovery, Shelve))
            or (isinstance(command, SetMode) and command.manual)
            or (isinstance(command, ManualOutput) and command.value is not None))


def needs_password(command: Command) -> bool:
    """Switching the filter to `monitor` (unsafe orders pass) asks for the password again."""
    return isinstance(command, SetPolicy) and command.policy == "monitor"

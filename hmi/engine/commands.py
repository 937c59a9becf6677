"""Operator and engineer commands: the one way anything outside the engine changes it.

Commands are plain data so that the UI, a headless script, a test and the journal all speak
the same language. :class:`hmi.session.session.Session` accepts every command; the run-state
ones (pause, step) it handles itself, the others it passes to the engine.
"""

from __future__ import annotations

from dataclasses import dataclass

from hmi.project.injection import Injection
from hmi.timefmt import format_duration


@dataclass(frozen=True)
class Pause:
    pass


@dataclass(frozen=True)
class Resume:
    pass


@dataclass(frozen=True)
class StepScans:
    count: int = 1


@dataclass(frozen=True)
class SetSpeed:
    factor: float | None  # 1.0 real time, 10.0 ten times faster, None as fast as possible


@dataclass(frozen=True)
class SetMode:
    manual: bool


@dataclass(frozen=True)
class ManualOutput:
    """Request an output on/off in manual mode (it still goes through the filter)."""

    name: str
    value: bool | None  # None releases the request (the output returns to 0)


@dataclass(frozen=True)
class FaultReset:
    pass


@dataclass(frozen=True)
class SetPolicy:
    policy: str  # monitor, block, correct


@dataclass(frozen=True)
class InjectFault:
    injection: Injection


@dataclass(frozen=True)
class RepairFaults:
    """Simulation only: the technician repairs the faulty devices (one, or all)."""

    device: str | None = None


@dataclass(frozen=True)
class SetInput:
    """Press or release an input no simulated device drives (a push button)."""

    name: str
    value: bool


@dataclass(frozen=True)
class Acknowledge:
    """Acknowledge one alarm (by key) or all of them (key None)."""

    key: str | None = None


@dataclass(frozen=True)
class StopDevice:
    """Hold every output of a device at its safe value until released (an operator policy)."""

    device: str


@dataclass(frozen=True)
class ReleaseDevice:
    device: str


@dataclass(frozen=True)
class ChoosePolicy:
    """The operator picks one of the policies an explanation offers; it is carried out."""

    key: str  # the explanation's (alarm's) key
    policy: str  # the policy's id


@dataclass(frozen=True)
class StartRecovery:
    """Enter recovery mode and run a declared recovery procedure (hmi.project.recovery)."""

    procedure: str


@dataclass(frozen=True)
class EndRecovery:
    """Leave recovery mode: automatic operation, the control law from its initial steps."""


@dataclass(frozen=True)
class Shelve:
    """Shelve an alarm (ISA-18.2 §11, OPC UA Part 9): hidden from the list, still journalled,
    back by itself after `duration_us`, or (None) one-shot: back once its condition clears."""

    key: str
    duration_us: int | None = None


@dataclass(frozen=True)
class Unshelve:
    key: str


@dataclass(frozen=True)
class CommentAlarm:
    """An operator's comment on an alarm, for the journal and the next shift."""

    key: str
    text: str


@dataclass(frozen=True)
class SetView:
    """The HMI's view: the operator's (devices and plain words) or the engineering one (the
    internal names, states, flags and bounds too). Changes nothing in the cell; journalled,
    so the record says what the operator was shown."""

    engineering: bool


Command = (Pause | Resume | StepScans | SetSpeed | SetMode | ManualOutput | FaultReset
           | SetPolicy | InjectFault | RepairFaults | SetInput | Acknowledge | StopDevice
           | ReleaseDevice | ChoosePolicy | StartRecovery | EndRecovery | Shelve | Unshelve
           | CommentAlarm | SetView)


@dataclass(frozen=True)
class CommandResult:
    accepted: bool
    message: str

    @classmethod
    def ok(cls, message: str) -> CommandResult:
        return cls(True, message)

    @classmethod
    def refused(cls, message: str) -> CommandResult:
        return cls(False, message)


def describe(command: Command) -> str:
    """One line for the journal and the UI."""
    match command:
        case Pause():
            return "pause"
        case Resume():
            return "run"
        case StepScans(count=n):
            return f"step {n} scan{'s' if n != 1 else ''}"
        case SetSpeed(factor=f):
            return "speed: as fast as possible" if f is None else f"speed: x{f:g}"
        case SetMode(manual=m):
            return "enter manual mode" if m else "leave manual mode"
        case ManualOutput(name=n, value=v):
            return f"manual {n} " + ("release" if v is None else ("on" if v else "off"))
        case FaultReset():
            return "fault reset"
        case SetPolicy(policy=p):
            return f"filter policy: {p}"
        case InjectFault(injection=i):
            return f"inject fault {i}"
        case RepairFaults(device=d):
            return "repair simulated faults" + (f" of {d}" if d else "")
        case SetInput(name=n, value=v):
            return f"input {n} {'on' if v else 'off'}"
        case Acknowledge(key=k):
            return "acknowledge all alarms" if k is None else f"acknowledge alarm {k}"
        case StopDevice(device=d):
            return f"stop device {d}"
        case ReleaseDevice(device=d):
            return f"release device {d}"
        case ChoosePolicy(key=k, policy=p):
            return f"choose policy {p} for {k}"
        case StartRecovery(procedure=p):
            return f"start recovery {p}"
        case EndRecovery():
            return "leave recovery mode"
        case Shelve(key=k, duration_us=d):
            return (f"shelve alarm {k} once (until it clears)" if d is None
                    else f"shelve alarm {k} for {format_duration(d)}")
        case Unshelve(key=k):
            return f"unshelve alarm {k}"
        case CommentAlarm(key=k):
            return f"comment on alarm {k}"
        case SetView(engineering=e):
            return "engineering view" if e else "operator view"
    return repr(command)

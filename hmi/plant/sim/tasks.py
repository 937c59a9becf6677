"""What a simulated device really did, task by task: the ground truth monitors are judged on.

A stopwatch monitor measures a task from the PLC's side (signals seen at scan instants). The
device knows the truth: when it started, when it ended and how long it actually worked. The
earliness sweep and the tests compare the monitor's verdict with this record, so the check
does not depend on the code it checks.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TaskRecord:
    start_us: int
    end_us: int | None  # None: not finished (yet)
    work_us: int  # time actually spent working, i.e. not halted
    aborted: bool = False  # ended by dropping the order, not by finishing the work

    @property
    def elapsed_us(self) -> int | None:
        return None if self.end_us is None else self.end_us - self.start_us


class TaskLog:
    """A device's tasks: finished ones and the one in progress."""

    def __init__(self) -> None:
        self.done: list[TaskRecord] = []
        self._start: int | None = None
        self._work = 0

    @property
    def active(self) -> bool:
        return self._start is not None

    def begin(self, t: int) -> None:
        self._start = t
        self._work = 0

    def worked(self, dt: int) -> None:
        if self._start is not None:
            self._work += dt

    def finish(self, t: int, aborted: bool = False) -> None:
        if self._start is not None:
            self.done.append(TaskRecord(self._start, t, self._work, aborted))
            self._start = None

    def records(self) -> tuple[TaskRecord, ...]:
        current = () if self._start is None else (TaskRecord(self._start, None, self._work),)
        return (*self.done, *current)

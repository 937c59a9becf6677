"""The earliness sweep: a stopwatch monitor against a plain watchdog, over interruptions.

    plchmi sweep PROJECT [--task NAME] [--fault DEVICE.CODE] [--starts 0.5s,1s,...]
                         [--lengths 0.5s,1s,...] [--attempt N]

For every interruption start w (measured from the task's start) and length L, one headless
run injects ``DEVICE.CODE@(t0 + w)+L``, where t0 is the instant the task starts (its N-th
start in an undisturbed run). Each row sets three things side by side:

* the truth, from the simulated device's own record of the task (when it really started and
  ended, how long it really worked): in time when it ended with elapsed time in
  [alpha, gamma) and work in [alpha, beta] (002 Property 1);
* the monitor's detection on that attempt (instant, x, y, rule), if any;
* the instant a plain watchdog (fault when x reaches gamma) fired on the same attempt.

The properties the table must show: no monitor fault on an attempt that was in time (no false
alarm), a monitor fault on every other attempt, never later than the watchdog. The command
exits 1 when a row breaks one of them.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from hmi.engine.stopwatch import Detection, WatchdogTrip
from hmi.errors import UsageError
from hmi.limits import MAX_RUN_SCANS
from hmi.timefmt import format_duration, seconds

if TYPE_CHECKING:
    from hmi.engine.monitors import MonitorState
    from hmi.engine.scan import Engine
    from hmi.engine.snapshot import Snapshot
    from hmi.plant.sim.tasks import TaskRecord
    from hmi.project.injection import Injection
    from hmi.project.model import Project, TaskMonitor

BASELINE_LIMIT_US = 600_000_000  # give up finding the task's start after 10 virtual minutes


@dataclass(frozen=True)
class SweepRow:
    start_us: int  # interruption start, after the task's start
    length_us: int
    end_x_us: int | None  # truth: the task's elapsed time at its end (None: not ended)
    work_us: int  # truth: time the device actually worked on it
    in_time: bool  # truth: ended inside [alpha, gamma) with work in [alpha, beta]
    monitor: Detection | None
    watchdog: WatchdogTrip | None

    @property
    def false_alarm(self) -> bool:
        return self.in_time and self.monitor is not None

    @property
    def missed(self) -> bool:
        return not self.in_time and self.monitor is None

    @property
    def later_than_watchdog(self) -> bool:
        return (self.monitor is not None and self.watchdog is not None
                and self.monitor.time_us > self.watchdog.time_us)

    @property
    def earlier_us(self) -> int | None:
        if self.monitor is None or self.watchdog is None:
            return None
        return self.watchdog.time_us - self.monitor.time_us


@dataclass(frozen=True)
class SweepResult:
    task: str
    title: str
    window: tuple[int, int, int]  # alpha, beta, gamma
    fault: str  # DEVICE.CODE
    attempt: int
    task_start_us: int
    period_us: int
    rows: tuple[SweepRow, ...]

    @property
    def ok(self) -> bool:
        return not any(r.false_alarm or r.missed or r.later_than_watchdog for r in self.rows)


def cmd_sweep(args: argparse.Namespace, project: Project) -> int:
    result = run_sweep(project, args.task, args.fault, args.starts, args.lengths,
                       attempt=args.attempt, control=args.control)
    print(format_sweep(result))
    return 0 if result.ok else 1


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------


def _pick_task(project: Project, name: str | None) -> TaskMonitor:
    from hmi.project.monitors import monitors_of
    monitors = monitors_of(project)
    if not monitors:
        raise UsageError("the project declares no monitors")
    if name is None:
        return monitors[0]
    for m in monitors:
        if m.name == name:
            return m
    raise UsageError(f"--task {name!r}: the project monitors " + ", ".join(
        m.name for m in monitors))


def _default_fault(project: Project, task: TaskMonitor) -> str:
    """The interruption fault of the device whose sensor the task's interruption reads."""
    from hmi.logic.expr import variables
    from hmi.project.device_models import DEVICE_MODELS
    exprs = [e for e in (task.interrupted, task.interrupt, task.resume) if e is not None]
    names = {v.name for e in exprs for v in variables(e)}
    found: list[str] = []
    for spec in project.plant.devices:
        model = DEVICE_MODELS.get(spec.model)
        code = model.interruption_fault if model is not None else None
        if code and names & set(spec.ports.values()):
            found.append(f"{spec.name}.{code}")
    if len(found) != 1:
        raise UsageError(f"cannot tell which fault interrupts task {task.name!r}; name it "
                         "with --fault DEVICE.CODE")
    return found[0]


def _engine(project: Project, control: str | None, injections: Iterable[Injection] = ()
            ) -> Engine:
    from hmi.engine.build import EngineOptions, build_engine
    from hmi.plant.sim.plant import SimPlant
    plant = SimPlant(project)
    for injection in injections:
        plant.inject(injection)
    return build_engine(project, plant, EngineOptions(control=control))


def _scan(engine: Engine) -> Snapshot:
    """The next scan's snapshot, one period after the last in virtual time (the first at 0),
    as a headless run scans."""
    return engine.step(engine.now + engine.project.scan_period_us if engine.scan else 0)


def _state(snap: Snapshot, name: str) -> MonitorState:
    return next(m for m in snap.monitors if m.name == name)


def find_task_start(project: Project, task: str, attempt: int = 1,
                    control: str | None = None) -> int:
    """When the task starts for the `attempt`-th time in an undisturbed run (µs)."""
    engine = _engine(project, control)
    while True:
        m = _state(_scan(engine), task)
        if m.attempt >= attempt:
            return m.attempt_start_us
        if engine.now > BASELINE_LIMIT_US:
            raise UsageError(f"task {task!r} did not start {attempt} time(s) in "
                             f"{seconds(BASELINE_LIMIT_US)} s of an undisturbed run")


def run_one(project: Project, task: TaskMonitor, fault: str, t0: int, start_us: int, length_us: int,
            attempt: int, control: str | None = None) -> SweepRow:
    """One run of the sweep: the task interrupted `start_us` after t0 for `length_us`."""
    from hmi.project.injection import parse_injection
    from hmi.studies.monitor_report import MonitorLog
    injection = parse_injection(f"{fault}@{t0 + start_us}us+{length_us}us")
    engine = _engine(project, control, [injection])
    from hmi.plant.sim.plant import SimPlant
    plant = engine.plant
    assert isinstance(plant, SimPlant)  # _engine's
    device = plant.resolve(injection)
    records: Callable[[], tuple[TaskRecord, ...]] | None = getattr(device, "task_records",
                                                                   None)
    if records is None:
        raise UsageError(f"device {device.name!r} ({device.MODEL}) keeps no task record, so "
                         "the sweep has no ground truth for it")
    log = MonitorLog()
    horizon = t0 + start_us + length_us + 2 * task.gamma_us
    while engine.now < horizon or not engine.started:
        snap = _scan(engine)
        log.add(snap)
        m = _state(snap, task.name)
        record = _record(records(), t0)
        attempt_over = m.attempt > attempt or (m.attempt == attempt and not m.running)
        if attempt_over and record is not None and record.end_us is not None:
            break
    record = _record(records(), t0)
    end_x = None if record is None or record.end_us is None else record.end_us - t0
    work = record.work_us if record is not None else 0
    in_time = (end_x is not None and task.alpha_us <= end_x < task.gamma_us
               and task.alpha_us <= work <= task.beta_us)
    return SweepRow(start_us, length_us, end_x, work, in_time,
                    log.detection(task.name, attempt), log.trip(task.name, attempt))


def _record(records: Iterable[TaskRecord], t0: int) -> TaskRecord | None:
    return next((r for r in records if r.start_us == t0), None)


def run_sweep(project: Project, task_name: str | None, fault: str | None, starts: Sequence[int],
              lengths: Sequence[int], attempt: int = 1,
              control: str | None = None) -> SweepResult:
    if project.plant.kind != "sim":
        raise UsageError("the sweep injects faults: it needs a simulated plant")
    if control and control not in project.controls:
        raise UsageError(f"--control {control!r}: the project has " + ", ".join(project.controls))
    task = _pick_task(project, task_name)
    fault = fault or _default_fault(project, task)
    from hmi.plant.sim.plant import SimPlant
    from hmi.project.injection import parse_injection
    try:
        SimPlant(project).resolve(parse_injection(f"{fault}@0s"))
    except UsageError as exc:
        raise UsageError(f"--fault {fault!r}: {exc}") from None
    if attempt < 1:
        raise UsageError("--attempt counts from 1")
    t0 = find_task_start(project, task.name, attempt, control)
    check_sweep_size(len(starts) * len(lengths),
                     t0 + max(starts) + max(lengths) + 2 * task.gamma_us,
                     project.scan_period_us)
    rows = tuple(run_one(project, task, fault, t0, w, length, attempt, control)
                 for w in starts for length in lengths)
    return SweepResult(task.name, task.title, (task.alpha_us, task.beta_us, task.gamma_us),
                       fault, attempt, t0, project.scan_period_us, rows)


def check_sweep_size(runs: int, horizon_us: int, period_us: int) -> None:
    """A sweep runs at most MAX_RUN_SCANS scans in all, as one headless run may (a list of a
    thousand starts of an hour each would run for days)."""
    scans = runs * (horizon_us // period_us + 1)
    if scans > MAX_RUN_SCANS:
        raise UsageError(f"the sweep is {runs:,} runs of up to {horizon_us // period_us + 1:,} "
                         f"scans, more than the {MAX_RUN_SCANS:,} scans plchmi runs at once "
                         "(fewer or shorter --starts and --lengths)")


# --------------------------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------------------------


def _s(us: int | None) -> str:
    return "-" if us is None else seconds(us)


def format_sweep(result: SweepResult) -> str:
    a, b, g = (format_duration(v) for v in result.window)
    lines = [
        f"Earliness sweep of task {result.task} ({result.title})",
        f"  normal [{a}, {b}], acceptable [{a}, {g}]; interruption {result.fault} injected w "
        f"after the task's start (attempt {result.attempt}, at {seconds(result.task_start_us)} "
        f"s) for L; scan {format_duration(result.period_us)}; times in s from the task's start",
        "",
    ]
    header = ["w", "L", "ends at", "work", "in time", "monitor x", "y", "rule",
              "watchdog x", "earlier by", "check"]
    table = [header]
    for r in result.rows:
        m, w = r.monitor, r.watchdog
        problem = ("FALSE ALARM" if r.false_alarm else "MISSED" if r.missed
                   else "LATER" if r.later_than_watchdog else "ok")
        table.append([
            format_duration(r.start_us), format_duration(r.length_us),
            _s(r.end_x_us) if r.end_x_us is not None else "not yet", seconds(r.work_us),
            "yes" if r.in_time else "no",
            _s(m.x_us if m else None), _s(m.y_us if m else None), m.rule if m else "-",
            _s(w.x_us if w else None), _s(r.earlier_us), problem])
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    for row in table:
        lines.append("  " + "  ".join(cell.rjust(widths[i]) if i not in (7, 10)
                                      else cell.ljust(widths[i])
                                      for i, cell in enumerate(row)).rstrip())
    faulty = [r for r in result.rows if not r.in_time]
    fine = [r for r in result.rows if r.in_time]
    detected = [r for r in faulty if r.monitor is not None]
    by_watchdog = [r for r in faulty if r.watchdog is not None]
    earlier = [r.earlier_us for r in detected if r.earlier_us]
    lines += [
        "",
        f"{len(result.rows)} runs: {len(fine)} in time, {len(faulty)} late or out of window.",
        f"  in time: monitor false alarms {sum(r.false_alarm for r in fine)}, watchdog false "
        f"alarms {sum(r.watchdog is not None for r in fine)}",
        f"  late/out of window: detected by the monitor {len(detected)}/{len(faulty)}, by the "
        f"watchdog {len(by_watchdog)}/{len(faulty)}; monitor later than the watchdog "
        f"{sum(r.later_than_watchdog for r in result.rows)}; strictly earlier "
        f"{len(earlier)}" + (f", by {seconds(min(earlier))} to {seconds(max(earlier))} s"
                             if earlier else ""),
        "OK: no false alarm, no miss, never later than the watchdog" if result.ok
        else "FAILED: see the check column",
    ]
    return "\n".join(lines)

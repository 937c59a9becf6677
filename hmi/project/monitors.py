"""The `monitors:` section: interruptible tasks watched by stopwatch monitors (002).

    monitors:
      conveyor:
        description: Conveyor C1 carrying a pallet from the pusher to sensor B
        device: Conveyor C1
        start: rise(d)              # events: the scan where the condition holds
        end: rise(B)
        interrupt: rise(Hc)         # a pair of events ...
        resume: fall(Hc)
        # interrupted: Hc           # ... or one level: the task is suspended while true
        normal: [3s, 4s]            # [alpha, beta]
        acceptable: [3s, 5s]        # [alpha, gamma], beta < gamma
        label: conveyor_fault       # default <task>_fault

Conditions read inputs, outputs, timers and observers. Monitors run at the end of the scan,
after the output scan, so an output is read as written at this scan: `rise(d)` is the scan
that sends the order d. They never read the control law's steps or memories: a monitor
watches the plant, not the program that drives it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hmi.errors import SourcePos
from hmi.logic.expr import Expr
from hmi.logic.names import NAME_RE
from hmi.project.model import TaskMonitor
from hmi.project.yamlnodes import NodeError, YNode
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from hmi.project.model import Project
    from hmi.project.reader import ProjectReader

MONITOR_KINDS = {"input", "output", "timer", "observer"}
MONITOR_KEYS = {"description", "device", "label", "start", "end", "interrupted", "interrupt",
                "resume", "normal", "acceptable"}
MONITOR_CONTEXT = ("in a monitor (it may read inputs, outputs, timers and observers, not the "
                   "control law's steps or memories)")
LABEL_SUFFIX = "_fault"


def monitors_of(project: Project) -> tuple[TaskMonitor, ...]:
    return project.monitors


def parse_monitors(loader: ProjectReader, period_us: int) -> tuple[TaskMonitor, ...]:
    """Read the `monitors:` section after every name is declared; report, never raise."""
    out: list[TaskMonitor] = []
    labels: dict[str, SourcePos] = {}
    for name, node, kpos in loader.section_items("monitors"):
        name = str(name)
        if not NAME_RE.match(name):
            loader.diag.error(kpos, f"{name!r} is not a valid task name",
                              "letters, digits and _, not starting with a digit")
            continue
        monitor = _monitor(loader, name, node, kpos, period_us, labels)
        if monitor is not None:
            out.append(monitor)
    return tuple(out)


def _monitor(loader: ProjectReader, name: str, node: YNode, kpos: SourcePos, period_us: int,
             labels: dict[str, SourcePos]) -> TaskMonitor | None:
    what = f"monitor {name!r}"
    fields = loader.guard(lambda: node.check_keys(
        what, MONITOR_KEYS, ["start", "end", "normal", "acceptable"]))
    if fields is None:
        return None
    text = {key: loader.guard(lambda k=key: fields[k].as_str(k), "") if key in fields else ""
            for key in ("description", "device", "label")}
    label = text["label"] or f"{name}{LABEL_SUFFIX}"
    label_pos = fields["label"].pos if "label" in fields else kpos
    ok = True
    if not NAME_RE.match(label):
        loader.diag.error(label_pos, f"fault label {label!r} is not a valid name",
                          "letters, digits and _, not starting with a digit")
        ok = False
    elif label in labels:
        loader.diag.error(label_pos, f"fault label {label!r} is already used by another "
                          f"monitor at {labels[label]}", "one label per monitor")
        ok = False
    elif label in loader.namespace:
        loader.diag.error(label_pos, f"fault label {label!r} is already declared as "
                          f"{loader.namespace[label]} at {loader.declared_at[label]}",
                          "a label distinct from the project's variables")
        ok = False
    else:
        labels[label] = label_pos

    def condition(key: str) -> Expr | None:
        return loader.expr(fields[key], f"the {key} condition of {what}", MONITOR_KINDS,
                           context=MONITOR_CONTEXT)

    start, end = condition("start"), condition("end")
    interrupted = interrupt = resume = None
    if "interrupted" in fields and ("interrupt" in fields or "resume" in fields):
        other = "interrupt" if "interrupt" in fields else "resume"
        loader.diag.error(fields[other].pos, f"{what} has both 'interrupted' and '{other}'",
                          "either a level 'interrupted: expr' or the events 'interrupt:' "
                          "and 'resume:'")
        ok = False
    elif "interrupted" in fields:
        interrupted = condition("interrupted")
        ok = ok and interrupted is not None
    elif "interrupt" in fields or "resume" in fields:
        if "interrupt" not in fields or "resume" not in fields:
            have = "interrupt" if "interrupt" in fields else "resume"
            need = "resume" if have == "interrupt" else "interrupt"
            loader.diag.error(fields[have].pos, f"{what} has '{have}' but no '{need}'",
                              "both 'interrupt:' and 'resume:' events, or a level "
                              "'interrupted:'")
            ok = False
        else:
            interrupt, resume = condition("interrupt"), condition("resume")
            ok = ok and interrupt is not None and resume is not None
    windows = _windows(loader, what, fields, period_us)
    if not ok or start is None or end is None or windows is None:
        return None
    alpha, beta, gamma = windows
    return TaskMonitor(name, label, text["description"], text["device"] or None, start, end,
                       interrupted, interrupt, resume, alpha, beta, gamma, kpos)


def _pair(node: YNode, what: str, upper: str) -> tuple[int, int]:
    items = node.as_seq(what)
    if len(items) != 2:
        raise NodeError(node.pos, f"{what} has {len(items)} values",
                        f"two durations [alpha, {upper}], e.g. [3s, 4s]")
    low = items[0].as_duration(f"alpha of {what}", allow_zero=True)
    high = items[1].as_duration(f"{upper} of {what}")
    return low, high


def _windows(loader: ProjectReader, what: str, fields: dict[str, YNode],
             period_us: int) -> tuple[int, int, int] | None:
    normal_node, accept_node = fields["normal"], fields["acceptable"]
    normal = loader.guard(lambda: _pair(normal_node, f"the normal duration of {what}", "beta"))
    accept = loader.guard(lambda: _pair(accept_node, f"the acceptable duration of {what}",
                                        "gamma"))
    if normal is None or accept is None:
        return None
    (alpha, beta), (alpha2, gamma) = normal, accept
    f = format_duration
    ok = True
    if alpha > beta:
        loader.diag.error(normal_node.value[0].pos, f"the normal duration of {what} is "
                          f"[{f(alpha)}, {f(beta)}]: alpha is longer than beta",
                          "[alpha, beta] with alpha <= beta")
        ok = False
    if alpha2 != alpha:
        loader.diag.error(accept_node.value[0].pos, f"the acceptable duration of {what} starts "
                          f"at {f(alpha2)} but the normal one at {f(alpha)}",
                          f"the same alpha in both, [{f(alpha)}, gamma] (002 §2)")
        ok = False
    if gamma <= beta:
        loader.diag.error(accept_node.value[1].pos, f"gamma {f(gamma)} of {what} is not longer "
                          f"than beta {f(beta)}", "beta < gamma: the acceptable duration "
                          "extends the normal one (002 §2)")
        ok = False
    if not ok:
        return None
    for value, node in ((alpha, normal_node.value[0]), (beta, normal_node.value[1]),
                        (gamma, accept_node.value[1])):
        if value % period_us:
            loader.diag.warning(node.pos, f"{f(value)} in {what} is not a multiple of the scan "
                                f"period {f(period_us)}: detection is quantised to the scan")
    return alpha, beta, gamma

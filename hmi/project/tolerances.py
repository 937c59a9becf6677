"""A device's `tolerances:`: the ranges of its parameters the project is built for.

    plant:
      kind: sim
      model: valve
      params: {travel: 2s, stall_tolerance: 1s}
      tolerances:
        travel: ±20%             # around the parameter's value: 1.6s to 2.4s
        bounce: [0ms, 20ms]      # from, to
      scan_jitter: 10ms          # a scan starts up to this late (the controller's tolerance)

A real valve's travel time moves with wear, temperature and supply, its switches bounce and
answer late, a PLC's scans start late: a diagnoser whose windows hold for one exact simulator
diagnoses a healthy valve faulty. The tolerances say what the design must hold for;
`plchmi check`, `plchmi band`, `diagnose` and `campaign` run the cell across them
(hmi/studies/band.py). Only the parameters a model marks as varying (ParamSpec.tolerable) take
one; the nominal value (the parameter's, or its default) must lie in the range, and the range
within what the parameter allows.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from hmi.project.device_models import DeviceModel, ParamSpec
from hmi.project.model import Tolerance
from hmi.project.reader import ProjectReader
from hmi.project.yamlnodes import NodeError, YNode
from hmi.timefmt import format_duration

FORMS = "±P% around the parameter's value (e.g. ±20%), or [low, high] (e.g. [1.6s, 2.4s])"
_RELATIVE = re.compile(r"^\s*(?:±|\+-|\+/-)\s*(\d+(?:\.\d+)?)\s*%\s*$")


def tolerable(model: DeviceModel) -> tuple[str, ...]:
    """The parameters of a model that may declare a tolerance."""
    return tuple(name for name, spec in model.params.items() if spec.tolerable)


def parse_tolerances(reader: ProjectReader, node: YNode, model: DeviceModel,
                     params: Mapping[str, Any], owner: str) -> tuple[Tolerance, ...]:
    """The `tolerances:` mapping of one device; errors reported at their line and column."""
    allowed = tolerable(model)
    expected = ("one of " + ", ".join(allowed)) if allowed else \
        f"nothing: the {model.name} model declares no parameter that varies"
    mapping = reader.guard(lambda: node.as_map(f"the tolerances of {owner}"), {})
    out = []
    for pname, vnode in mapping.items():
        pname = str(pname)
        kpos = node.key_pos.get(pname, node.pos)
        spec = model.params.get(pname)
        if spec is None:
            reader.diag.error(kpos, f"{owner}: the {model.name} model has no parameter "
                              f"{pname!r}", expected)
            continue
        if not spec.tolerable:
            reader.diag.error(kpos, f"{owner}: parameter {pname!r} of the {model.name} model "
                              "takes no tolerance", expected)
            continue
        nominal = params.get(pname, spec.default)
        tolerance = reader.guard(lambda s=spec, n=vnode, p=pname, v=nominal:
                                 _tolerance(s, n, p, v, owner))
        if tolerance is not None:
            out.append(tolerance)
    return tuple(out)


def _tolerance(spec: ParamSpec, node: YNode, name: str, nominal: float,
               owner: str) -> Tolerance:
    what = f"{owner}: the tolerance of {name!r}"
    if node.kind == "seq":
        items = node.as_seq(what)
        if len(items) != 2:
            raise NodeError(node.pos, f"{what} has {len(items)} values", FORMS)
        low, high = (_value(spec, item, f"{what}'s {end}")
                     for item, end in zip(items, ("low end", "high end"), strict=True))
        text = f"[{_show(spec, low)}, {_show(spec, high)}]"
        if low >= high:
            raise NodeError(node.pos, f"{what} is an empty range ({text})", "low < high")
    elif node.kind == "scalar" and isinstance(node.value, str) and _RELATIVE.match(node.value):
        percent = float(_RELATIVE.match(node.value).group(1))  # type: ignore[union-attr]
        if not 0 < percent < 100:
            raise NodeError(node.pos, f"{what} is ±{percent:g}%", "a percentage above 0 and "
                            "below 100")
        if not nominal:
            raise NodeError(node.pos, f"{what}: ±{percent:g}% of {_show(spec, nominal)} is no "
                            "range", "[low, high] for a parameter whose value is 0")
        low = nominal * (1 - percent / 100)
        high = nominal * (1 + percent / 100)
        if spec.kind == "duration":
            low, high = round(low), round(high)
        text = f"±{percent:g}%"
    else:
        raise NodeError(node.pos, f"{what} is {node.raw!r}", FORMS)
    if not low <= nominal <= high:
        raise NodeError(node.pos, f"{what} ({_show(spec, low)} to {_show(spec, high)}) leaves "
                        f"out the parameter's value {_show(spec, nominal)}",
                        "a range holding the value the device is simulated with")
    for value in (low, high):
        if spec.kind == "duration" and value <= 0 and spec.minimum != 0:
            raise NodeError(node.pos, f"{what} reaches {_show(spec, value)}",
                            f"a range of durations longer than zero for {name!r}")
        if (spec.minimum is not None and value < spec.minimum) or \
                (spec.maximum is not None and value > spec.maximum):
            if spec.minimum is not None and spec.maximum is not None:
                bounds = f"from {_show(spec, spec.minimum)} to {_show(spec, spec.maximum)}"
            elif spec.minimum is not None:
                bounds = f"of at least {_show(spec, spec.minimum)}"
            else:
                bounds = f"of at most {_show(spec, spec.maximum)}"
            raise NodeError(node.pos, f"{what} reaches {_show(spec, value)}, out of the "
                            "parameter's range", f"values {bounds}")
    return Tolerance(name, low, high, nominal, spec.kind, text, node.pos)


def _value(spec: ParamSpec, node: YNode, what: str) -> float:
    if spec.kind == "duration":
        return node.as_duration(what, allow_zero=True)
    return node.as_number(what)


def _show(spec: ParamSpec, value: float | None) -> str:
    if value is None:
        return "?"
    return format_duration(int(value)) if spec.kind == "duration" else f"{value:g}"


def parse_scan_jitter(reader: ProjectReader, node: YNode, period_us: int) -> int:
    """`scan_jitter: 10ms`: how late a scan may start, at most one scan period (later, two
    scans would swap)."""
    jitter = reader.guard(lambda: node.as_duration("scan_jitter", allow_zero=True), 0)
    if jitter > period_us:
        reader.diag.error(node.pos, f"scan_jitter {format_duration(jitter)} is longer than the "
                          f"scan period ({format_duration(period_us)})",
                          "at most one scan period")
        return 0
    return int(jitter)

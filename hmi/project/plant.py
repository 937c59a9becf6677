"""The `plant:` section: a simulated plant's devices, or a Modbus device's connection.

Devices are checked against the catalogue of simulated models (hmi/project/device_models.py):
the model's name, its parameters (each against its ParamSpec, then together), its ports bound
to project variables, and the "device" parameters naming other devices of the plant.
"""

from __future__ import annotations

from typing import Any

from hmi.errors import SourcePos
from hmi.project.device_models import DEVICE_MODELS, ParamSpec
from hmi.project.model import (
    DeviceSpec,
    PlantSpec,
    Tolerance,
    Variable,
)
from hmi.project.reader import ProjectReader
from hmi.project.yamlnodes import NodeError, YNode


def parse_plant(reader: ProjectReader, pos: SourcePos, inputs: list[Variable],
                outputs: list[Variable], period_us: int = 10_000) -> PlantSpec:
    node = reader.sections.get("plant")
    if node is None:
        reader.diag.error(pos, "the project has no plant", "a 'plant:' section (kind: sim)")
        return PlantSpec("sim")
    fields = reader.guard(lambda: node.check_keys(
        "plant", {"kind", "model", "params", "ports", "devices", "host", "port", "unit",
                  "timeout", "read_gap", "write_refresh", "tolerances", "scan_jitter"},
        ["kind"]))
    if fields is None:
        return PlantSpec("sim")
    kind = reader.guard(lambda: reader.choice(fields["kind"], "plant kind", ("sim", "modbus")),
                        "sim")
    devices: list[DeviceSpec] = []
    # (owner, parameter, device named, where, models allowed) of each "device" parameter
    links: list[tuple[str, str, str, SourcePos, tuple[str, ...]]] = []
    wired: dict[str, tuple[str, SourcePos]] = {}  # input -> (the sensor driving it, where)
    if "model" in fields and "devices" in fields:
        reader.diag.error(fields["devices"].pos, "the plant has both 'model' and 'devices'",
                          "'model' for one device, or 'devices' for several")
    elif "model" in fields:
        device = _device(reader, None, node, fields, inputs, outputs, links, wired)
        if device:
            devices.append(device)
    elif "devices" in fields:
        dmap = reader.guard(lambda: fields["devices"].as_map("devices"), {})
        if "tolerances" in fields:
            reader.diag.error(fields["tolerances"].pos, "the plant's 'tolerances' belong to "
                              "one device", "'tolerances:' inside each device of 'devices:'")
        for dname, dnode in dmap.items():
            dfields = reader.guard(lambda n=dnode, d=dname: n.check_keys(
                f"device {d!r}", {"model", "params", "ports", "tolerances"}, ["model"]))
            if dfields is None:
                continue
            device = _device(reader, str(dname), dnode, dfields, inputs, outputs,
                             links, wired)
            if device:
                devices.append(device)
    elif kind == "sim":
        reader.diag.error(node.pos, "a simulated plant needs a model",
                          "'model: valve' or a 'devices:' mapping")
    elif "tolerances" in fields:
        reader.diag.error(fields["tolerances"].pos, "tolerances without a simulated device",
                          "'model:' (or 'devices:') with the parameters they vary")
    _check_links(reader, devices, links)
    if kind == "sim":
        bound = {var for d in devices for var in d.ports.values()}
        for var in inputs:
            if var.name not in bound:
                reader.diag.warning(var.pos, f"input {var.name!r} is not connected to the "
                                    "simulated plant; it reads 0 unless set by the operator")
    spec_kwargs: dict[str, Any] = {}
    if "host" in fields:
        spec_kwargs["host"] = reader.guard(lambda: fields["host"].as_str("host"), "127.0.0.1")
    if "port" in fields:
        spec_kwargs["port"] = reader.guard(lambda: fields["port"].as_int("port", 1, 65535),
                                           502)
    if "unit" in fields:
        spec_kwargs["unit"] = reader.guard(lambda: fields["unit"].as_int("unit", 0, 255), 1)
    if "timeout" in fields:
        spec_kwargs["timeout_us"] = reader.guard(
            lambda: fields["timeout"].as_duration("timeout"), 1_000_000)
    if "read_gap" in fields:
        spec_kwargs["read_gap"] = reader.guard(
            lambda: fields["read_gap"].as_int("read_gap", 0, 2000), 8)
    if "scan_jitter" in fields:
        from hmi.project.tolerances import parse_scan_jitter
        spec_kwargs["scan_jitter_us"] = parse_scan_jitter(reader, fields["scan_jitter"],
                                                          period_us)
        spec_kwargs["jitter_pos"] = fields["scan_jitter"].pos
    if "write_refresh" in fields:
        spec_kwargs["write_refresh_us"] = reader.guard(
            lambda: fields["write_refresh"].as_duration("write_refresh", allow_zero=True),
            1_000_000)
    if kind == "modbus":  # a real device: every input and output needs its address
        for var in (*inputs, *outputs):
            if var.address is None:
                reader.diag.error(var.pos, f"{var.kind} {var.name!r} has no plant address, "
                                  "which a Modbus plant needs for every input and output",
                                  "address: di:N or coil:N (or ir:N.B, hr:N.B)")
    return PlantSpec(kind, tuple(devices), pos=node.pos, **spec_kwargs)


def _device(reader: ProjectReader, name: str | None, node: YNode, fields: dict[str, YNode],
            inputs: list[Variable], outputs: list[Variable],
            links: list[tuple[str, str, str, SourcePos, tuple[str, ...]]],
            wired: dict[str, tuple[str, SourcePos]]) -> DeviceSpec | None:
    model_name = reader.guard(lambda: fields["model"].as_str("model"))
    if model_name is None:
        return None
    model = DEVICE_MODELS.get(model_name)
    if model is None:
        reader.diag.error(fields["model"].pos, f"unknown plant model {model_name!r}",
                          "one of " + ", ".join(sorted(DEVICE_MODELS)))
        return None
    params: dict[str, Any] = {}
    if "params" in fields:
        pmap = reader.guard(lambda: fields["params"].check_keys(
            f"the parameters of {model_name}", set(model.params)), {})
        for pname, pnode in pmap.items():
            value = reader.guard(lambda s=model.params[pname], n=pnode, p=pname:
                                 _param_value(s, n, p))
            if value is not None:
                params[pname] = value
                if model.params[pname].kind == "device":
                    links.append((name or model_name, pname, value, pnode.pos,
                                        model.params[pname].choices))
        for pname, message, expected in model.param_problems(params):
            reader.diag.error(pmap[pname].pos if pname in pmap else fields["params"].pos,
                              f"{model_name} parameter {pname!r}: {message}", expected)
    input_names = {v.name for v in inputs}
    output_names = {v.name for v in outputs}
    # A port binds by identity to a project variable of the same name unless 'ports:'
    # says otherwise; a port with no such variable is simply not connected.
    ports = {p: p for p in model.sensors if p in input_names}
    ports.update({p: p for p in model.actuators if p in output_names})
    if "ports" in fields:
        pmap = reader.guard(lambda: fields["ports"].check_keys(
            f"the ports of {model_name}", {*model.sensors, *model.actuators}), {})
        for port, vnode in pmap.items():
            var = reader.guard(lambda n=vnode: n.as_str("a port's variable"))
            if var is not None:
                ports[port] = var
    for port, var in ports.items():
        want_input = port in model.sensors
        ok = var in input_names if want_input else var in output_names
        pos = fields["ports"].value[port].pos if "ports" in fields and \
            isinstance(fields["ports"].value, dict) and port in fields["ports"].value \
            else fields["model"].pos
        if not ok:
            reader.diag.error(pos, f"{model_name} port {port!r} is bound to {var!r}, which is "
                              f"not an {'input' if want_input else 'output'} of the project",
                              f"an {'input' if want_input else 'output'} name (map it under "
                              "'ports:')")
        elif want_input and var in wired:
            # Two sensors on one input: which one the program reads would be an accident of
            # the plant's step order. (An output may order several devices: a conveyor's
            # release is the robot's transfer order.)
            other, other_pos = wired[var]
            reader.diag.error(pos, f"{model_name} sensor {port!r} is bound to input {var!r}, "
                              f"which {other} (at {other_pos}) already drives",
                              "one sensor per input: an input wired to one device's sensor")
        elif want_input:
            wired[var] = (f"{'device ' + repr(name) + ' ' if name else ''}sensor {port!r}", pos)
    for port in model.actuators:
        if port not in ports:
            reader.diag.warning(fields["model"].pos, f"{model_name} actuator {port!r} is not "
                                "bound to any output; it is never driven")
    tolerances: tuple[Tolerance, ...] = ()
    if "tolerances" in fields:
        from hmi.project.tolerances import parse_tolerances
        tolerances = parse_tolerances(reader, fields["tolerances"], model, params,
                                      f"device {name or model_name!r}")
    return DeviceSpec(name or model_name, model_name, params, ports, node.pos, tolerances)


def _check_links(reader: ProjectReader, devices: list[DeviceSpec],
                 links: list[tuple[str, str, str, SourcePos, tuple[str, ...]]]) -> None:
    """A "device" parameter (a pipe to another device) names a device of the right model."""
    models = {d.name: d.model for d in devices}
    for owner, param, target, pos, allowed in links:
        if target == owner:
            reader.diag.error(pos, f"device {owner!r}: parameter {param!r} names the device "
                              "itself", "another device of the plant")
        elif target not in models:
            reader.diag.error(pos, f"device {owner!r}: parameter {param!r} names {target!r}, "
                              "which is not a device of the plant",
                              "one of " + ", ".join(sorted(models)))
        elif allowed and models[target] not in allowed:
            reader.diag.error(pos, f"device {owner!r}: parameter {param!r} names {target!r}, "
                              f"a {models[target]}", "a device of model " + " or ".join(allowed))


def _param_value(spec: ParamSpec, node: YNode, name: str) -> Any:
    if spec.kind == "duration":
        return node.as_duration(f"parameter {name!r}", allow_zero=spec.minimum == 0)
    if spec.kind == "bool":
        return node.as_bool(f"parameter {name!r}")
    if spec.kind == "device":
        return node.as_str(f"parameter {name!r} (a device name)")
    if spec.kind == "choice":
        value = node.as_str(f"parameter {name!r}")
        if value not in spec.choices:
            raise NodeError(node.pos, f"parameter {name!r} is {value!r}",
                            "one of " + ", ".join(spec.choices))
        return value
    number = node.as_number(f"parameter {name!r}")
    low, high = spec.minimum, spec.maximum
    if (low is not None and number < low) or (high is not None and number > high):
        if low is not None and high is not None:
            expected = f"a number from {low:g} to {high:g}"
        elif low is not None:
            expected = f"a number of at least {low:g}"
        else:
            expected = f"a number of at most {high:g}"
        raise NodeError(node.pos, f"parameter {name!r} is {number:g}, out of range", expected)
    return number

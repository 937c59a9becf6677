"""The Modbus address map, URLs and load-time checks: everything decided before a packet."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from hmi.cli import main
from hmi.errors import ProjectError, UsageError
from hmi.plant.modbus.address_map import AddressMap, Point, plan_coil_runs, plan_reads
from hmi.plant.modbus.client import ModbusSettings, parse_plant_url
from hmi.project.loader import load_project
from hmi.project.model import PlantAddress
from tests.conftest import PROJECTS, ROOT, write_project


def pt(name: str, kind: str, text: str) -> Point:
    table, _, rest = text.partition(":")
    index, _, bit = rest.partition(".")
    return Point(name, kind, PlantAddress(table, int(index), int(bit) if bit else None))


def test_reads_are_batched_per_table_bridging_small_gaps():
    points = [pt("a", "input", "di:0"), pt("b", "input", "di:5"), pt("c", "input", "di:40"),
              pt("d", "input", "ir:3.1"), pt("e", "input", "ir:3.7"), pt("f", "input", "ir:4.0"),
              pt("g", "input", "coil:9")]
    reads = plan_reads(points, read_gap=8)
    assert [(r.table, r.start, r.count) for r in reads] == [
        ("coil", 9, 1), ("di", 0, 6), ("di", 40, 1), ("ir", 3, 2)]
    assert [p.name for p in reads[3].points] == ["d", "e", "f"]
    assert [(r.start, r.count) for r in plan_reads(points[:3], read_gap=0)] == \
        [(0, 1), (5, 1), (40, 1)]


def test_a_read_never_exceeds_the_protocol_limit():
    points = [pt(f"x{i}", "input", f"hr:{i * 10}.0") for i in range(40)]  # hr 0..390
    reads = plan_reads(points, read_gap=20)
    assert all(r.count <= 125 for r in reads)
    assert sum(len(r.points) for r in reads) == 40


def test_coil_writes_are_consecutive_runs_and_register_bits_masks():
    outs = [pt("A", "output", "coil:0"), pt("B", "output", "coil:1"),
            pt("C", "output", "coil:3"), pt("D", "output", "hr:7.2"),
            pt("E", "output", "hr:7.0")]
    m = AddressMap(outs)
    assert [(r.start, r.names) for r in m.coil_runs] == [(0, ("A", "B")), (3, ("C",))]
    (reg,) = m.register_bits
    assert reg.index == 7 and reg.bits == (("E", 0), ("D", 2))
    and_mask, or_mask = reg.masks({"D": True, "E": False})
    assert and_mask == 0xFFFF & ~0b101 and or_mask == 0b100
    assert plan_coil_runs([]) == ()


def test_read_back_adds_the_outputs_addresses():
    points = [pt("fsc", "input", "di:0"), pt("C", "output", "coil:0"),
              pt("O", "output", "coil:1")]
    assert [r.table for r in AddressMap(points).reads] == ["di"]
    observed = AddressMap(points, read_back=True)
    assert [(r.table, r.start, r.count) for r in observed.reads] == [("coil", 0, 2), ("di", 0, 1)]


def test_decode_bits_and_register_bits():
    m = AddressMap([pt("a", "input", "di:2"), pt("b", "input", "hr:1.3")], read_gap=8)
    di, hr = m.reads[0], m.reads[1]
    values: dict[str, bool] = {}
    assert (di.start, hr.start) == (2, 1)
    m.decode(di, [True, False, False, False, False, False, False, False], values)
    m.decode(hr, [0xFFFF, 0b1000], values)
    assert values == {"a": True, "b": True}


@pytest.mark.parametrize("url,expected", [
    ("modbus://127.0.0.1:5020", ("127.0.0.1", 5020, 1)),
    ("modbus://plc.local:502/17", ("plc.local", 502, 17)),
    ("modbus://[::1]:1502/0", ("::1", 1502, 0)),
])
def test_plant_urls(url, expected):
    s = parse_plant_url(url, ModbusSettings())
    assert (s.host, s.port, s.unit) == expected


@pytest.mark.parametrize("url", ["http://h:1", "modbus://h", "modbus://h:99999",
                                 "modbus://h:1/300", "modbus://h:1/x", "modbus://:5020",
                                 "modbus://h:1?x=1"])
def test_bad_plant_urls(url):
    with pytest.raises(UsageError, match="expected modbus://HOST:PORT"):
        parse_plant_url(url, ModbusSettings())


MODBUS_PROJECT = """
    name: m
    scan_period: 10ms
    inputs:
      a: {description: sensor a, address: "di:0"}
      b: sensor b
    outputs:
      Y: {description: order Y, address: "coil:0"}
    control:
      equations:
        Y: a
    plant:
      kind: modbus
      host: 10.0.0.7
      port: 1502
      unit: 3
      timeout: 250ms
      read_gap: 0
      write_refresh: 0s
"""


def test_a_modbus_project_needs_every_address(tmp_path):
    write_project(tmp_path, {"project.yaml": MODBUS_PROJECT})
    with pytest.raises(ProjectError) as info:
        load_project(tmp_path)
    (error,) = info.value.errors
    assert "input 'b' has no plant address" in error.message
    assert (error.pos.line, error.pos.col) == (5, 3)


def test_modbus_settings_load(tmp_path):
    text = MODBUS_PROJECT.replace("b: sensor b", 'b: {description: sensor b, address: "di:1"}')
    write_project(tmp_path, {"project.yaml": text})
    spec = load_project(tmp_path).plant
    s = ModbusSettings.from_spec(spec)
    assert (s.host, s.port, s.unit, s.timeout_us, s.read_gap, s.write_refresh_us) == \
        ("10.0.0.7", 1502, 3, 250_000, 0, 0)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hmi.cli", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)


def _main(args, capsys) -> tuple[int | str | None, str]:
    """`plchmi ARGS` in this process: the exit status and the standard error of what
    `python -m hmi.cli` runs (``raise SystemExit(main())``), without a Python start and
    hmi's imports (~0.3 CPU s) for each case; an exception would fail the test."""
    try:
        code: int | str | None = main(list(args))
    except SystemExit as exc:  # argparse's own usage errors
        code = exc.code
    return code, capsys.readouterr().err


VALVE = str(PROJECTS / "cispi_valve")


@pytest.mark.parametrize("args,fragment", [
    (["run", VALVE, "--for", "1s", "--plant", "modbus:/x"], "expected sim, modbus or"),
    (["run", VALVE, "--for", "1s", "--plant", "modbus://h:0"], "the port is missing"),
    (["run", VALVE, "--for", "1s", "--read-only"], "--read-only observes a real device"),
    (["run", VALVE, "--for", "1s", "--plant", "modbus://127.0.0.1:1", "--inject", "F5@1s"],
     "--inject needs the simulated plant"),
    (["run", VALVE, "--for", "1s", "--plant", "modbus://127.0.0.1:1", "--policy", "monitor"],
     "--allow-monitor"),
    (["serve-plant", VALVE, "--inject", "F99@1s"], "communication faults: busy, mute"),
    (["serve-plant", VALVE, "--port", "70000"], "is not a TCP port"),
    (["bench", "nope"], "unknown bench section nope"),
])
def test_bad_modbus_arguments_exit_2(args, fragment, capsys):
    code, err = _main(args, capsys)
    assert code == 2, err
    assert fragment in err and "Traceback" not in err


def test_a_project_without_addresses_cannot_run_on_modbus(tmp_path):
    text = textwrap.dedent(MODBUS_PROJECT).replace("kind: modbus", "kind: sim\n  model: valve")
    write_project(tmp_path, {"project.yaml": text})
    proc = _cli("run", str(tmp_path), "--for", "1s", "--plant", "modbus://127.0.0.1:1")
    assert proc.returncode == 2
    assert "project.yaml:5:3: error: input 'b' has no plant address" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_the_schema_knows_the_modbus_plant_keys():
    import json

    import jsonschema
    import yaml
    schema = json.loads((ROOT / "hmi" / "project" / "schema.json").read_text())
    jsonschema.validate(yaml.safe_load(textwrap.dedent(MODBUS_PROJECT)), schema)
    bad = yaml.safe_load(textwrap.dedent(MODBUS_PROJECT).replace("read_gap: 0", "read_gap: -1"))
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema)

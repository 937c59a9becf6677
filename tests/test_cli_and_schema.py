"""The command line (check, run, bad arguments) and the published JSON Schema."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
import yaml

from hmi.cli import main
from tests.conftest import PROJECTS, ROOT

SCHEMA = json.loads((ROOT / "hmi" / "project" / "schema.json").read_text())
# One validator for every case (jsonschema.validate checks the schema itself on every call:
# 0.13 CPU s each); test_the_schema_is_a_valid_json_schema checks it once.
VALIDATOR = jsonschema.validators.validator_for(SCHEMA)(SCHEMA)


def test_check_lists_the_constraint_classes(capsys):
    assert main(["check", str(PROJECTS / "cispi_valve")]) == 0
    out = capsys.readouterr().out
    for i in range(1, 7):
        assert f"CSs{i}  simple" in out
    assert "CSc1  combined" in out
    assert "Safety constraints (7: 6 simple, 1 combined)" in out


def test_run_writes_a_trace_and_summarises(tmp_path, capsys):
    trace = tmp_path / "t.csv"
    assert main(["run", str(PROJECTS / "cispi_valve"), "--for", "20s", "--trace",
                 str(trace)]) == 0
    out = capsys.readouterr().out
    assert "2001 scans" in out and "cycles 2" in out and "Damage events: none" in out
    assert len(trace.read_text().splitlines()) == 2002


@pytest.mark.parametrize("args,fragment", [
    (["run", "PROJECT", "--for", "ten"], "is not a duration"),
    (["run", "PROJECT", "--for", "10s", "--inject", "F99@1s"], "unknown fault F99"),
    (["run", "PROJECT", "--for", "10s", "--inject", "F5"], "expected FAULT@TIME"),
    (["run", "PROJECT", "--for", "10s", "--control", "nope"], "--control 'nope'"),
    (["run", "PROJECT"], "--for"),
])
def test_bad_arguments_exit_2_with_a_message(args, fragment, capsys):
    """In-process (a new interpreter costs 0.2 CPU s a case); the one below runs one case in
    a real process: its exit status and stderr as a shell sees them."""
    args = [str(PROJECTS / "cispi_valve") if a == "PROJECT" else a for a in args]
    try:
        code = main(args)
    except SystemExit as exc:  # argparse refusing an argument
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert fragment in err and "Traceback" not in err


def test_a_bad_argument_exits_2_from_a_real_process():
    args = ["run", str(PROJECTS / "cispi_valve"), "--for", "10s", "--inject", "F99@1s"]
    proc = subprocess.run([sys.executable, "-m", "hmi.cli", *args], capture_output=True,
                          text=True, cwd=ROOT)
    assert proc.returncode == 2
    assert "unknown fault F99" in proc.stderr and "Traceback" not in proc.stderr


def _project_files():
    return sorted(p for p in PROJECTS.glob("*/*.yaml"))


@pytest.mark.parametrize("path", _project_files(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_example_project_files_validate_against_the_schema(path):
    VALIDATOR.validate(yaml.safe_load(path.read_text()))


def test_the_schema_is_a_valid_json_schema():
    assert type(VALIDATOR) is jsonschema.Draft202012Validator  # the draft it names
    VALIDATOR.check_schema(SCHEMA)


def test_schema_rejects_what_the_loader_rejects():
    with pytest.raises(jsonschema.ValidationError):
        VALIDATOR.validate({"inptus": {}})
    with pytest.raises(jsonschema.ValidationError):
        VALIDATOR.validate({"timers": {"T": {"type": "TON", "input": "a"}}})
    with pytest.raises(jsonschema.ValidationError):
        VALIDATOR.validate({"scan_period": "10"})


def test_schema_covers_every_section_the_loader_knows():
    from hmi.project.loader import TOP_KEYS
    assert set(SCHEMA["properties"]) == TOP_KEYS


def test_an_unexpected_failure_is_reported_without_a_traceback(monkeypatch, capsys, tmp_path):
    import hmi.session.trace as trace

    def broken(self, snap):
        raise RuntimeError("disk on fire")
    monkeypatch.setattr(trace.TraceWriter, "write", broken)
    assert main(["run", str(PROJECTS / "cispi_valve"), "--for", "1s", "--trace",
                 str(tmp_path / "t.csv")]) == 1
    err = capsys.readouterr().err
    assert "internal error: RuntimeError: disk on fire" in err and "Traceback" not in err
    report = err.split("the details are in ")[1].split(";")[0]
    assert "Traceback" in Path(report).read_text()

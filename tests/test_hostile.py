"""Hostile input: every class of bad project, argument and journal gets a clear
error — exit status 2 naming file:line:column for file content, 1 for a failure at run
time — never "internal error", a traceback, a hang, or a file read or written outside the
project folder, the component library, the data folder and the paths given on the command
line. Each case runs in-process under a time and memory bound (tests/bounds.py).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import time
import tracemalloc
from pathlib import Path

import pytest

from hmi.cli import main
from hmi.errors import ProjectError
from hmi.explain.journal import default_path, read, safe_file_name
from hmi.limits import (
    MAX_CONSTRAINTS,
    MAX_DAMAGED_SHOWN,
    MAX_EXPR_CHARS,
    MAX_EXPR_DEPTH,
    MAX_FILE_BYTES,
    MAX_NAME_CHARS,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
)
from hmi.logic.expr import ExprError, parse_expr
from hmi.project.loader import load_project
from hmi.project.yamlcompose import compose_text
from tests.bounds import bounded, run_cli
from tests.conftest import PROJECTS, ROOT
from tests.test_malformed import project_text

BASE = project_text()


def write(folder: Path, files: dict[str, str | bytes]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content, encoding="utf-8")
    return folder


def cli(args: list[str], capsys, seconds: float = 10.0) -> tuple[int, str, str]:
    """main(args) under a time and memory bound: (exit status, stdout, stderr)."""
    with bounded(seconds):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse refusing an argument: status 2
            code = exc.code
    out, err = capsys.readouterr()
    assert "internal error" not in err and "Traceback" not in err, err
    return code, out, err


def position_of(text: str, token: str) -> tuple[int, int]:
    index = text.index(token)
    return text.count("\n", 0, index) + 1, index - (text.rfind("\n", 0, index) + 1) + 1


def first_error(err: str) -> str:
    return next(line for line in err.splitlines() if ": error: " in line)


def expect_error_at(err: str, file: str, line: int, col: int, fragment: str) -> None:
    assert fragment in err, err
    match = re.search(rf"{re.escape(file)}:(\d+):(\d+): error: [^\n]*{re.escape(fragment)}",
                      err)
    assert match, err
    assert (int(match.group(1)), int(match.group(2))) == (line, col), err


def alias_bomb(levels: int) -> str:
    """Each anchor a list of nine aliases of the previous: 9**levels values from a few
    hundred bytes."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    for i in range(1, levels + 1):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# Depth and size
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("levels", [6, 8, 12])
def test_an_alias_bomb_is_refused_fast_and_small(levels, tmp_path, capsys):
    text = BASE + "description: x\n" + alias_bomb(levels).replace("a0:", "x0:")
    folder = write(tmp_path / "p", {"project.yaml": text})
    tracemalloc.start()
    started = time.process_time()  # CPU time: the wall clock measures the machine's load
    try:
        with pytest.raises(ProjectError) as info, bounded(5):
            load_project(folder)
        elapsed = time.process_time() - started
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    error = info.value.errors[0]
    assert f"more than {MAX_YAML_NODES:,} YAML values" in error.message
    assert error.pos.line > 0 and error.pos.col > 0  # at the alias that passes the limit
    assert elapsed < 3 and peak < 150 * 1024 * 1024, (elapsed, peak)
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and "aliases count as copies" in err


def test_an_alias_to_an_enclosing_list_is_a_loop(tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": BASE + "description: &a [x, *a]\n"})
    code, _, err = cli(["check", folder], capsys)
    text = (folder / "project.yaml").read_text()
    expect_error_at(err, "project.yaml", *position_of(text, "*a]"), "(a loop)")
    assert code == 2


def test_an_alias_shares_nothing_with_its_anchor():
    root = compose_text("a: &x {k: [1, 2]}\nb: *x\n", "f.yaml")
    a, b = root.value["a"], root.value["b"]
    assert a is not b and a.value["k"] is not b.value["k"]
    assert [n.value for n in b.value["k"].value] == [1, 2]


@pytest.mark.parametrize("opening", ["[", "{a: "], ids=["lists", "mappings"])
def test_deep_yaml_nesting_is_refused_at_its_depth(opening, tmp_path, capsys):
    closing = "]" if opening == "[" else "}"
    text = "name: " + opening * 1000 + "1" + closing * 1000 + "\n"
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys)
    # The top-level mapping is the first level: the error is at the MAX_YAML_DEPTH-th opening.
    col = len("name: ") + len(opening) * (MAX_YAML_DEPTH - 1) + 1
    expect_error_at(err, "project.yaml", 1, col, f"nested more than {MAX_YAML_DEPTH} deep")
    assert code == 2


@pytest.mark.parametrize("expr, fragment", [
    ("not " * 1000 + "a", f"at most {MAX_EXPR_CHARS:,} characters"),
    ("not " * 10000 + "a", f"at most {MAX_EXPR_CHARS:,} characters"),
    ("(a and (b or " * 500 + "a" + "))" * 500, f"at most {MAX_EXPR_CHARS:,} characters"),
    ("not " * (MAX_EXPR_DEPTH + 1) + "a", f"nested more than {MAX_EXPR_DEPTH} deep"),
    ("(" * 40 + "a" + ")" * 40, f"nested more than {MAX_EXPR_DEPTH} deep"),
    ("not (" * 20 + "a" + ")" * 20, f"nested more than {MAX_EXPR_DEPTH} deep"),
    ("prev(a, " + "9" * 5000 + ")", "characters"),
    ("X1.t >= 99999999999999h", "longer than the longest duration"),
])
def test_expressions_too_long_or_too_deep_are_refused(expr, fragment, tmp_path, capsys):
    text = BASE.replace("Y: a and not b", f"Y: {expr}")
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and fragment in err, err
    assert re.search(r"project\.yaml:13:\d+: error: ", err), err


def test_nesting_within_the_limit_is_accepted():
    parse_expr("not " * MAX_EXPR_DEPTH + "a", _pos())
    parse_expr("(" * (MAX_EXPR_DEPTH // 2) + "a and not b" + ")" * (MAX_EXPR_DEPTH // 2),
               _pos())
    parse_expr(" and ".join(f"not x{i}" for i in range(100)), _pos())  # flat: no depth


def _pos():
    from hmi.errors import SourcePos
    return SourcePos("f.yaml", 3, 5)


def test_a_file_over_the_size_limit_is_refused_without_reading_it(tmp_path, capsys):
    big = "description: |\n" + ("  " + "x" * 98 + "\n") * (MAX_FILE_BYTES // 100 + 10)
    folder = write(tmp_path / "p", {"project.yaml": BASE + "include: [big.yaml]\n",
                                    "big.yaml": big})
    code, _, err = cli(["check", folder], capsys, seconds=5)
    assert code == 2 and "big.yaml: error: the file is too large" in err, err


def test_numbers_with_too_many_digits_are_refused(tmp_path, capsys):
    text = BASE.replace("safe: 0", "safe: " + "9" * 5000)
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys)
    expect_error_at(err, "project.yaml", *position_of(text, "9999"), "5000 digits")
    assert code == 2


def test_too_many_constraints_is_one_error_naming_the_limit(tmp_path, capsys):
    lines = "".join(f"  K{i}: Y and b\n" for i in range(MAX_CONSTRAINTS + 1))
    text = BASE.replace("constraints:\n  K1: Y and b\n  K2: Y and Z\n", "constraints:\n" + lines)
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys, seconds=30)
    assert code == 2
    assert err.count("error:") == 1 and f"at most {MAX_CONSTRAINTS:,}" in err, err
    assert re.search(r"project\.yaml:\d+:1: error: the project has 10,001 safety", err)


def many_constraints(count: int) -> str:
    """`count` constraints over few outputs and many contexts (the shape that made check's
    filter analysis take 22 ms per constraint)."""
    lines = "".join(f"  K{i}: Y and b and not a and prev(Z, {1 + i % 60})\n"
                    for i in range(count))
    return BASE.replace("constraints:\n  K1: Y and b\n  K2: Y and Z\n", "constraints:\n" + lines)


def test_five_thousand_constraints_are_checked_and_run(tmp_path, capsys):
    """Loading and checking are linear in the constraints (the bound is generous for a shared
    machine; bench-like figures are measured by `plchmi bench`)."""
    folder = write(tmp_path / "p", {"project.yaml": many_constraints(5000)})
    code, out, err = cli(["check", folder], capsys, seconds=60)
    assert code == 0 and "bounded: " in out, err
    code, out, err = cli(["run", folder, "--for", "200ms"], capsys, seconds=60)
    assert code == 0, err


# --------------------------------------------------------------------------------------------
# Special files
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom", "/dev/null"])
def test_a_device_is_not_read_as_a_project(device, capsys):
    code, _, err = cli(["check", device], capsys, seconds=5)
    assert code == 2 and f"{device}: error: not a regular file: this is a device" in err


def test_a_fifo_as_project_file_is_refused_not_waited_on(tmp_path, capsys):
    folder = tmp_path / "p"
    folder.mkdir()
    os.mkfifo(folder / "project.yaml")
    code, _, err = cli(["check", folder], capsys, seconds=5)
    assert code == 2 and "not a regular file: this is a FIFO" in err


def test_a_folder_as_include_is_refused(tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": BASE + "include: [sub]\n"})
    (folder / "sub").mkdir()
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and "this is a folder, not a file" in err


@pytest.mark.parametrize("path, fragment", [
    ("/dev/zero", "not a regular file: this is a device"),
    ("/tmp", "this is a folder"),
])
def test_journal_path_that_is_not_a_file(path, fragment, capsys):
    code, _, err = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys, seconds=5)
    assert code == 2 and fragment in err


# --------------------------------------------------------------------------------------------
# Numbers
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("param, value, fragment", [
    ("travel", ".nan", "is .nan, not a duration"),
    ("travel", ".inf", "is .inf, not a duration"),
    ("block_at", ".nan", "is .nan, not a finite number"),
    ("block_at", "-.inf", "is -.inf, not a finite number"),
])
def test_non_finite_plant_parameters_are_refused(param, value, fragment, tmp_path, capsys):
    text = BASE.replace("  ports:", f"  params: {{{param}: {value}}}\n  ports:")
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["run", folder, "--for", "1s"], capsys)
    expect_error_at(err, "project.yaml", *position_of(text, value + "}"), fragment)
    assert code == 2


def test_for_nan_is_not_a_duration_not_a_missing_unit(tmp_path, capsys):
    text = BASE + "scenarios:\n  s: {inject: [F5@1s], for: .nan}\n"
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys)
    expect_error_at(err, "project.yaml", *position_of(text, ".nan"), "is .nan, not a duration")
    assert "has no unit" not in err and code == 2


@pytest.mark.parametrize("args, fragment", [
    (["--for", "99999999999999999999h"], "is not a duration"),
    (["--for", "1001h"], "longer than the longest duration allowed (1000h)"),
    (["--for", "999h"], "more than the 100,000,000 plchmi runs at once"),
    (["--for", "1s", "--period", "1us"], "shorter than the shortest scan period"),
    (["--for", "0s"], "longer than zero"),
])
def test_run_lengths_beyond_the_limits_are_usage_errors(args, fragment, capsys):
    code, _, err = cli(["run", PROJECTS / "cispi_valve", *args], capsys, seconds=5)
    assert code == 2 and fragment in err, err


def test_a_long_run_says_so_up_front(tmp_path, capsys, monkeypatch):
    import hmi.session.runio
    monkeypatch.setattr(hmi.session.runio, "NOTICE_RUN_SCANS", 100)
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "2s"], capsys)
    assert code == 0 and "201 scans to run (2s at a 10ms scan period)" in err


@pytest.mark.parametrize("text, token, fragment", [
    ("scan_period: 1us", "1us", "shorter than the shortest scan period"),
    ("scan_period: 99999999999h", "99999999999h", "longer than the longest duration"),
])
def test_scan_periods_out_of_range(text, token, fragment, tmp_path, capsys):
    project = BASE.replace("scan_period: 10ms", text)
    folder = write(tmp_path / "p", {"project.yaml": project})
    code, _, err = cli(["check", folder], capsys)
    expect_error_at(err, "project.yaml", *position_of(project, token), fragment)
    assert code == 2


@pytest.mark.parametrize("change, fragment", [
    ({"interval_min": "9s", "interval_max": "7s"}, "interval_max (7s) is shorter than"),
    ({"interval_min": "500us"}, "at least 1ms"),
])
def test_box_intervals_that_cannot_be_drawn(change, fragment, tmp_path, capsys):
    folder = tmp_path / "sorting"
    shutil.copytree(PROJECTS / "sorting", folder)
    text = (folder / "project.yaml").read_text()
    for key, value in change.items():
        text = re.sub(rf"{key}: *\S+", f"{key}: {value}", text)
    (folder / "project.yaml").write_text(text)
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and fragment in err, err
    assert re.search(r"project\.yaml:\d+:\d+: error: sorting_cell parameter 'interval_m", err)


# --------------------------------------------------------------------------------------------
# Text
# --------------------------------------------------------------------------------------------

TEXT_CASES = [
    # (id, replace in BASE, with, token the error points at, fragment)
    ("superscript-step", "control:\n  equations:\n    Y: a and not b\n    Z: T1",
     "control:\n  grafcet:\n    steps:\n      \"²\": {initial: true, actions: [Y]}\n"
     "    transitions: []\n  equations:\n    Z: T1", "\"²\"", "is not a step number"),
    ("fullwidth-duration", "scan_period: 10ms", "scan_period: １０ms", "１０ms",
     "is not a duration"),
    ("fullwidth-address", "sensor a}", "sensor a, address: 'di:０'}", "'di:０'",
     "is not a plant address"),
    ("fullwidth-in-expression", "K2: Y and Z", "K2: Ｙ and Z", "Ｙ",
     "which Python would read as 'Y'"),
    ("math-bold-in-expression", "K2: Y and Z", "K2: Y and 𝐙", "𝐙",
     "which Python would read as 'Z'"),
    ("double-struck-name", "  Z: order Z\n", "  Z: order Z\n  ℂ: c\n", "ℂ",
     "which Python would read as 'C'"),
    ("lone-surrogate", "name: t", 'name: t\ndescription: "a\\ud800b"', '"a\\ud800b"',
     "U+D800 (a lone surrogate)"),
    ("escaped-nul", "name: t", 'name: "t\\0x"', '"t\\0x"', "U+0000 (NUL)"),
    ("escaped-esc", "order Z", '"order \\e[31mZ"', '"order', "U+001B (ESC)"),
    ("bidi-override", "order Z", "order \u202eZ redro", "order \u202eZ",
     "U+202E (RIGHT-TO-LEFT OVERRIDE)"),
    ("bel-in-file", "order Z", "order \x07Z", "\x07", "control character U+0007 (BEL)"),
    ("nul-in-file", "order Z", "order \x00Z", "\x00", "control character U+0000 (NUL)"),
    ("name-too-long", "  Z: order Z\n", "  Z: order Z\n  " + "a" * 300 + ": x\n", "a" * 300,
     "300 characters long"),
    ("name-with-newline", "  Z: order Z\n", '  Z: order Z\n  "c\\n": x\n', '"c\\n"',
     "is not a valid name"),
]


@pytest.mark.parametrize("old, new, token, fragment", [c[1:] for c in TEXT_CASES],
                         ids=[c[0] for c in TEXT_CASES])
def test_text_that_is_not_what_it_looks_like(old, new, token, fragment, tmp_path, capsys):
    assert old in BASE
    text = BASE.replace(old, new, 1)
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["check", folder], capsys)
    expect_error_at(err, "project.yaml", *position_of(text, token), fragment)
    assert code == 2


@pytest.mark.parametrize("data, token, fragment", [
    (BASE.replace("order Z", "order \xe9").encode("latin-1"), b"\xe9", "byte 0xe9"),
    (BASE.encode("utf-16"), b"\xff", "looks like UTF-16"),
    (BASE.replace("order Z", "order \x7f").encode(), b"\x7f", "U+007F (DEL)"),
])
def test_bytes_that_are_not_utf8_text(data, token, fragment, tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": data})
    code, _, err = cli(["check", folder], capsys)
    index = data.index(token)
    line = data.count(b"\n", 0, index) + 1
    col = index - (data.rfind(b"\n", 0, index) + 1) + 1
    expect_error_at(err, "project.yaml", line, col, fragment)
    assert code == 2


def test_a_byte_order_mark_is_harmless(tmp_path):
    folder = write(tmp_path / "p", {"project.yaml": b"\xef\xbb\xbf" + BASE.encode()})
    assert load_project(folder).name == "t"


@pytest.mark.parametrize("args, fragment", [
    (["run", "V", "--for", "１s"], "is not a duration"),
    (["run", "V", "--for", "1s", "--inject", "F5@１s"], "the time is not"),
    (["run", "V", "--for", "1s", "--plant", "modbus://h:502/²"], "unit '²' is not a number"),
    (["serve-plant", "V", "--port", "²"], "is not a TCP port"),
    (["serve-plant", "V", "--unit", "٣"], "is not a Modbus unit id"),
    (["journal", "V", "--since", "２h"], "expected an ISO date/time"),
])
def test_unicode_digits_on_the_command_line(args, fragment, capsys):
    args = [str(PROJECTS / "cispi_valve") if a == "V" else a for a in args]
    with pytest.raises(SystemExit) as info, bounded(5):
        main(args)
        raise SystemExit(2)  # main returned instead of argparse exiting
    err = capsys.readouterr().err
    assert info.value.code == 2 and fragment in err, err


def test_look_alike_names_in_component_bindings_are_not_folded(tmp_path, capsys):
    text = (PROJECTS / "cispi_subsystem" / "project.yaml").read_text()
    folder = tmp_path / "cispi_subsystem"
    shutil.copytree(PROJECTS / "cispi_subsystem", folder)
    library = os.path.relpath(ROOT / "components" / "valve.yaml", folder)
    (folder / "project.yaml").write_text(
        text.replace("../../components/valve.yaml", library).replace("fsc: fsc1", "fsc: ｆsc1", 1))
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and "'ｆsc1', which is not declared" in err, err


# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name, fragment", [
    ("/etc/passwd", "is an absolute path"),
    ("../../../../../../../../etc/passwd", "leads outside the project folder"),
    ("link.yaml", "leads outside the project folder"),
    ("~/x.yaml", "is an absolute path"),
    ("a" * 300 + ".yaml", "too long a file name"),
    ("", "is empty"),
])
def test_includes_stay_inside_the_project_folder(name, fragment, tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": BASE + f"include: ['{name}']\n"})
    (folder / "link.yaml").symlink_to("/etc/passwd")
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and fragment in err, err
    assert "root:" not in err  # nothing of the refused file is read, let alone printed
    assert re.search(r"project\.yaml:\d+:\d+: error: the included file", err)


def test_an_include_in_a_subfolder_and_a_symlink_inside_are_fine(tmp_path):
    sections = BASE.split("constraints:")
    folder = write(tmp_path / "p", {
        "project.yaml": sections[0] + "include: [parts/c.yaml, alias.yaml]\n",
        "parts/.keep": "", "desc.yaml": "description: via a symlink\n"})
    (folder / "parts" / "c.yaml").write_text("constraints:" + sections[1])
    (folder / "alias.yaml").symlink_to(folder / "desc.yaml")
    project = load_project(folder)
    assert [c.name for c in project.constraints] == ["K1", "K2"]
    assert project.description == "via a symlink"


@pytest.mark.parametrize("use, fragment", [
    ("/etc/passwd", "is an absolute path"),
    ("../../../../../../../etc/passwd", "leads outside the project folder or the component "
     "library"),
])
def test_component_use_stays_in_the_project_or_the_library(use, fragment, tmp_path, capsys):
    folder = write(tmp_path / "p", {
        "project.yaml": BASE + f"components:\n  V: {{use: '{use}', bind: {{}}}}\n"})
    code, _, err = cli(["check", folder], capsys)
    assert code == 2 and fragment in err and "root:" not in err, err


def test_the_library_is_reached_from_a_project_elsewhere(tmp_path):
    folder = tmp_path / "cispi_subsystem"
    shutil.copytree(PROJECTS / "cispi_subsystem", folder)
    text = (folder / "project.yaml").read_text()
    library = os.path.relpath(ROOT / "components" / "valve.yaml", folder)
    (folder / "project.yaml").write_text(text.replace("../../components/valve.yaml", library))
    assert len(load_project(folder).components) == 2


@pytest.mark.parametrize("name", ["../../ESCAPED", "/tmp/ESCAPED", "..", ".", "a/../../b",
                                  "Cell 3 / Line 2", "ÉCHAPPÉ", "x" * 200])
def test_the_project_name_is_never_a_path(name, tmp_path, capsys):
    data = Path(os.environ["PLCHMI_DATA"])
    text = BASE.replace("name: t", f"name: {json.dumps(name)}")
    folder = write(tmp_path / "deep" / "er" / "p", {"project.yaml": text})
    code, _, err = cli(["run", folder, "--for", "100ms"], capsys)
    assert code == 0, err
    journal = default_path(name)
    assert journal.is_file() and journal.parent.parent == data
    assert journal.parent.name == safe_file_name(name) and len(journal.parent.name) <= 89
    written = [p for p in tmp_path.rglob("*") if p.is_file() and p.name != "project.yaml"]
    assert all(data in p.parents for p in written), written
    assert not [p for p in (tmp_path.parent, tmp_path, Path("/tmp")) if (p / "ESCAPED").exists()]


def test_safe_file_names_keep_plain_names_and_separate_cleaned_ones():
    assert safe_file_name("cispi_valve") == "cispi_valve"
    assert safe_file_name("a/b") != safe_file_name("a_b")
    assert safe_file_name("a/b").startswith("a_b-")


# --------------------------------------------------------------------------------------------
# Output I/O
# --------------------------------------------------------------------------------------------


def test_trace_on_a_full_device_is_a_run_time_error(tmp_path, capsys):
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "2s", "--trace",
                          "/dev/full"], capsys)
    assert code == 1
    assert "plchmi: error: cannot write the trace /dev/full: no space left on device" in err


def test_a_failing_write_mid_run_stops_it_with_the_outputs_safe(tmp_path, capsys,
                                                                 monkeypatch):
    """A disk that fills up at the 299th scan: the run stops there, the plant gets the safe
    vector, the journal says the session stopped, exit status 1."""
    import csv
    import errno

    from hmi.plant.sim.plant import SimPlant

    writes: list[dict[str, bool]] = []
    real_write = SimPlant.write
    monkeypatch.setattr(SimPlant, "write", lambda self, t, out: (writes.append(dict(out)),
                                                                 real_write(self, t, out)))
    real_row = csv.DictWriter.writerow
    count = [0]

    def row(self, values):
        count[0] += 1
        if count[0] == 300:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_row(self, values)
    monkeypatch.setattr(csv.DictWriter, "writerow", row)
    journal = tmp_path / "j.jsonl"
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "10s", "--control",
                          "faulty", "--trace", tmp_path / "t.csv", "--journal", journal], capsys)
    # The 300th row written is scan 299's (the header is the first)
    assert code == 1 and "the run stopped at scan 299 (t = 2.980 s)" in err, err
    assert "outputs written safe" in err
    assert writes[-1] == {"C": False, "O": False}  # the valve's safe vector, written last
    assert any(w != writes[-1] for w in writes)  # it had been driven before
    entries = read(journal).entries
    assert entries[0]["event"] == "start"
    # never "ended normally" after an error: an abnormal end, with the reason
    assert entries[-1]["event"] == "abnormal-end", entries[-1]
    assert "ended abnormally" in entries[-1]["message"]
    assert "cannot write the trace" in entries[-1]["message"], entries[-1]["message"]


def test_a_journal_that_fails_mid_run_stops_it_safe(tmp_path, capsys, monkeypatch):
    import errno

    from hmi.explain import journal as journal_module
    real = journal_module.Journal.append_all
    count = [0]

    def append_all(self, entries):  # every write goes through it (a scan's alarms at once)
        count[0] += 1
        if count[0] >= 3:
            raise journal_module.JournalWriteError(
                "the journal", self.path, OSError(errno.EIO, "Input/output error"))
        real(self, entries)
    monkeypatch.setattr(journal_module.Journal, "append_all", append_all)
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "20s", "--control",
                          "faulty", "--journal", tmp_path / "j.jsonl"], capsys)
    assert code == 1 and "cannot write the journal" in err and "input/output error" in err
    assert "the run stopped at scan" in err


@pytest.mark.parametrize("option, path, code_expected, fragment", [
    ("--journal", "/dev/full", 2, "not a regular file"),
    ("--journal", "/proc/version", 1, "cannot write the journal /proc/version"),
    ("--journal", "DIR", 2, "is a directory"),
    ("--journal", "DIR/missing/x/../j.jsonl", 1, None),
    ("--trace", "DIR", 2, "is a directory"),
    ("--trace", "DIR/missing/t.csv", 2, "no such file or directory"),
    ("--trace", "FIFO", 1, "no such device or address"),
])
def test_output_paths_that_cannot_be_written(option, path, code_expected, fragment, tmp_path,
                                             capsys):
    os.mkfifo(tmp_path / "fifo")
    path = path.replace("DIR", str(tmp_path)).replace("FIFO", str(tmp_path / "fifo"))
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "200ms", option, path],
                         capsys, seconds=5)
    if fragment is None:  # a journal's missing folders are created: a normal run
        assert code == 0, err
        return
    assert code == code_expected and fragment in err, err


# --------------------------------------------------------------------------------------------
# plchmi journal
# --------------------------------------------------------------------------------------------

JOURNAL_LINES = [
    (b'{"scan": {}, "text": "x"}', "its 'scan' is an object where a number belongs"),
    (b'{"wall": 5}', "its 'wall' is a number where a string belongs"),
    (b'{"scan": true}', "its 'scan' is a Boolean"),
    (b"[" * 100_000, "JSON nested too deep"),
    (b'{"n": ' + b"9" * 5000 + b"}", "not a journal entry"),
    (b'{"text": "\\ud800"}', "a lone surrogate"),
    (b"x" * (2 * 1024 * 1024), "line longer than 1 MiB"),
    (b"\x00" * 100, "not valid JSON"),
]


def test_null_fields_of_a_journal_entry_print_as_empty(tmp_path, capsys):
    """Found by the fuzz suite: `"type": null` made the printer fail."""
    path = tmp_path / "j.jsonl"
    path.write_text('{"wall": null, "type": null, "event": "x", "scan": null, "t": null}\n')
    code, out, _ = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys)
    assert code == 0 and "x: " in out


@pytest.mark.parametrize("jobs", ["0", "-3", "100000"])
def test_campaign_jobs_are_bounded(jobs, capsys):
    code, _, err = cli(["campaign", PROJECTS / "cispi_valve", "--jobs", jobs], capsys)
    assert code == 2 and "expected 1 to 32 worker processes" in err


@pytest.mark.parametrize("line, reason", JOURNAL_LINES, ids=[str(i) for i in range(8)])
def test_damaged_journal_lines_are_skipped_with_a_warning(line, reason, tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    good = b'{"wall":"2026-01-01T00:00:00.000+00:00","type":"action","event":"one","scan":1}\n'
    path.write_bytes(good + line + b"\n" + good.replace(b"one", b"two"))
    code, out, err = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys)
    assert code == 0
    assert "one" in out and "two" in out
    assert f"{path}:2: damaged journal entry skipped: " in err and reason in err, err


def test_control_characters_in_a_journal_never_reach_the_terminal(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    path.write_text(json.dumps({"type": "action", "event": "x", "message": "\x1b[2J\x07hi"})
                    + "\n")
    code, out, _ = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys)
    assert code == 0 and "\x1b" not in out and "\x07" not in out and "\\x1b[2J\\x07hi" in out


def test_line_separators_and_bidi_controls_in_a_journal_are_shown_escaped(tmp_path, capsys):
    """Found by the long fuzz (PLCHMI_FUZZ_EXAMPLES=15000): U+2028 in a message split one
    entry into two lines for whoever reads the output line by line; U+202E would reorder
    what the terminal shows."""
    path = tmp_path / "j.jsonl"
    path.write_text(json.dumps({"type": "action", "event": "x",
                                "message": "a\u2028b\u2029c\u202ed\u2066e"}) + "\n")
    code, out, _ = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys)
    assert code == 0 and len(out.splitlines()) == 1
    assert "a\\u2028b\\u2029c\\u202ed\\u2066e" in out


@pytest.mark.parametrize("since, code_expected, fragment", [
    ("99999999999999h", 2, "longer than the longest duration allowed"),
    ("0001-01-01", 0, None),
    ("9999-12-31T23:59:59", 0, None),
    ("2026-13-45", 2, "expected an ISO date/time"),
    ("soon", 2, "expected an ISO date/time"),
    ("-1h", 2, "argument --since"),
    ("1h\x00", 2, "expected an ISO date/time"),
])
def test_since_values(since, code_expected, fragment, tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    path.write_text('{"wall":"2026-01-01T00:00:00.000+00:00","type":"action","event":"one"}\n'
                    '{"wall":"2026-01-01T00:00:00","type":"action","event":"naive"}\n'
                    '{"wall":"yesterday","type":"action","event":"odd"}\n')
    code, out, err = cli(["journal", PROJECTS / "cispi_valve", "--path", path, "--since",
                          since], capsys)
    assert code == code_expected, err
    if fragment:
        assert fragment in err
    elif since.startswith("0001"):
        assert "one" in out and "naive" in out  # a wall without a zone is UTC, as written


def test_a_huge_journal_of_garbage_is_read_in_bounded_memory(tmp_path, capsys):
    path = tmp_path / "j.jsonl"
    with path.open("wb") as file:
        file.write(b'{"type":"action","event":"first"}\n')
        chunk = b"\x00" * (1 << 20)
        for _ in range(64):  # 64 MiB without a newline
            file.write(chunk)
    code, out, err = cli(["journal", PROJECTS / "cispi_valve", "--path", path], capsys,
                         seconds=20)
    assert code == 0 and "first" in out and ":2: damaged journal entry skipped" in err


# --------------------------------------------------------------------------------------------
# Messages that misled
# --------------------------------------------------------------------------------------------


def test_an_ipv6_url_without_its_bracket(capsys):
    code, _, err = cli(["run", PROJECTS / "cispi_valve", "--for", "1s", "--plant",
                        "modbus://[::1"], capsys)
    assert code == 2 and "Invalid IPv6 URL" in err and "port must be a number" not in err


def test_serve_plant_on_an_unknown_host_says_so(capsys):
    code, _, err = cli(["serve-plant", PROJECTS / "cispi_valve", "--host",
                        "no.such.host.invalid", "--port", "0"], capsys)
    assert code == 2 and "no such host or address" in err and "in use" not in err


# --------------------------------------------------------------------------------------------
# What must run in a process of its own
# --------------------------------------------------------------------------------------------


def test_hostile_cases_in_a_limited_process(tmp_path):
    """The worst cases once more as the command a user types, in a process limited to 1 GB
    and 20 s: an alias bomb and a device as project, a 100k-deep journal line."""
    bomb = write(tmp_path / "bomb", {"project.yaml": alias_bomb(9)})
    journal = tmp_path / "j.jsonl"
    journal.write_bytes(b"[" * 100_000 + b"\n")
    for args, code in (([ "check", bomb], 2), (["check", "/dev/urandom"], 2),
                       (["journal", PROJECTS / "cispi_valve", "--path", journal], 0)):
        result = run_cli([str(a) for a in args], tmp_path)
        assert result.returncode == code, result.stderr
        assert "internal error" not in result.stderr and "Traceback" not in result.stderr


def test_expression_errors_are_expr_errors():
    for text in ("a ++ b", "a\\b", "lambda: 1", "a if b else c", "'x'", "f'{a}'", "a[0]",
                 "prev(a, 99999999999999999999999)", "X1.t >= 1e3s", "a := b"):
        with pytest.raises(ExprError):
            parse_expr(text, _pos())


def test_docs_list_every_limit():
    docs = (ROOT / "docs" / "project-format.md").read_text()
    import hmi.limits
    for name in hmi.limits.__all__:
        if name.startswith(("MAX_", "MIN_", "NOTICE_")):
            assert name in docs, f"docs/project-format.md does not list {name}"



# --------------------------------------------------------------------------------------------
# Structures that made a check exponential or quadratic
# --------------------------------------------------------------------------------------------

DIAG_HEAD = """name: big
scan_period: 10ms
inputs:
""" + "".join(f"  i{k}: in{k}\n" for k in range(16)) + """outputs:
  Y: y
  Z: z
control:
  equations:
    Y: i1
plant:
  kind: sim
  model: valve
  ports: {fsc: i0, fso: i1, C: Y, O: Z}
"""


def diagnoser_fan(count: int, prefix: str = "") -> str:
    """`count` event transitions from one state, each on all 16 inputs, pairwise exclusive:
    proving it by enumeration is 2**16 assignments per pair."""
    def condition(k: int) -> str:
        return prefix + " and ".join(("" if k >> j & 1 else "not ") + f"i{j}"
                                     for j in range(16))
    states = "      S0: {}\n" + "".join(f"      T{k}: {{labels: [L1]}}\n" for k in range(count))
    moves = "".join(f"      - {{from: S0, to: T{k}, when: \"{condition(k)}\"}}\n"
                    for k in range(count))
    return (DIAG_HEAD + "diagnosers:\n  D:\n    labels: {L1: one}\n    partitions:\n"
            "      p: {labels: [L1], actuators: [Y]}\n    initial: S0\n    states:\n" + states
            + "    transitions:\n" + moves)


def test_a_diagnoser_of_exclusive_products_is_checked_without_enumerating(tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": diagnoser_fan(40)})
    started = time.process_time()  # CPU time: the wall clock measures the machine's load
    code, out, err = cli(["check", folder], capsys, seconds=30)
    assert code == 0 and "not deterministic" not in err + out, err
    assert time.process_time() - started < 15  # 780 pairs: 14 hours by enumeration


def test_the_determinism_check_has_a_work_limit(tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": diagnoser_fan(8, "(i0 or i1) and ")})
    code, out, _ = cli(["check", folder], capsys, seconds=30)
    assert code == 0
    assert "were not checked for determinism (the check's limit of 131,072 assignments" in out


def test_a_long_grafcet_chain_written_backwards_checks_in_linear_time(tmp_path, capsys):
    count = 2000
    steps = "".join(f"      {k}: {{initial: {'true' if k == 0 else 'false'}}}\n"
                    for k in range(count))
    moves = "".join(f"      - {{from: {k}, to: {k + 1}, when: i0}}\n"
                    for k in reversed(range(count - 1)))
    text = DIAG_HEAD.replace("control:\n  equations:\n    Y: i1\n", "control:\n  grafcet:\n"
                             "    steps:\n" + steps + "    transitions:\n" + moves
                             + "  equations:\n    Y: i1\n")
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, out, err = cli(["check", folder], capsys, seconds=60)
    assert code == 0 and "can never become active" not in out, err


def test_a_sweep_too_long_to_finish_is_refused(capsys):
    starts = ",".join(f"{k}h" for k in range(1, 40))
    code, _, err = cli(["sweep", PROJECTS / "conveyor_robot", "--starts", starts, "--lengths",
                        "900h"], capsys, seconds=30)
    assert code == 2 and "more than the 100,000,000 scans plchmi runs at once" in err, err


@pytest.mark.parametrize("args, code_expected, fragment", [
    (["check", "a" * 5000], 2, "cannot use this path: File name too long"),
    (["check", "a\x00b"], 2, "no such project folder"),
    (["run", str(PROJECTS / "cispi_valve"), "--for", "1s", "--trace", "/tmp/a\x00b"], 2,
     "embedded null byte"),
    (["run", str(PROJECTS / "cispi_valve"), "--for", "1s", "--journal", "a" * 5000], 2,
     "file name too long"),
    (["journal", str(PROJECTS / "cispi_valve"), "--path", "a" * 5000], 2,
     "file name too long"),
])
def test_paths_the_system_refuses(args, code_expected, fragment, capsys):
    code, _, err = cli(args, capsys)
    assert code == code_expected and fragment in err, err


def test_a_campaign_too_long_to_finish_is_refused(tmp_path, capsys):
    folder = tmp_path / "cispi_valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    text = (folder / "campaign.yaml").read_text()
    (folder / "campaign.yaml").write_text(re.sub(r"length: *\S+", "length: 999h", text, count=1))
    code, _, err = cli(["campaign", folder], capsys)
    assert code == 2 and "more than the 100,000,000 plchmi runs at once" in err, err


# --------------------------------------------------------------------------------------------
# The project file itself
# --------------------------------------------------------------------------------------------

SECRET = "api_key: hunter2-SECRET\npassword: SECRET-2\n"


@pytest.mark.parametrize("command", [["check"], ["run", "--for", "100ms"],
                                     ["export", "--format", "st", "-o", "OUT"], ["journal"]])
@pytest.mark.parametrize("target", ["/etc/passwd", "secret.yaml"])
def test_a_project_file_that_leads_outside_its_folder_is_not_read(command, target, tmp_path,
                                                                  capsys):
    secret = write(tmp_path / "elsewhere", {"secret.yaml": SECRET}) / "secret.yaml"
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").symlink_to(secret if target == "secret.yaml" else target)
    args = [a.replace("OUT", str(tmp_path / "out")) for a in command]
    for given in (folder, folder / "project.yaml"):
        code, out, err = cli([args[0], given, *args[1:]], capsys)
        assert code == 2, err
        assert "leads outside the project folder; it is not read" in err
        for quoted in ("root:", "api_key", "SECRET", "password"):
            assert quoted not in out + err, err


def test_a_project_file_symlinked_inside_its_folder_is_fine(tmp_path):
    folder = write(tmp_path / "p", {"real.yaml": BASE})
    (folder / "project.yaml").symlink_to("real.yaml")
    assert load_project(folder).name == "t"


@pytest.mark.parametrize("text", ["x" * 3_500_000 + "\n", "? " + "k" * 3_500_000 + "\n: 1\n",
                                  BASE + "policy: " + "p" * 3_000_000 + "\n"],
                         ids=["scalar", "explicit-key", "value-quoted"])
def test_error_messages_quote_an_excerpt_never_the_file(text, tmp_path, capsys):
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, out, err = cli(["check", folder], capsys)
    assert code == 2
    assert len(out + err) < 2000, (len(out), len(err))
    assert "characters" in err, err  # the length is said, so the engineer knows what it was


def test_a_project_name_over_the_limit_is_refused_at_its_place(tmp_path, capsys):
    for length, code_expected in ((MAX_NAME_CHARS, 0), (MAX_NAME_CHARS + 1, 2)):
        text = BASE.replace("name: t", "name: " + "n" * length)
        folder = write(tmp_path / str(length), {"project.yaml": text})
        code, _, err = cli(["check", folder], capsys)
        assert code == code_expected, err
    expect_error_at(err, "project.yaml", 1, 7, f"more than {MAX_NAME_CHARS}")


def test_one_input_is_driven_by_one_sensor(tmp_path, capsys):
    """A pump's running feedback wired to the input a valve's end switch already drives:
    which of them the program reads would be an accident of the plant's step order."""
    folder = tmp_path / "sub"
    shutil.copytree(PROJECTS / "cispi_subsystem", folder)
    text = (folder / "project.yaml").read_text()
    library = os.path.relpath(ROOT / "components", folder)
    text = text.replace("../../components", library)
    (folder / "project.yaml").write_text(text.replace("run: Prun}", "run: fso1}"))
    code, _, err = cli(["check", folder], capsys)
    assert code == 2, err
    changed = (folder / "project.yaml").read_text()
    line = next(i for i, t in enumerate(changed.splitlines(), 1) if "run: fso1" in t)
    col = changed.splitlines()[line - 1].index("fso1}") + 1
    expect_error_at(err, "project.yaml", line, col, "pump sensor 'run' is bound to input "
                    "'fso1', which device 'V1' sensor 'fso'")
    # An output may order several devices: the conveyor's release is the robot's transfer.
    assert cli(["check", PROJECTS / "conveyor_robot"], capsys)[0] == 0


def test_a_journal_of_a_million_damaged_lines_is_read_in_bounded_memory(tmp_path, capsys):
    """Read one line at a time and said in a few lines: a million lines of garbage held
    ~250 MB as Damaged records and printed a million warnings."""
    path = tmp_path / "j.jsonl"
    lines = 1_000_000
    path.write_bytes(b'{"type":"action","event":"first"}\n' + b"x\n" * lines
                     + b'{"type":"action","event":"last"}\n')
    with bounded(60, extra_mb=100):
        code = main(["journal", str(PROJECTS / "cispi_valve"), "--path", str(path)])
    out, err = capsys.readouterr()
    assert code == 0 and "first" in out and "last" in out
    warnings = err.splitlines()
    assert len(warnings) == MAX_DAMAGED_SHOWN + 1, warnings[-3:]
    assert warnings[-1].endswith(f"... and {lines - MAX_DAMAGED_SHOWN:,} more damaged lines "
                                 "skipped")


# --------------------------------------------------------------------------------------------
# soak --replay: a file from outside, read as every other
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind, fragment", [
    ("binary", "replay.steps:1:3: not UTF-8 text"),
    ("device", "/dev/zero: not a regular file: this is a device"),
    ("fifo", "replay.steps: not a regular file: this is a FIFO"),
    ("big", "the file is too large"),
    ("long", "replay.steps:3:1: the steps run 3600001s of virtual time up to here, "
             "360,000,101 scans at a 10ms scan period: more than the 100,000,000"),
    ("folder", "this is a folder"),
])
def test_a_replay_file_is_read_safely_and_bounded(kind, fragment, tmp_path, capsys):
    path = tmp_path / "replay.steps"
    if kind == "binary":
        path.write_bytes(b"ru\xd0\x00n 1s\n")
    elif kind == "device":
        path = Path("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "big":
        path.write_bytes(b"press a\n" * (MAX_FILE_BYTES // 8 + 1))
    elif kind == "long":
        path.write_text("run 1s\npress a\nrun 1000h\n")
    elif kind == "folder":
        path.mkdir()
    code, out, err = cli(["soak", PROJECTS / "cispi_valve", "--replay", path], capsys)
    assert code == 2 and fragment in err, err
    assert "replaying" not in out  # refused before the HMI starts


def test_soak_minutes_are_bounded_by_the_run_limit(tmp_path, capsys):
    text = BASE.replace("scan_period: 10ms", "scan_period: 100us")
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, _, err = cli(["soak", folder, "--minutes", "10000"], capsys)
    assert code == 2 and "6,000,000,001 scans, more than the 100,000,000" in err, err


# --------------------------------------------------------------------------------------------
# Output paths that collide
# --------------------------------------------------------------------------------------------


def test_a_trace_over_the_journal_is_refused_before_a_byte_is_written(tmp_path, capsys):
    data = Path(os.environ["PLCHMI_DATA"])
    project = PROJECTS / "cispi_valve"
    assert cli(["run", project, "--for", "2s", "--control", "faulty"], capsys)[0] == 0
    journal = default_path("cispi_valve")
    assert journal.parent.parent == data
    before = journal.read_bytes()
    (tmp_path / "hard.jsonl").hardlink_to(journal)
    (tmp_path / "soft.jsonl").symlink_to(journal)
    mine = tmp_path / "mine.jsonl"
    mine.write_bytes(before)
    for args in (["--trace", journal], ["--trace", tmp_path / "hard.jsonl"],
                 ["--trace", tmp_path / "soft.jsonl"],
                 ["--trace", data / "cispi_valve" / ".." / "cispi_valve" / "journal.jsonl"],
                 ["--trace", mine, "--journal", mine],
                 ["--journal", mine, "--trace", tmp_path / ".." / tmp_path.name / "mine.jsonl"]):
        code, out, err = cli(["run", project, "--for", "1s", *args], capsys)
        assert code == 2, (args, err)
        assert "would be written over it" in err and "Ran" not in out, err
    assert journal.read_bytes() == before and mine.read_bytes() == before


@pytest.mark.parametrize("option", ["--trace", "--journal"])
def test_no_output_is_a_file_of_the_project(option, tmp_path, capsys):
    folder = tmp_path / "cispi_valve"
    shutil.copytree(PROJECTS / "cispi_valve", folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    for name in ("project.yaml", "constraints.yaml"):
        code, _, err = cli(["run", folder, "--for", "1s", option, folder / name], capsys)
        assert code == 2 and "this is a file of the project" in err, err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_an_export_never_writes_over_a_project_file(tmp_path, capsys):
    head, rest = BASE.split("inputs:", 1)
    folder = write(tmp_path / "cell", {
        "project.yaml": head.replace("name: t", "name: cell") + "include: [cell.st]\n",
        "cell.st": "inputs:" + rest})
    code, _, err = cli(["export", folder, "--format", "st", "-o", folder], capsys)
    assert code == 2 and "this is a file of the project" in err, err
    assert (folder / "cell.st").read_text() == "inputs:" + rest


def test_texts_of_a_budget_fallback_under_correct_say_what_happened(tmp_path, capsys):
    """Nothing is latched when the corrector writes the safe state for one scan: no "Safe
    blocking ... until a fault reset", no fault reset to recommend; and hundreds of broken
    rules without descriptions are counted, not "a safety rule" said hundreds of times."""
    from tests import costly
    text = costly.combined(300).replace("policy: correct\n", "policy: correct\n"
                                        "solver_budget: 100\n")
    folder = write(tmp_path / "p", {"project.yaml": text})
    code, out, err = cli(["run", folder, "--for", "100ms", "--explain"], capsys, seconds=30)
    assert code == 0, err
    assert "at the search budget" in out and "latched no" in out
    assert "Safe blocking" not in out and "release the latch" not in out
    assert "Fault reset" not in out
    assert "search for safe orders ran out of its budget" in out
    why = next(line for line in out.splitlines() if "used up its budget" in line)
    assert re.search(r"broke \d+ safety rules\.", why), why
    assert "a safety rule; a safety rule" not in out

"""Property-based fuzzing of everything plchmi reads from outside.

Four generators feed the real command, in-process, each case bounded in time and memory
(tests/bounds.py): mutated example projects (`check`, then `run` when it loads), generated
expressions (parsed, checked, compiled and evaluated; and inside a project), command lines
(`check`, `run`, `journal`, `diagnose` with hostile options) and journal files of generated
lines. The properties, for every case:

* the exit status is 0, 1 or 2, never "internal error", never a traceback;
* exit status 2 for file content names file:line:column, at a line and column of that file;
* the case ends within CASE_SECONDS and CASE_MB of memory;
* nothing is read outside the project folder and the component library (`check`), and the
  journal reader prints exactly the readable entries, one warning per damaged line.

Budget: PLCHMI_FUZZ_EXAMPLES examples per property (default: a CI budget of about a
minute for the whole file). A longer run on demand, random rather than derandomised:

    PLCHMI_FUZZ_EXAMPLES=2000 .venv/bin/python -m pytest tests/test_fuzz.py -p no:cacheprovider

(see docs/project-format.md, "Limits and paths").
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hmi.textfile
from hmi.cli import main
from hmi.errors import SourcePos
from hmi.logic.expr import (
    ExprError,
    NotMonomial,
    check_names,
    compile_bool,
    monomial_literals,
    parse_expr,
)
from hmi.paths import COMPONENTS
from tests.bounds import bounded
from tests.conftest import PROJECTS

LONG = "PLCHMI_FUZZ_EXAMPLES" in os.environ
EXAMPLES = int(os.environ.get("PLCHMI_FUZZ_EXAMPLES", "0")) or None
CASE_SECONDS = 10.0  # generous on a loaded 2-core machine; a case takes well under 1 s
CASE_MB = 600


def budget(ci_examples: int) -> settings:
    """CI: a fixed, derandomised budget (the same cases every run); on demand: more,
    random cases."""
    return settings(max_examples=EXAMPLES or ci_examples, deadline=None, derandomize=not LONG,
                    database=None, print_blob=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


# --------------------------------------------------------------------------------------------
# Running one case and checking its outcome
# --------------------------------------------------------------------------------------------

ERROR_LINE = re.compile(r"^(?P<file>.+?)(?::(?P<line>\d+):(?P<col>\d+))?: error: (?P<msg>.*)$")
# Errors about a whole file (no position inside it), the only ones allowed without line:col.
WHOLE_FILE = ("file not found", "not a regular file", "the file is too large", "cannot read",
              "this is a folder", "this folder has no project.yaml",
              "no such project folder or file", "the file is empty",
              "leads outside the project folder", "cannot be resolved")


def run_main(args: list[str], capsys, seconds: float = CASE_SECONDS,
             extra_mb: int = CASE_MB) -> tuple[int, str, str]:
    with bounded(seconds, extra_mb):
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse: a bad option value
            code = exc.code
    out, err = capsys.readouterr()
    assert code in (0, 1, 2), (args, code, err)
    assert "internal error" not in err and "Traceback" not in err, (args, err)
    return code, out, err


def check_positions(err: str, folder: Path) -> None:
    """Every error about file content is at file:line:column inside that file."""
    for line in err.splitlines():
        if line.startswith("plchmi:") or ": error: " not in line:
            continue
        match = ERROR_LINE.match(line)
        assert match, line
        if match["line"] is None:
            assert any(f in match["msg"] for f in WHOLE_FILE), line
            continue
        path = Path(match["file"])
        path = path if path.is_absolute() else Path.cwd() / path
        if not path.is_file() or path.stat().st_size > 10_000_000:
            continue
        lines = path.read_bytes().decode("utf-8", "replace").split("\n")
        row, col = int(match["line"]), int(match["col"])
        assert 1 <= row <= len(lines) + 1, line
        if row <= len(lines):
            assert 1 <= col <= len(lines[row - 1]) + 2, line


def copy_project(name: str, into: Path) -> Path:
    """An example project in a temporary folder, its component `use:` pointing at the
    library wherever the copy is."""
    folder = into / name
    shutil.copytree(PROJECTS / name, folder)
    project = folder / "project.yaml"
    text = project.read_text(encoding="utf-8")
    if "../../components/" in text:
        library = os.path.relpath(COMPONENTS, folder)
        project.write_text(text.replace("../../components", library), encoding="utf-8")
    return folder


def reads_confined_to(allowed: list[Path]) -> Callable[[], list[Path]]:
    """Record every file hmi.textfile opens; return the ones outside `allowed`."""
    opened: list[Path] = []
    original = hmi.textfile.open_regular

    def spy(path):
        opened.append(Path(path).resolve())
        return original(path)
    hmi.textfile.open_regular = spy
    roots = [p.resolve() for p in allowed]

    def outside() -> list[Path]:
        hmi.textfile.open_regular = original
        return [p for p in opened if not any(p.is_relative_to(r) for r in roots)]
    return outside


# --------------------------------------------------------------------------------------------
# Mutated example projects
# --------------------------------------------------------------------------------------------

EXAMPLES_PROJECTS = sorted(p.name for p in PROJECTS.iterdir() if (p / "project.yaml").exists())

HOSTILE_VALUES = [
    ".nan", ".inf", "-.inf", "9" * 40, "1e309", "-1", "0", "0x10", "0o17", "1:30", "~", "''",
    "yes", "on", "１０ms", "²", "'²'", "Ｙ", "𝐂 and ℂ", '"\\ud800"', '"\\0"', '"\\e[2J"',
    '"a\\nb"', "&a [*a]", "*nope", "[" * 80, "{" * 80, "!!python/object/apply:os.system [x]",
    "!!binary aGk=", "!!set {a}", "99999999999999h", "1001h", "1us", "0s", "0ms", "2s",
    "'di:０'", "'coil:70000'", "'hr:3.99'", "prev(a, 65)", "prev(a, 0)", "not " * 40 + "a",
    "(" * 40 + "a" + ")" * 40, "X1.t >= 99999h", "X99.t >= 1s", "a +", "rise(a and b)",
    "../../../etc/passwd", "/etc/passwd", "/dev/zero", "'" + "a" * 300 + "'",
    "[" + ", ".join(["x"] * 50) + "]", "{a: 1, a: 2}", "- x", "|\n  text", ">-", "? a", "@x",
    "`x`", "%TAG", "\t", "True", "False", "null", "[]", "{}", "C and O", "not C and fsc",
    "Y and not Y", "F5@1s", "F5@１s", "x.y@z",
]
INSERTED = ["\x00", "\x07", "\x1b", "\x7f", "\x85", "\u2028", "\ufeff", "\t", "\r", "\n",
            "\ud7ff", "é", "Ｙ", "𝐂", "\u202e", ": ", "- ", "#", "&", "*", "!", "%", "'", '"',
            "{", "}", "[", "]", ",", "|", ">"]
RAW_BYTES = [b"\xff", b"\xfe\xff", b"\xc3", b"\xed\xa0\x80", b"\x00", b"\xe9"]


@st.composite
def mutated_file(draw, text: str) -> bytes:
    lines = text.split("\n")
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["value", "key", "delete", "duplicate", "swap", "insert",
                                     "indent", "char", "bytes", "truncate", "bomb"]))
        k = draw(st.integers(0, max(0, len(lines) - 1)))
        line = lines[k] if lines else ""
        value = draw(st.sampled_from(HOSTILE_VALUES) | st.text(max_size=12))
        if kind == "value" and ":" in line:
            head = line.split(":", 1)[0]
            lines[k] = f"{head}: {value}"
        elif kind == "key" and ":" in line:
            indent = len(line) - len(line.lstrip(" "))
            lines[k] = " " * indent + value.replace(":", "") + ":" + line.split(":", 1)[1]
        elif kind == "delete" and lines:
            del lines[k]
        elif kind == "duplicate" and lines:
            lines.insert(k, line)
        elif kind == "swap" and len(lines) > 1:
            j = draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
        elif kind == "insert":
            indent = draw(st.sampled_from(["", "  ", "    "]))
            lines.insert(k, f"{indent}{draw(st.from_regex(r'[A-Za-z_]{1,8}', fullmatch=True))}"
                            f": {value}")
        elif kind == "indent" and lines:
            lines[k] = draw(st.sampled_from(["  ", "", "\t", " "])) + line.lstrip(" ")
        elif kind == "char":
            col = draw(st.integers(0, len(line)))
            lines[k] = line[:col] + draw(st.sampled_from(INSERTED)) + line[col:]
        elif kind == "bomb":
            lines.append("description: &b0 [x, x, x, x, x, x, x, x, x]")
            lines += [f"x{i}: &b{i} [" + ", ".join([f"*b{i - 1}"] * 9) + "]"
                      for i in range(1, 10)]
    data = "\n".join(lines).encode("utf-8", "surrogatepass")
    if kind == "bytes":
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.sampled_from(RAW_BYTES)) + data[at:]
    elif kind == "truncate":
        data = data[:draw(st.integers(0, len(data)))]
    return data


@st.composite
def mutated_project(draw) -> tuple[str, dict[str, bytes]]:
    name = draw(st.sampled_from(EXAMPLES_PROJECTS))
    files = sorted(p.name for p in (PROJECTS / name).glob("*.yaml"))
    changed = {}
    for file in draw(st.lists(st.sampled_from(files), min_size=1, max_size=2, unique=True)):
        text = (PROJECTS / name / file).read_text(encoding="utf-8")
        changed[file] = draw(mutated_file(text))
    return name, changed


@pytest.mark.slow
@budget(ci_examples=100)
@given(case=mutated_project())
def test_mutated_projects(case, capsys):
    name, changed = case
    with tempfile.TemporaryDirectory() as tmp:
        folder = copy_project(name, Path(tmp))
        for file, data in changed.items():
            (folder / file).write_bytes(data)
        outside = reads_confined_to([folder, COMPONENTS])
        try:
            code, _, err = run_main(["check", folder], capsys)
        finally:
            read_outside = outside()
        assert not read_outside, read_outside
        assert code in (0, 2), err
        if code == 2:
            check_positions(err, folder)
            return
        code, _, err = run_main(["run", folder, "--for", "300ms", "--trace",
                                 Path(tmp) / "t.csv"], capsys)
        check_positions(err, folder)


# --------------------------------------------------------------------------------------------
# Generated expressions
# --------------------------------------------------------------------------------------------

NAMES = ["a", "b", "Y", "Z", "T1", "X0", "X1", "X9", "prev", "rise", "fall", "True", "False",
         "None", "lambda", "import", "__import__", "os", "Ｙ", "𝐙", "ℂ", "a" * 60, "_", "x1"]
ATOMS = [*NAMES, "1", "0", "2", "1.5", "'x'", '"y"', "[]", "{}", "...", "1e3", "0x1",
                 "X1.t", "X1.t >= 2s", "X1.t < 1.5s", "X1.t == 99999999999h", "2s", "1min",
                 "１s", "prev(a)", "prev(a, 2)", "prev(a, 65)", "prev(a, -1)", "prev(a, b)",
                 "rise(a)", "fall(Z)", "rise(a and b)", "prev()", "max(a)", "a.b", "a[0]",
                 "a if b else Z", "(yield a)", "await a", "a := b", "f'{a}'", "*a", "**a"]
OPERATORS = [" and ", " or ", " and not ", " or not ", " + ", " == ", " >= ", " is ", " in ",
             ", ", " ", "", " & ", " | ", " ^ ", " // ", " not in "]


def expressions() -> st.SearchStrategy[str]:
    atom = st.sampled_from(ATOMS)
    base = st.one_of(atom, st.text(max_size=20))

    def extend(inner):
        return st.one_of(
            st.tuples(inner, st.sampled_from(OPERATORS), inner).map("".join),
            inner.map(lambda e: f"not {e}"),
            inner.map(lambda e: f"({e})"),
            st.tuples(st.sampled_from(["prev(", "rise(", "fall(", "not ("]), inner)
            .map(lambda t: t[0] + t[1] + ")"),
            st.tuples(st.integers(1, 60), st.sampled_from(["not ", "(", "not ("]), inner)
            .map(lambda t: t[1] * t[0] + t[2] + (")" * t[0] if "(" in t[1] else "")),
        )
    return st.recursive(base, extend, max_leaves=12)


NAMESPACE = {"a": "input", "b": "input", "Y": "output", "Z": "output", "T1": "timer",
             "x1": "observer"}
SLOTS = {name: k for k, name in enumerate(NAMESPACE)}


@pytest.mark.slow
@budget(ci_examples=600)
@given(text=expressions())
def test_generated_expressions(text):
    """Parsing gives an Expr or an ExprError at a column of the text; what passes the name
    check is a monomial or not (NotMonomial), and compiles and evaluates."""
    pos = SourcePos("f.yaml", 3, 7)
    with bounded(CASE_SECONDS, CASE_MB):
        try:
            expr = parse_expr(text, pos)
        except ExprError as exc:
            assert exc.pos.file == "f.yaml" and exc.pos.line == 3
            assert 7 <= exc.pos.col <= 7 + len(text) + 1, (text, exc.pos)
            return
        problems = check_names(expr, NAMESPACE, ("X0", "X1"))
        for problem in problems:
            assert 7 <= problem.pos.col <= 7 + len(text), (text, problem.pos)
        if problems:
            return
        with contextlib.suppress(NotMonomial):
            monomial_literals(expr)
        fn = compile_bool(expr, SLOTS, {"X0": len(SLOTS), "X1": len(SLOTS) + 1})
        image = [True, False, True, False, True, False, 5, 10]
        history = [list(image) for _ in range(64)]
        assert fn(image, history) in (True, False)


@pytest.mark.slow
@budget(ci_examples=100)
@given(text=expressions(), where=st.sampled_from(["equation", "constraint", "timer"]))
def test_generated_expressions_in_a_project(text, where, capsys):
    from tests.test_malformed import project_text
    quoted = json.dumps(text)  # a JSON string is a YAML double-quoted scalar
    sections = {"equation": {"control": f"control:\n  equations:\n    Y: {quoted}\n"
                                        "    Z: T1\n"},
                "constraint": {"constraints": f"constraints:\n  K1: {quoted}\n"},
                "timer": {"timers": f"timers:\n  T1: {{type: TON, input: {quoted}, "
                                    "preset: 1s}\n"}}[where]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "p"
        folder.mkdir()
        (folder / "project.yaml").write_text(project_text(**sections), encoding="utf-8")
        code, _, err = run_main(["check", folder], capsys)
        assert code in (0, 2)
        check_positions(err, folder)


# --------------------------------------------------------------------------------------------
# Command lines
# --------------------------------------------------------------------------------------------

DURATIONS = ["200ms", "1s", "0s", "-1s", "１s", "1e3s", "99999999999999999999h", "1001h",
             "999h", "nan", "", " 1s", "1.5s", "10 s", "1.0000000001s", "1min", "\x00"]
PERIODS = ["10ms", "1us", "100us", "0ms", "５ms", "1h", "1ms"]
INJECTIONS = ["F5@1s", "F5@１s", "F99@1s", "V1.F5@1s+2s", "@", "F5@99999999999h", "x" * 300,
              "C1.stop@1s+2s", "F5@1s+0s", "F5@-1s", "busy@1s+1s", "F5@1s+1001h"]
SINCE = ["2h", "0001-01-01", "9999-12-31T23:59:59", "2026-13-45", "soon", "99999999999999h",
         "２h", "2026-11-22T15:00+25:00", "1h\x00", "-1h", ""]
PLANTS = ["sim", "modbus://[::1", "modbus://h:99999", "modbus://h:x", "modbus://:502",
          "modbus://h:502/999", "modbus://h:502/²", "opcua://x", "", "modbus:///"]


def option_values(tmp: Path) -> dict[str, st.SearchStrategy]:
    paths = st.sampled_from([str(tmp / "out.csv"), str(tmp / "out.jsonl"), str(tmp),
                             "/dev/full", "/dev/null", str(tmp / "missing" / "x.csv"),
                             str(tmp / ("n" * 300)), "/proc/version"])
    texts = st.text(max_size=15)
    return {
        "--for": st.sampled_from(DURATIONS) | texts,
        "--period": st.sampled_from(PERIODS) | texts,
        "--inject": st.sampled_from(INJECTIONS) | texts,
        "--scenario": st.sampled_from(["paper", "nope", "", "../x"]) | texts,
        "--control": st.sampled_from(["faulty", "normal", "main", "Ｙ"]) | texts,
        "--policy": st.sampled_from(["monitor", "block", "correct", "x"]),
        "--solver": st.sampled_from(["exact", "paper", "z3"]),
        "--diagnosis": st.sampled_from(["ftc", "observe", "off", "on"]),
        "--trace": paths,
        "--journal": paths,
        "--plant": st.sampled_from(PLANTS) | texts,
        "--since": st.sampled_from(SINCE) | texts,
        "--path": paths,
    }


COMMAND_OPTIONS = {
    "check": [],
    "diagnose": [],
    "run": ["--for", "--for", "--period", "--inject", "--scenario", "--control", "--policy",
            "--solver", "--diagnosis", "--trace", "--journal", "--plant", "--explain"],
    "journal": ["--since", "--path", "--csv"],
}
FLAGS = {"--explain", "--csv"}


@st.composite
def command_line(draw, tmp: Path) -> list[str]:
    command = draw(st.sampled_from(sorted(COMMAND_OPTIONS)))
    project = draw(st.sampled_from([str(PROJECTS / p) for p in EXAMPLES_PROJECTS]
                                   + [str(tmp / "none"), "/dev/null", str(tmp), "",
                                      str(PROJECTS / "cispi_valve" / "project.yaml")]))
    args = [command, project]
    values = option_values(tmp)
    for option in draw(st.lists(st.sampled_from(COMMAND_OPTIONS[command] or ["--x"]),
                                max_size=5)):
        if option == "--x":
            args.append(draw(st.sampled_from(["--", "-", "--for", "--help=x", "-x"])))
        elif option in FLAGS:
            args.append(option)
        else:
            args += [option, draw(values[option])]
    if command == "run" and "--for" not in args and draw(st.booleans()):
        args += ["--for", "300ms"]
    if command == "diagnose":  # the closed-loop exploration takes a minute: not per case
        args.append("--no-closed-loop")
    return args


@pytest.mark.slow
@budget(ci_examples=150)
@given(data=st.data())
def test_command_lines(data, capsys):
    with tempfile.TemporaryDirectory() as tmp:
        journal = Path(tmp) / "j.jsonl"
        journal.write_text('{"type":"action","event":"x","wall":"2026-01-01T00:00:00"}\n')
        args = data.draw(command_line(Path(tmp)))
        run_main(args, capsys)


# --------------------------------------------------------------------------------------------
# Journal files
# --------------------------------------------------------------------------------------------

JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=4),
    max_leaves=10)
FIELDS = ["wall", "type", "event", "scan", "t", "message", "text", "key", "severity", "state",
          "project", "returns"]


@st.composite
def journal_line(draw) -> bytes:
    kind = draw(st.sampled_from(["entry", "entry", "entry", "odd-entry", "json", "bytes", "cut",
                                 "deep", "huge", "escape"]))
    entry = {"wall": "2026-11-22T15:00:00.000+00:00", "type": "action", "event": "x",
             "scan": draw(st.integers(0, 10**6)), "t": "1.000", "message": draw(st.text())}
    if kind == "entry":
        return json.dumps(entry, ensure_ascii=draw(st.booleans())).encode("utf-8",
                                                                        "surrogatepass")
    if kind == "odd-entry":
        entry[draw(st.sampled_from(FIELDS))] = draw(JSON_VALUES)
        return json.dumps(entry).encode()
    if kind == "json":
        return json.dumps(draw(JSON_VALUES)).encode()
    if kind == "bytes":
        return draw(st.binary(max_size=60)).replace(b"\n", b" ")
    if kind == "cut":
        line = json.dumps(entry).encode()
        return line[:draw(st.integers(0, len(line)))]
    if kind == "deep":
        return draw(st.sampled_from([b"[", b"{\"a\":"])) * draw(st.integers(1, 50_000))
    if kind == "huge":
        return b'{"n": ' + b"9" * draw(st.integers(4000, 6000)) + b"}"
    return json.dumps({"message": draw(st.sampled_from(["\x1b[2J", "\ud800", "\x00", "\u202e",
                                                        "\x07\x08", "\u2028", "\x85"]))}).encode()


@pytest.mark.slow
@budget(ci_examples=150)
@given(lines=st.lists(journal_line(), max_size=12), newline_at_end=st.booleans(),
       since=st.sampled_from([None, "1h", "0001-01-01", "2026-11-22T15:00"]),
       csv=st.booleans())
def test_journal_files(lines, newline_at_end, since, csv, capsys):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "journal.jsonl"
        data = b"\n".join(lines) + (b"\n" if newline_at_end and lines else b"")
        path.write_bytes(data)
        args = ["journal", PROJECTS / "cispi_valve", "--path", path]
        if since:
            args += ["--since", since]
        if csv:
            args.append("--csv")
        code, out, err = run_main(args, capsys)
        assert code == 0, err
        warned = re.findall(rf"^plchmi: warning: {re.escape(str(path))}:(\d+): damaged journal "
                            "entry skipped: .+$", err, re.M)
        numbers = [int(n) for n in warned]
        assert numbers == sorted(set(numbers)) and all(1 <= n <= len(lines) for n in numbers)
        readable = sum(1 for line in lines if line.strip()) - len(numbers)
        if not csv and since is None:
            assert len(out.splitlines()) == readable, (out, err)
        assert "\x1b" not in out and "\x00" not in out


# --------------------------------------------------------------------------------------------
# The project file as a symlink
# --------------------------------------------------------------------------------------------

LINK_TARGETS = ["/etc/passwd", "/etc/hostname", "/dev/zero", "/proc/self/status", "secret",
                "secret_dir/s.yaml", "inside", "sub/inside.yaml", "missing", "loop", "..",
                "/", "project.yaml.d"]


@pytest.mark.slow
@budget(ci_examples=40)
@given(target=st.sampled_from(LINK_TARGETS), through=st.sampled_from(["folder", "file"]),
       command=st.sampled_from(["check", "run", "journal", "export"]))
def test_symlinked_project_files(target, through, command, capsys):
    """project.yaml a symlink, to anything: read only when it leads to a file inside its
    folder; nothing of a file outside is ever printed."""
    from tests.test_malformed import project_text
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "secret").write_text("api_key: SECRET-KEY\n")
        (root / "secret_dir").mkdir()
        (root / "secret_dir" / "s.yaml").write_text("password: SECRET-PW\n")
        folder = root / "p"
        (folder / "sub").mkdir(parents=True)
        (folder / "inside").write_text(project_text())
        (folder / "sub" / "inside.yaml").write_text(project_text())
        (folder / "project.yaml.d").mkdir()
        link = folder / "project.yaml"
        if target == "loop":
            (folder / "loop").symlink_to(link)
        outside = target.startswith("/") or target.startswith("secret") or target == ".."
        link.symlink_to(target if target.startswith("/") else
                        (root / target if target.startswith("secret") else target))
        args = {"check": ["check"], "run": ["run", "--for", "100ms"], "journal": ["journal"],
                "export": ["export", "--format", "st", "-o", root / "out"]}[command]
        given_path = folder if through == "folder" else link
        read_outside = reads_confined_to([folder, COMPONENTS, Path(os.environ["PLCHMI_DATA"])])
        try:
            code, out, err = run_main([args[0], given_path, *args[1:]], capsys)
        finally:
            opened = read_outside()
        assert not opened, opened
        for secret in ("SECRET", "root:", "api_key", "password", "VmSize"):
            assert secret not in out + err, (target, out, err)
        if outside:
            assert code == 2, err
        if target in ("inside", "sub/inside.yaml") and command == "check":
            assert code == 0, err


# --------------------------------------------------------------------------------------------
# soak --replay files
# --------------------------------------------------------------------------------------------

STEP_LINES = ["run 1s", "run 10ms", "run 1000h", "run 99999999h", "run -1s", "run", "run １s",
              "press r y", "press", "palette Manual: O on", "palette", "row O", "row",
              "click #io 3 1", "click #io x 1", "click", "resize 80x24", "resize 0x0",
              "resize 99999999999999999999x1", "# a comment", "", "  ", "jump", "\t run 1s"]


@pytest.mark.slow
@budget(ci_examples=150)
@given(lines=st.lists(st.sampled_from(STEP_LINES) | st.text(max_size=20), max_size=12),
       raw=st.sampled_from([b"", b"\xff", b"\x00", b"\xed\xa0\x80", b"\r"]),
       kind=st.sampled_from(["file", "file", "file", "fifo", "folder", "device"]))
def test_replay_files(lines, raw, kind):
    """A replay file is a list of steps or a usage error at FILE:LINE:COL, read as every file
    from outside: never a hang, an internal error or a run past MAX_RUN_SCANS."""
    from hmi.errors import UsageError
    from hmi.limits import MAX_RUN_SCANS
    from hmi.soak.command import read_replay
    from hmi.soak.steps import Run
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.steps"
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "folder":
            path.mkdir()
        elif kind == "device":
            path = Path("/dev/zero")
        else:
            path.write_bytes("\n".join(lines).encode("utf-8", "surrogatepass") + raw)
        with bounded(CASE_SECONDS, CASE_MB):
            try:
                steps = read_replay(path, 10_000)
            except UsageError as exc:
                assert str(exc).startswith(f"--replay {path}"), exc
                return
        assert kind == "file"
        assert sum(s.us for s in steps if isinstance(s, Run)) // 10_000 + 1 <= MAX_RUN_SCANS


# --------------------------------------------------------------------------------------------
# Output paths that collide
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@budget(ci_examples=60)
@given(trace=st.sampled_from(["journal", "hard", "soft", "dotted", "project", "include",
                              "other", "same", None]),
       journal=st.sampled_from(["default", "explicit", "project", "other", "same"]))
def test_output_paths_that_collide(trace, journal, capsys):
    """No output is written over the journal, a file of the project or the other output:
    a usage error before a byte is written, and every file as it was."""
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        folder = copy_project("cispi_valve", root)
        default = Path(os.environ["PLCHMI_DATA"]) / "cispi_valve" / "journal.jsonl"
        default.parent.mkdir(parents=True, exist_ok=True)
        default.write_text('{"type":"session","event":"start"}\n')
        mine = root / "mine.jsonl"
        mine.write_text('{"type":"session","event":"start"}\n')
        journal_path = {"default": None, "explicit": mine, "project": folder / "project.yaml",
                        "other": root / "j2.jsonl", "same": root / "t.jsonl"}[journal]
        used_journal = journal_path or default
        linked = used_journal.exists()
        if linked:
            (root / "hard").hardlink_to(used_journal)
        paths = {"journal": used_journal, "hard": root / "hard", "soft": root / "soft",
                 "dotted": used_journal.parent / ".." / used_journal.parent.name
                 / used_journal.name, "project": folder / "control.yaml",
                 "include": folder / "constraints.yaml", "other": root / "t.csv",
                 "same": root / "t.jsonl", None: None}
        (root / "soft").symlink_to(used_journal)
        before = {p: p.read_bytes() for p in [default, mine, *folder.iterdir()] if p.is_file()}
        args = ["run", folder, "--for", "200ms"]
        if trace is not None:
            args += ["--trace", paths[trace]]
        if journal_path is not None:
            args += ["--journal", journal_path]
        code, _, err = run_main(args, capsys)
        clash = journal == "project" or (trace is not None and (
            trace in ("journal", "project", "include", "dotted", "soft")
            or (trace == "hard" and linked)
            or (trace == "same" and journal == "same")))
        if clash:
            assert code == 2 and "would be written over it" in err, (args, err)
            assert {p: p.read_bytes() for p in before} == before
        else:
            assert code == 0, (args, err)
            assert {p: p.read_bytes() for p in before if p.parent == folder} == \
                {p: b for p, b in before.items() if p.parent == folder}


# --------------------------------------------------------------------------------------------
# Projects under every limit, and floods
# --------------------------------------------------------------------------------------------


@pytest.mark.slow
@budget(ci_examples=12)
@given(kind=st.sampled_from(["monomials", "short", "combined", "opposed", "aliased"]),
       count=st.integers(1, 10_000), outputs=st.integers(3, 64),
       inputs=st.integers(2, 200))
def test_many_constraint_projects(kind, count, outputs, inputs, capsys):
    """Generated projects of up to MAX_CONSTRAINTS constraints and the longest expressions:
    `check` and a short `run` each end within a CPU time and memory bound, whatever the
    shape (refused past MAX_TOTAL_EXPR_CHARS at file:line:column)."""
    import time

    from tests import costly
    make = costly.KINDS[kind]
    if kind == "monomials":
        count = min(count, 2000)  # 2,000 of them are 3.9 MB: under MAX_FILE_BYTES
    text = make(count, inputs=inputs, outputs=outputs)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "p"
        folder.mkdir()
        (folder / "project.yaml").write_text(text)
        for args in (["check", folder], ["run", folder, "--for", "200ms"]):
            started = time.process_time()
            code, _, err = run_main(args, capsys, seconds=60, extra_mb=1000)
            assert time.process_time() - started < 40, args
            assert code in (0, 2), err
            check_positions(err, folder)
            if code == 2:
                break


@pytest.mark.slow
@budget(ci_examples=4)
@given(count=st.integers(50, 800), bits=st.integers(3, 12), outputs=st.integers(4, 40))
def test_flooding_projects(count, bits, outputs, capsys):
    """Hundreds of rules broken at each scan: at most FLOOD_LIMIT constraint alarms raised
    and one flood alarm; the journal a bounded number of lines a scan."""
    from hmi.explain.alarms import FLOOD_KEY, FLOOD_LIMIT
    from hmi.explain.journal import read
    from tests import costly
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "p"
        folder.mkdir()
        (folder / "project.yaml").write_text(costly.flood(count, bits, outputs))
        journal = Path(tmp) / "j.jsonl"
        code, _, err = run_main(["run", folder, "--for", "300ms", "--journal", journal],
                                capsys, seconds=60, extra_mb=1000)
        assert code == 0, err
        alarms = [e for e in read(journal).entries if e["type"] == "alarm"]
        raised = {e["key"] for e in alarms if e["event"] == "raised"
                  and e["key"].startswith("constraint:")}
        assert len(raised) <= FLOOD_LIMIT
        # the flood alarm is raised once; a flood that comes and goes scan by scan is an
        # alarm that chatters, collapsed as any other
        flood = [e["event"] for e in alarms if e["key"] == FLOOD_KEY]
        assert not flood or (flood[0] == "raised" and flood.count("raised") == 1), flood
        assert len(alarms) <= 31 * (2 * FLOOD_LIMIT + 5)


def test_the_budget_is_documented():
    docs = (Path(__file__).resolve().parent.parent / "docs" / "project-format.md").read_text()
    assert "PLCHMI_FUZZ_EXAMPLES" in docs


@pytest.fixture(autouse=True)
def _no_stray_files():
    """No case leaves a file in the working directory (all outputs go to temporary folders)."""
    before = set(os.listdir("."))
    yield
    assert set(os.listdir(".")) <= before | {".hypothesis"}

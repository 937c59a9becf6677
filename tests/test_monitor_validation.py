"""Malformed `monitors:` and `scenarios:` sections: file:line:column, a clear message, exit 2.

Same method as test_malformed: each case marks the token the error must point at, and the
expected position is found in the text the test wrote.
"""

from __future__ import annotations

import re

import pytest

from hmi.cli import main
from hmi.errors import ProjectError
from hmi.project.loader import load_project
from hmi.project.monitors import monitors_of
from hmi.project.scenarios import scenarios_of
from tests.test_malformed import _position, project_text

GOOD = """
monitors:
  job:
    description: the job
    start: rise(Y)
    end: rise(a)
    interrupted: b
    normal: [3s, 4s]
    acceptable: [3s, 5s]
"""


def monitors(body: str) -> str:
    return "monitors:\n  job:\n" + "".join(f"    {line}\n" for line in body.split("; "))


BASE_JOB = "start: rise(Y); end: rise(a); normal: [3s, 4s]; acceptable: [3s, 5s]"

CASES = [
    ("beta-not-below-gamma", "gamma 4s of monitor 'job' is not longer than beta 4s", "4s]",
     monitors("start: a; end: b; normal: [3s, 4s]; acceptable: [3s, 4s]"), 2),
    ("alpha-above-beta", "alpha is longer than beta", "4s,",
     monitors("start: a; end: b; normal: [4s, 3s]; acceptable: [4s, 5s]"), 1),
    ("alphas-differ", "starts at 2s but the normal one at 3s", "2s",
     monitors("start: a; end: b; normal: [3s, 4s]; acceptable: [2s, 5s]"), 1),
    ("unknown-signal", "unknown name 'bb'", "bb",
     monitors("start: a; end: rise(bb); normal: [3s, 4s]; acceptable: [3s, 5s]"), 1),
    ("memory-in-monitor", "'M' is a memory", "M\n",
     "memories:\n  M: m\n" + monitors(BASE_JOB + "; interrupted: M"), 1),
    ("duration-no-unit", "alpha of the normal duration of monitor 'job' 3 has no unit", "3,",
     monitors("start: a; end: b; normal: [3, 4s]; acceptable: [3s, 5s]"), 1),
    ("duration-not-duration", "'soon' is not a duration", "soon",
     monitors("start: a; end: b; normal: [3s, soon]; acceptable: [3s, 5s]"), 1),
    ("three-values", "has 3 values", "[3s, 4s, 5s]",
     monitors("start: a; end: b; normal: [3s, 4s, 5s]; acceptable: [3s, 5s]"), 1),
    ("not-a-list", "must be a list", "3s\n",
     monitors("start: a; end: b; normal: 3s; acceptable: [3s, 5s]"), 1),
    ("interrupt-without-resume", "has 'interrupt' but no 'resume'", "rise(b)",
     monitors(BASE_JOB + "; interrupt: rise(b)"), 1),
    ("level-and-events", "has both 'interrupted' and 'interrupt'", "fall(b)",
     monitors(BASE_JOB + "; interrupted: b; interrupt: fall(b)"), 1),
    ("missing-end", "monitor 'job' has no 'end'", "start",
     monitors("start: a; normal: [3s, 4s]; acceptable: [3s, 5s]"), 1),
    ("unknown-key", "unknown key 'gamma'", "gamma",
     monitors(BASE_JOB + "; gamma: 5s"), 1),
    ("label-is-a-variable", "fault label 'a' is already declared as input", "a\n",
     monitors(BASE_JOB + "; label: a"), 1),
    ("label-twice", "fault label 'job_fault' is already used", "job_fault",
     monitors(BASE_JOB) + "  other:\n    start: a\n    end: b\n    normal: [1s, 2s]\n"
     "    acceptable: [1s, 3s]\n    label: job_fault\n", 1),
    ("bad-task-name", "'2job' is not a valid task name", "2job",
     monitors(BASE_JOB).replace("job:", "2job:"), 1),
    ("scenario-unknown-fault", "unknown fault 'F99'", "F99",
     "scenarios:\n  s1: {inject: [F5@1s, F99@2s]}\n", 1),
    ("scenario-bad-injection", "'F5 at 1s' is not a fault injection", "F5 at",
     "scenarios:\n  s1: {inject: [F5 at 1s]}\n", 1),
    ("scenario-no-inject", "scenario 's1' has no 'inject'", "{description",
     "scenarios:\n  s1: {description: nothing}\n", 1),
    ("scenario-bad-length", "the length of scenario 's1' 'long' is not a duration", "long",
     "scenarios:\n  s1: {inject: [], for: long}\n", 1),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_malformed_monitor_or_scenario(case, tmp_path, capsys):
    _, fragment, token, extra, nth = case
    folder = tmp_path / "p"
    folder.mkdir()
    text = project_text() + extra
    (folder / "project.yaml").write_text(text, encoding="utf-8")
    with pytest.raises(ProjectError) as info:
        load_project(folder)
    matching = [d for d in info.value.errors if fragment in d.message + str(d.expected)]
    assert matching, [str(d) for d in info.value.errors]
    d = matching[0]
    # The token is searched after the section starts, so the base project cannot match.
    offset = text.index(extra)
    line, col = _position(text[offset:], token, nth)
    line += text.count("\n", 0, offset)
    assert (d.pos.line, d.pos.col) == (line, col), str(d)
    assert main(["check", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and fragment in err
    assert re.search(r"project\.yaml:\d+:\d+: error: ", err)


def test_a_good_monitor_loads_with_its_defaults(tmp_path):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text() + GOOD.lstrip("\n")
                                         + "scenarios:\n  s1: {inject: [F5@1s+2s]}\n")
    project = load_project(folder)
    (m,) = monitors_of(project)
    assert (m.name, m.label, m.alpha_us, m.beta_us, m.gamma_us) == (
        "job", "job_fault", 3_000_000, 4_000_000, 5_000_000)
    assert str(m.interrupted) == "b" and m.interrupt is None
    (s,) = scenarios_of(project)
    assert str(s.injections[0]) == "F5@1s+2s" and s.duration_us is None


def test_durations_off_the_scan_grid_are_a_warning(tmp_path):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text() + GOOD.lstrip("\n").replace(
        "[3s, 5s]", "[3s, 5.005s]"))
    warnings = [str(w) for w in load_project(folder).warnings]
    assert any("5.005s in monitor 'job' is not a multiple of the scan period" in w
               for w in warnings)


def test_a_monitor_reading_deep_history_gets_it(tmp_path):
    # prev(a, 5) needs five past images; the engine's history grows to fit the monitors.
    from tests.conftest import make_session
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / "project.yaml").write_text(project_text() + GOOD.lstrip("\n").replace(
        "start: rise(Y)", "start: prev(Y, 5) and not prev(Y, 6)"))
    session = make_session(folder)
    assert session.engine.history.maxlen >= 6
    session.run_for(3_000_000)
    (m,) = session.last.snapshot.monitors
    # Y is written from the first scan (t = 0): five scans later is the 50 ms scan.
    assert m.attempt >= 1 and session.last.error is None
    first = make_session(folder)
    starts = []

    def on_scan(cell):
        if cell.snapshot.monitors[0].attempt:
            starts.append(cell.snapshot.time_us)

    first.run_for(200_000, on_scan)
    assert starts[0] == 50_000

"""What a project under every limit may cost: the total of its expressions after aliases
(MAX_TOTAL_EXPR_CHARS) bounds compiling and running it, the analysis of `check` stops at
MAX_ANALYSIS_STEPS. Each case is a generator of tests/costly.py run as the command a user
types, in-process, its CPU time measured (never the wall clock: the machine is shared) and
its address space bounded (tests/bounds.py). The bounds are generous for a loaded 2-core
machine; each case cost several times more before those limits (figures in the docstrings,
CPU time and resident memory measured with /usr/bin/time -v).
"""

from __future__ import annotations

import re
import time

import pytest

from hmi.cli import main
from hmi.limits import MAX_ANALYSIS_STEPS, MAX_TOTAL_EXPR_CHARS
from tests import costly
from tests.bounds import bounded


def costs(args: list, capsys, seconds: float, extra_mb: int) -> tuple[int, str, str, float]:
    """main(args) under a CPU and an address-space bound: (exit status, out, err, CPU s)."""
    started = time.process_time()
    with bounded(seconds, extra_mb):
        code = main([str(a) for a in args])
    cpu = time.process_time() - started
    out, err = capsys.readouterr()
    assert "internal error" not in err and "Traceback" not in err, err
    return code, out, err, cpu


def test_ten_thousand_aliases_of_the_longest_monomial_are_refused_at_the_total(tmp_path,
                                                                                capsys):
    """A 125 KB file: `check` took 15 CPU s and 765 MB, `run` 115 s and 6.6 GB."""
    folder = costly.write("aliased", tmp_path / "p")
    code, _, err, cpu = costs(["check", folder], capsys, seconds=20, extra_mb=300)
    assert code == 2 and err.count(": error: ") == 1, err
    assert re.search(r"project\.yaml:\d+:7: error: the project's expressions pass "
                     f"{MAX_TOTAL_EXPR_CHARS:,} characters in all here", err), err
    assert cpu < 5, cpu


def test_two_thousand_longest_monomials_are_refused(tmp_path, capsys):
    """3.9 MB, under the file size limit: `run` spent 15 CPU s and 1.36 GB compiling them."""
    folder = costly.write("monomials", tmp_path / "p", 2000)
    code, _, err, cpu = costs(["run", folder, "--for", "100ms"], capsys, seconds=30,
                              extra_mb=400)
    assert code == 2 and "characters in all here" in err, err
    assert cpu < 10, cpu


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["monomials", "short"])
def test_a_project_at_the_limits_is_checked_and_run_in_bounded_cost(kind, tmp_path, capsys):
    """The most expression text in the longest monomials (check 1.0 CPU s and 40 MB, run 1.5 s
    and 154 MB) or in the most constraints, combined (check 2.9 s and 82 MB, run 3.0 s and
    177 MB): what docs/project-format.md gives as the worst."""
    folder = costly.write(kind, tmp_path / "p")
    code, out, err, cpu = costs(["check", folder], capsys, seconds=40, extra_mb=600)
    assert code == 0 and "Safety filter analysis" in out, err
    assert cpu < 20, cpu
    code, out, err, cpu = costs(["run", folder, "--for", "1s"], capsys, seconds=40,
                                extra_mb=800)
    assert code == 0, err
    assert cpu < 20, cpu


@pytest.mark.parametrize("kind", ["combined", "opposed"])
def test_the_filter_analysis_stops_at_its_work_limit(kind, tmp_path, capsys):
    """2,000 combined constraints over 24 outputs, each situation a new problem for the
    corrector: 46 CPU s. 10,000 simple ones forcing one output both ways: 25 million pairs
    to compare, 17 CPU s. Both said as bounded, with the limit."""
    folder = costly.write(kind, tmp_path / "p")
    code, out, err, cpu = costs(["check", folder], capsys, seconds=30, extra_mb=400)
    assert code == 0, err
    assert "bounded: " in out
    if kind == "combined":
        assert f"stopped at the analysis's work limit of {MAX_ANALYSIS_STEPS:,} steps" in out
    else:
        assert "conflicts between simple constraints: at least " in out
    assert cpu < 8, cpu


# --------------------------------------------------------------------------------------------
# Per scan: the filter's work within its budget, its caches bounded, an alarm flood contained
# --------------------------------------------------------------------------------------------


def engine_of(text: str, folder):
    from hmi.engine.scan import Engine
    from hmi.plant.sim import SimPlant
    from hmi.project.loader import load_project
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "project.yaml").write_text(text, encoding="utf-8")
    project = load_project(folder)
    return project, Engine(project, SimPlant(project))


def every_output_asked(text: str, outputs: int) -> str:
    return text.replace("    Y0: i0\n", "".join(f"    Y{k}: True\n" for k in range(outputs)))


def test_preparing_the_correction_counts_in_the_budget(tmp_path):
    """9,000 three-output constraints on 40 outputs: the search reported 9,000 to 9,670 steps
    against a budget of 5,000, its problem's preparation not counted. Now each scan's report
    stays within the budget (a search stops at its next node: a few steps past it at most),
    and a problem whose preparation alone passes it is not searched."""
    text = every_output_asked(costly.short(9000, outputs=40), 40)
    project, engine = engine_of(text, tmp_path / "p")
    budget = engine.safety_filter.budget
    reports = [engine.step(k * project.scan_period_us).filter_report for k in range(20)]
    searched = [r for r in reports if r is not None and r.steps]
    assert searched and all(r.steps <= budget * 1.02 for r in searched), \
        [r.steps for r in searched]
    assert any("would take" in (r.fallback or "") and "not searched" in r.fallback
               for r in searched), searched[0].fallback
    text = every_output_asked(costly.short(2000, outputs=40), 40)
    project, engine = engine_of(text, tmp_path / "q")
    reports = [engine.step(k * project.scan_period_us).filter_report for k in range(20)]
    assert all(r.steps <= budget * 1.02 for r in reports if r is not None), \
        [r.steps for r in reports if r is not None]
    assert any("of them preparing it" in (r.fallback or "") for r in reports if r is not None)


def test_the_filter_caches_are_bounded_and_change_no_decision(tmp_path, monkeypatch):
    """Contexts following a counter: a new set of active constraints at every scan. The
    prepared sets were never dropped (36 MB per 100 scans); bounded now by the constraints
    they hold, and a filter that clears them often decides exactly as one that keeps them."""
    import hmi.engine.filter as filter_module
    text = costly.flood(600, bits=10)
    project, kept = engine_of(text, tmp_path / "a")
    monkeypatch.setattr(filter_module, "ACTIVE_SET_CACHE", 500)
    monkeypatch.setattr(filter_module, "CORRECTION_CACHE_SIZE", 300)
    _, cleared = engine_of(text, tmp_path / "b")
    for k in range(60):
        a = kept.step(k * project.scan_period_us)
        b = cleared.step(k * project.scan_period_us)
        assert (a.outputs, a.filter_report.steps, a.filter_report.fallback) == \
            (b.outputs, b.filter_report.steps, b.filter_report.fallback), k
        assert cleared.safety_filter._by_active_size <= 500 + 600
        assert cleared.safety_filter._corrections_size <= 300 + 600


@pytest.mark.slow
def test_a_new_active_set_every_scan_holds_bounded_memory(tmp_path):
    """flood(): 3,000 combined constraints, a new active set at each scan. Before the bound:
    52 MB more held after 300 scans, growing without end; now the caches stop near 25 MB."""
    import tracemalloc
    project, engine = engine_of(costly.flood(), tmp_path / "p")
    for k in range(10):
        engine.step(k * project.scan_period_us)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        with bounded(240, 600):
            for k in range(10, 310):
                engine.step(k * project.scan_period_us)
        held = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    assert held < 32 * 1024 * 1024, held / 1e6


def test_an_alarm_flood_is_one_alarm_and_a_few_journal_writes_per_scan(tmp_path, capsys,
                                                                     monkeypatch):
    """Hundreds of rules broken at each scan were hundreds of alarms, each its own fsynced
    journal line (a 5 s run: 207,221 lines, 86 s). Now the list holds FLOOD_LIMIT of them and
    one flood alarm counts the others; a scan's transitions are one write and one fsync."""
    import os

    from hmi.explain.alarms import FLOOD_KEY, FLOOD_LIMIT
    from hmi.explain.journal import read
    folder = costly.write("flood", tmp_path / "p", 1500)
    journal = tmp_path / "journal.jsonl"
    fsyncs = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (fsyncs.append(fd), real_fsync(fd))[1])
    code, _, err, cpu = costs(["run", folder, "--for", "1s", "--journal", journal], capsys,
                                seconds=60, extra_mb=600)
    assert code == 0, err
    entries = read(journal).entries
    alarms = [e for e in entries if e["type"] == "alarm"]
    floods = [e for e in alarms if e["key"] == FLOOD_KEY]
    assert [e["event"] for e in floods] == ["raised"], floods
    assert "more safety rules broken than the list shows" in floods[0]["text"]
    raised = {e["key"] for e in alarms if e["event"] == "raised"
              and e["key"].startswith("constraint:")}
    assert len(raised) <= FLOOD_LIMIT, len(raised)
    assert len(entries) < 2000, len(entries)
    assert len(fsyncs) <= 2 * 101 + 10, len(fsyncs)
    assert cpu < 30, cpu

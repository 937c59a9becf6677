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

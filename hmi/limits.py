"""Every limit on what a project, a journal or a command line may ask of plchmi, in one place.

A project file is data from anywhere: a file of a few hundred bytes can ask for gigabytes (a
YAML alias bomb), a deep nest of brackets can exhaust Python's stack, a duration of 10^20
hours never ends. Each limit below is far above what a real cell needs (the figures in
brackets are the largest of the example projects) and low enough that reaching it costs
well under a second and a few tens of megabytes. Reaching one is a bad-input error (exit
status 2) that names the limit, never a crash or a hang. docs/project-format.md lists them.
"""

from __future__ import annotations

MAX_FILE_BYTES = 4 * 1024 * 1024
"""Size of one project, include or component file [13 KB]."""

MAX_YAML_NODES = 100_000
"""YAML nodes of one file, counting each use of an alias as a copy of what it names [860]."""

MAX_YAML_DEPTH = 64
"""Nesting of YAML mappings and lists [8]."""

MAX_NUMBER_DIGITS = 30
"""Digits of a number written in a project file [6]."""

MAX_EXPR_CHARS = 2000
"""Characters of one expression [about 90]."""

MAX_EXPR_DEPTH = 32
"""Nesting of an expression: parentheses and `not` inside each other [3]."""

MAX_TOTAL_EXPR_CHARS = 400_000
"""Characters of all a project's expressions together, each use of a YAML alias and each
component instance counted as a copy [about 9,000]: what compiling, checking and running a
project costs grows with it (MAX_EXPR_CHARS x MAX_CONSTRAINTS would be 20 million)."""

MAX_CONSTRAINTS = 10_000
"""Safety constraints of a project, its components' included [20]."""

MAX_VARIABLES = 10_000
"""Inputs, outputs, memories, timers and observers of a project [40]."""

MAX_NAME_CHARS = 200
"""Characters of a name (a variable, a constraint, the project's name) [30]."""

MAX_DURATION_US = 1000 * 3_600_000_000
"""The longest duration written anywhere (1000 h: a preset, a window, a run's length)."""

MIN_SCAN_PERIOD_US = 100
"""The shortest scan period (0.1 ms) [5 ms]."""

MAX_RUN_SCANS = 100_000_000
"""Scans of one headless run (100 h at a 10 ms scan period; hours of computing)."""

NOTICE_RUN_SCANS = 2_000_000
"""Above this many scans a headless run says up front that it will take a while."""

MAX_DETERMINISM_ASSIGNMENTS = 1 << 17
"""Assignments a diagnoser's determinism check may enumerate in all [408]; past it, the
remaining pairs of transitions are left unchecked with a warning."""

MAX_ANALYSIS_STEPS = 2_000_000
"""Work of `plchmi check`'s safety filter analysis, in the corrector's steps (a constraint
or a literal read) [about 60,000]; past it the analysis stops and says how far it went."""

MAX_JOBS = 32
"""Worker processes of `plchmi campaign --jobs` (a fork bomb otherwise)."""

MAX_JOURNAL_LINE_BYTES = 1024 * 1024
"""One journal entry; a longer line is damaged [about 400 bytes]."""

MAX_DAMAGED_SHOWN = 10
"""Damaged lines of a journal said one by one by `plchmi journal`; the rest are counted."""

__all__ = [
    "MAX_ANALYSIS_STEPS",
    "MAX_CONSTRAINTS", "MAX_DAMAGED_SHOWN", "MAX_DETERMINISM_ASSIGNMENTS", "MAX_DURATION_US",
    "MAX_EXPR_CHARS",
    "MAX_EXPR_DEPTH", "MAX_FILE_BYTES", "MAX_JOBS", "MAX_JOURNAL_LINE_BYTES", "MAX_NAME_CHARS",
    "MAX_NUMBER_DIGITS", "MAX_RUN_SCANS", "MAX_TOTAL_EXPR_CHARS", "MAX_VARIABLES",
    "MAX_YAML_DEPTH", "MAX_YAML_NODES",
    "MIN_SCAN_PERIOD_US", "NOTICE_RUN_SCANS", "describe_bytes",
]


def describe_bytes(count: int) -> str:
    """4 MiB, 200 KiB, 12 bytes: the way a limit on sizes is written in messages."""
    for unit, size in (("MiB", 1024 * 1024), ("KiB", 1024)):
        if count >= size:
            value = count / size
            return f"{value:.0f} {unit}" if value == int(value) else f"{value:.1f} {unit}"
    return f"{count} bytes"

"""The order of a scan's parts, declared once.

Why here: the engine's scan program (hmi.engine.compiled.ScanProgram: which parts each
mode's function runs, in this order), the engine's two ways of running a scan
(Engine._cycle, and the printed frame of hmi.engine.compiled.auto_frame) and the PLC program
of the export (hmi.export.program_pou: which function block it calls, in this order) are
all walks of this tuple, so a part moved here moves in each. What runs between the
program's parts in the engine (the input scan, the filter, the output scan) is named too.
A stage added beyond the built-in ones declares its own part and where it runs
(hmi.engine.program_stages): :func:`placed` puts it there, for the engine and the PLC.
"""

from __future__ import annotations

from collections.abc import Iterable

INPUTS = "inputs"  # 1. the input scan
MEMORY = "memory"  # 2. timers, observers
STEP_TIMES = "step_times"  # 2. the GRAFCET's step times (the control law's)
DIAGNOSERS = "diagnosers"  # 3. the local diagnosers (and the High Level Diagnoser)
RECONSTRUCTION = "reconstruction"  # 4. the filtered sensors
RECOVERIES_NEEDED = "recoveries_needed"  # which recovery procedures the cell needs
LAW = "law"  # 5. the control law (in recovery mode: the running procedure)
FILTER = "filter"  # 6. the safety filter
OUTPUTS = "outputs"  # 7. the output scan
MONITORS = "monitors"  # 8. the stopwatch monitors, on the I/O just exchanged

SCAN = (INPUTS, MEMORY, STEP_TIMES, DIAGNOSERS, RECONSTRUCTION, RECOVERIES_NEEDED, LAW,
        FILTER, OUTPUTS, MONITORS)
# The parts of the scan program's function for a mode (stages 2 to 5): the rest of SCAN is
# the engine's own (stage 1, 6, 7) or a function of its own (the monitors).
PROGRAM = (MEMORY, STEP_TIMES, DIAGNOSERS, RECONSTRUCTION, RECOVERIES_NEEDED, LAW)
# The engine's part that calls the mode's function (the parts of PROGRAM, at once)
MODE_PROGRAM = "program"


def _engine_parts() -> tuple[str, ...]:
    parts: list[str] = []
    for part in SCAN:
        name = MODE_PROGRAM if part in PROGRAM else part
        if name not in parts:
            parts.append(name)
    return tuple(parts)


# SCAN as the engine runs it: the parts of PROGRAM one call, where the first of them stands
ENGINE = _engine_parts()
# Before the output scan, a part may fail (inputs unknown, an internal error): the outputs go
# safe; from the output scan on, the parts run whatever happened before them.
GUARDED = ENGINE[:ENGINE.index(OUTPUTS)]
EXCHANGED = ENGINE[ENGINE.index(OUTPUTS):]


def placed(base: tuple[str, ...], added: Iterable[tuple[str, str]]) -> tuple[str, ...]:
    """`base` with each added part, given as (part, the part it runs after), right after
    that part (several after one part: in the order given). How a stage beyond the built-in
    ones takes its place (hmi.engine.program_stages): the engine's program and the PLC's
    both walk the result."""
    parts = list(base)
    last: dict[str, str] = {}  # the part added last after each part
    for part, after in added:
        if part in parts:
            raise ValueError(f"{part!r} is a part of the scan already")
        if after not in parts:
            raise ValueError(f"{part!r} runs after {after!r}, not a part of {base}")
        parts.insert(parts.index(last.get(after, after)) + 1, part)
        last[after] = part
    return tuple(parts)

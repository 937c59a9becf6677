"""The order of a scan's parts, declared once.

Why here: the engine's scan program (hmi.engine.compiled.ScanProgram: which parts each
mode's function runs, in this order) and the PLC program of the export
(hmi.export.program_pou: which function block it calls, in this order) are both walks of
this tuple, so a part moved here moves in both. What runs between them in the engine (the
input scan, the filter, the output scan) is named too: the export's walk places its blocks
by it, the engine's frame (hmi.engine.compiled.auto_frame) and Engine._cycle call them where
a part says.
"""

from __future__ import annotations

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

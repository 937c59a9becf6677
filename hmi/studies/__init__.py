"""Offline studies of a project, and their reports: they run the engine (or reason over the
project) outside a live session, to say what the cell does over every fault, instant or
interruption. The closed loop explored exhaustively (explore, loopstate, closed_loop,
untimed, loop_sweep, sweep_report), the fault campaign (campaign), the diagnosers'
diagnosability (diagnosability, diag_report), the stopwatch monitors against a watchdog
(monitor_sweep, monitor_report), the constraint set's offline checks (filter_analysis).
Nothing that runs a scan imports them."""

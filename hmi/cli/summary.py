"""What a headless run prints at its end besides the run summary (hmi/session/run_report.py): the
alarms raised (and their explanations with --explain), and what a Modbus plant saw."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the report's model, imported by the commands that run
    from hmi.plant.base import PlantStatus
    from hmi.plant.modbus.client import ModbusPlant
    from hmi.session.run_report import RunCollector


def alarm_summary(collector: RunCollector, explain: bool) -> str:
    from hmi.timefmt import seconds as secs
    if not collector.alarm_events:
        return "Alarms: none"
    raised = [e for e in collector.alarm_events if e.event in ("raised", "returned")]
    lines = [f"Alarms: {len(raised)} raised or returned, "
             f"{sum(1 for e in collector.alarm_events if e.event == 'chattering')} chattering"]
    shown = 0
    for event in collector.alarm_events:
        if event.event not in ("raised", "chattering") or shown >= 20:
            continue
        shown += 1
        what = "CHATTERING " if event.event == "chattering" else ""
        lines.append(f"  {secs(event.time_us)} s  [{event.severity}] {what}{event.text}")
    if explain:
        for key, explanation in collector.explanations.items():
            lines.append("")
            lines.append(f"Explanation of {key} (as last shown, since "
                         f"{secs(explanation.since_us)} s):")
            lines.append(explanation.render(4))
            if explanation.recommended:
                lines.append(f"  Recommended: {explanation.recommended.label}")
    return "\n".join(lines)


def plant_report(plant: ModbusPlant, at_end: PlantStatus, overruns: int) -> str:
    """What a run against a Modbus plant saw of it: the link as it was when the run ended
    (`at_end`), and every request sent, the stop's included."""
    d = plant.status.details
    stop = f", of which {d['stop_writes']} at stop" if d["stop_writes"] else ""
    lines = [f"Plant {at_end.description}: "
             f"{'connected' if at_end.connected else 'NOT CONNECTED'} ({at_end.message})",
             f"  requests {d['requests']} (reads {d['reads']}, writes {d['writes']}{stop}), "
             f"exception responses {d['exceptions']}, timeouts {d['timeouts']}, "
             f"invalid answers {d['invalid']}, connections lost {d['losses']}, "
             f"connections made {d['connects']}"]
    io = plant.io_percentiles()
    if io:
        lines.append(f"  Modbus I/O per scan: p50 {io[0] / 1000:.2f} ms, p99 {io[1] / 1000:.2f} "
                     f"ms, max {d['max_io_ms']:.2f} ms; scans slower than the period "
                     f"{d['slow_scans']}; scan overruns {overruns}")
    return "\n".join(lines)

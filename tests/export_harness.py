"""Run the engine and the exported PLC code side by side, scan by scan, and compare.

The engine runs on its simulated plant; the exported Structured Text runs in the test's own
interpreter (tests/stsubset.py) on the same input image, the same program outputs (FOV) and
the same clock, with the engine's policy and diagnosis mode, and a fault reset after the same
scans. Every scan, everything the safety layer computes must be equal: the outputs written,
the violation word, the latch, the timers and observers, the partition flags and filtered
sensors, each diagnoser's state and labels, each monitor's location, stopwatches, counters
and latched evidence.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from operator import itemgetter

from hmi.engine.commands import FaultReset
from hmi.engine.scan import Engine
from hmi.export.build import build
from hmi.export.st import write_st
from hmi.plant.sim import Injection, SimPlant, parse_injection
from hmi.project.model import Project
from hmi.project.monitors import monitors_of
from tests.stsubset import Instance, Program, Runtime

POLICIES = {"monitor": 0, "block": 1, "correct": 2}
MODES = {"ftc": 0, "observe": 1, "off": 2}
LOCATIONS = {"waiting": 0, "executing": 1, "interrupted": 2, "faulty": 3}
RULES = {"cannot_finish": 1, "deadline": 2, "overrun": 3, "late_end": 4, "too_fast": 5}
MONITOR_PORTS = ("Location", "X", "Y", "Attempt", "Faults", "Completed", "Fault", "Rule",
                 "FaultX", "FaultY")


@dataclass
class Agreement:
    """What one side-by-side run covered, so a test can show it exercised something."""

    scans: int = 0
    violations: int = 0  # scans with a violation
    corrected: int = 0  # scans whose written vector differs from the FOV
    latched: int = 0
    fallbacks: int = 0  # scans the corrector found no safe vector (the safe state written)
    diagnoser_states: set[str] = field(default_factory=set)
    monitor_faults: int = 0
    resets: int = 0
    tested: int = 0  # most vectors the exported corrector tested in one scan

    def add(self, other: Agreement) -> None:
        for name in ("scans", "violations", "corrected", "latched", "fallbacks",
                     "monitor_faults", "resets"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.diagnoser_states |= other.diagnoser_states
        self.tested = max(self.tested, other.tested)


class Twin:
    """The exported program of a project, loaded once, run beside engines."""

    def __init__(self, project: Project, text: str | None = None):
        self.project = project
        model = build(project)
        self.text = text if text is not None else write_st(model)
        self.program = Program(self.text)
        # Which identifier holds which project value (IEC names are case-insensitive).
        self.sym = {k: v.upper() for k, v in model.symbols.items()}
        self.fov: tuple[bool, ...] = ()
        self.fov_names = [self.sym[f"FOV_{v.name}"] for v in project.outputs]
        control = next(p.name for p in model.pous if p.name.endswith("_Control"))
        self.program.set_native(control.upper(), self._control)

    def _control(self, inst: Instance, globals_: dict) -> None:
        """The functional control's stand-in: the engine's FOV of this scan."""
        for name, value in zip(self.fov_names, self.fov, strict=True):
            globals_[name] = value

    def run(self, engine: Engine, until_us: int | None = None, resets_after: Iterable[int] = (),
            times: Iterable[int] | None = None,
            before: Callable[[int, Engine], None] | None = None,
            codes: dict[str, int] | None = None) -> Agreement:
        """Step `engine` and the exported code beside it; assert every scan.

        Scans at every period up to `until_us`, or at `times`. `before(scan, engine)` runs
        before each scan (operator commands, inputs set on the simulated plant); a fault
        reset follows each scan of `resets_after`, on both sides. `codes` overrides the
        values written to FilterPolicy and DiagnosisMode (to try values the engine has no
        name for).
        """
        codes = codes or {}
        project, sym = self.project, self.sym
        rt = Runtime(self.program)
        rt.set(sym["FilterPolicy"], POLICIES[engine.policy])
        stage = engine.diagnosis
        rt.set(sym["DiagnosisMode"], codes.get("DiagnosisMode",
                                               MODES[stage.mode if stage is not None
                                                     else "ftc"]))
        lay = engine.layout
        slots = lay.slots
        inputs = [(sym[n], slots[n]) for n in lay.inputs]
        # Every output, timer, observer, flag and filtered sensor: read as one tuple on each
        # side (one C call each, not a Python call per name), compared name by name only
        # when the tuples differ, to say which.
        value_names = [n for n, k in zip(lay.names, lay.kinds, strict=True)
                       if k in ("output", "timer", "observer", "flag", "filtered")]
        read_values = rt.reader([sym[n] for n in value_names]) if value_names else tuple
        image_values = (itemgetter(*(slots[n] for n in value_names)) if len(value_names) > 1
                        else lambda image: tuple(image[slots[n]] for n in value_names))
        constraints = [c.name for c in project.constraints]
        violations = rt.getter(sym["Violations"])
        latch = rt.getter(sym["FilterLatched"])
        fallback = rt.getter(sym["FilterFallback"])
        tested = rt.getter(f"Safety.{sym['Filter']}.Tested")
        runtimes = stage.runtimes if stage is not None else []
        diagnosers = [(r, rt.getter(f"Safety.{sym['Diag_' + r.spec.name]}.State"),
                       [(lab, rt.getter(f"Safety.{sym['Diag_' + r.spec.name]}."
                                        f"{sym[r.spec.name + '.' + lab]}"))
                        for lab in r.spec.labels]) for r in runtimes]
        monitor_specs = monitors_of(project)
        monitors = [(rt.reader([f"Safety.{sym['Mon_' + t.name]}.{port}"
                                for port in MONITOR_PORTS]), rt.getter(sym[t.label]))
                    for t in monitor_specs]
        mstage = engine.monitors
        automata = mstage.automata if mstage is not None else []
        resets = set(resets_after)
        result = Agreement()
        if times is None:
            assert until_us is not None
            times = range(0, until_us + 1, project.scan_period_us)
        policy = sym["FilterPolicy"]
        for now in times:
            if before is not None:
                before(engine.scan + 1, engine)
            rt.globals[policy] = codes.get("FilterPolicy", POLICIES[engine.policy])
            snap = engine.step(now)
            image = snap.values
            for ident, slot in inputs:
                rt.globals[ident] = image[slot]
            self.fov = snap.fov
            reset = snap.scan in resets
            if reset:
                rt.set(sym["FaultReset"], True)
            rt.scan(now)
            where = f"scan {snap.scan} (t = {now} us)"
            mine_values, engine_values = read_values(), image_values(image)
            if mine_values != engine_values:
                for name, mine_value, value in zip(value_names, mine_values, engine_values,
                                                   strict=True):
                    assert mine_value == value, f"{where}: {name} = {mine_value}, engine {value}"
            report = snap.filter
            violated = set(report.violated_names) if report is not None else set()
            word = violations()
            mine = {c for j, c in enumerate(constraints) if word >> j & 1}
            assert mine == violated, f"{where}: violations {sorted(mine)} != {sorted(violated)}"
            latched = any(r.source == "filter" for r in snap.latched)
            assert latch() == latched, f"{where}: latch {latch()}"
            fell_back = report is not None and report.fallback is not None
            assert fallback() == fell_back, f"{where}: fallback {fallback()} ({report})"
            if reset:  # between scans, as an operator's command: the PLC did it at its end
                engine.apply(FaultReset())
                result.resets += 1
            # States and latches are compared after a reset on both sides; labels, flags and
            # the stopwatches only move at the next scan, on both sides.
            for state, (runtime, number, labels) in zip(snap.diagnosers, diagnosers,
                                                        strict=True):
                got, want = runtime.names[number()], runtime.names[runtime.current]
                assert got == want, f"{where}: {state.name} in {got}, not {want}"
                mine_labels = {lab for lab, get in labels if get()}
                assert mine_labels == set(state.labels), f"{where}: labels of {state.name}"
                result.diagnoser_states.add(f"{state.name}.{state.state}")
            for spec, (ports, label), a in zip(monitor_specs, monitors, automata,
                                               strict=True):
                got = ports()
                d = a.latched
                evidence = (RULES[d.rule], d.x_us, d.y_us) if d is not None else got[7:]
                want = (LOCATIONS[a.location], a.x_us, a.y_us, a.attempt, a.faults,
                        a.completed, d is not None, *evidence)
                assert got == want, f"{where}: monitor {spec.name} {got} != {want}"
                if not reset:
                    assert label() == (d is not None), f"{where}: global {spec.label}"
                result.monitor_faults += d is not None
            result.scans += 1
            result.violations += bool(violated)
            result.corrected += snap.outputs != snap.fov
            result.latched += latched
            result.fallbacks += fell_back
            result.tested = max(result.tested, tested())
        return result


def engine_for(project: Project, inject: Iterable[str | Injection] = (),
               policy: str | None = None, control: str | None = None,
               diagnosis: str = "ftc") -> Engine:
    plant = SimPlant(project)
    for item in inject:
        plant.inject(parse_injection(item) if isinstance(item, str) else item)
    return Engine(project, plant, control=control, policy=policy, diagnosis=diagnosis)

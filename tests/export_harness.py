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
from concurrent.futures import Executor
from dataclasses import dataclass, field
from operator import itemgetter

from hmi.engine.commands import FaultReset
from hmi.engine.scan import Engine
from hmi.export.build import build
from hmi.export.st import write_st
from hmi.plant.sim import Injection, SimPlant, parse_injection
from hmi.project.campaign import campaign_of
from hmi.project.diagnosers import diagnosers_of, layout_names
from hmi.project.loader import load_project
from hmi.project.model import Project
from hmi.project.monitors import monitors_of
from hmi.project.scenarios import scenarios_of
from hmi.studies.campaign import CONFIGS
from tests.conftest import PROJECTS
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
    """The exported program of a project, loaded once, run beside engines: its control law
    `control` (the project's default: None) exported too, its FOV compared with the engine's;
    or, `engine_fov`, the engine's FOV given to the program in place of its control (manual
    mode: the operator's requests are the FOV)."""

    def __init__(self, project: Project, text: str | None = None, control: str | None = None,
                 engine_fov: bool = False):
        self.project = project
        self.control_name = control or project.default_control
        model = build(project, control)
        self.text = text if text is not None else write_st(model)
        self.program = Program(self.text)
        # Which identifier holds which project value (IEC names are case-insensitive).
        self.sym = {k: v.upper() for k, v in model.symbols.items()}
        self.fov: tuple[bool, ...] = ()
        self.fov_names = [self.sym[f"FOV_{v.name}"] for v in project.outputs]
        self.engine_fov = engine_fov
        self.runtime = Runtime  # (tests/st_mutants.py records what it is given and holds)
        if engine_fov:
            control_pou = next(p.name for p in model.pous if p.name.endswith("_Control"))
            self.program.set_native(control_pou.upper(), self._control)

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
        assert self.engine_fov or engine.control_name == self.control_name, (
            f"the engine runs law {engine.control_name}, the export {self.control_name}")
        rt = self.runtime(self.program)
        read_fov = rt.reader(self.fov_names)
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
            if not self.engine_fov:
                mine_fov = read_fov()
                assert mine_fov == snap.fov, f"{where}: FOV {mine_fov}, engine {snap.fov}"
            report = snap.filter_report
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


LONG_US = 30_000_000  # the faulty programs' runs
# A campaign run is compared up to this long after its fault, not to the campaign's end: on
# the valve's 48 runs, the last new situation (every Boolean of the image, the violations,
# the latch, each diagnoser's state and labels) appears at most 10.8 s after the fault
# (measured on the engine over the whole 40 s runs), so the rest of a run repeats situations
# already compared; the margin is 4 s. It cuts the valve's campaign scans by about a third.
AFTER_FAULT_US = 15_000_000

# One recorded run: project, injections, length, policy, diagnosis mode, control law.
TraceRun = tuple[str, tuple[Injection, ...], int, str | None, str, str | None]


def export_traces(name: str, faulty_policies: tuple[str, ...] = ("correct", "block", "monitor"),
                  scenarios: tuple[str, ...] | None = None, campaign: bool = True
                  ) -> list[TraceRun]:
    """The runs of one example project the export is compared on: its fault campaign (each
    fault under the three configurations), its scenarios, its faulty program per policy."""
    project = load_project(PROJECTS / name)
    runs: list[TraceRun] = []
    spec = campaign_of(project)
    if spec is not None and campaign:
        for s in spec.scenarios:
            for c in CONFIGS:
                runs.append((name, (Injection(s.fault, s.at_us, s.device),),
                             min(spec.length_us, s.at_us + AFTER_FAULT_US), c.policy,
                             c.diagnosis, None))
    for s in scenarios_of(project):
        if scenarios is None or s.name in scenarios:
            runs.append((name, s.injections, s.duration_us or LONG_US, None, "ftc", None))
    if "faulty" in project.controls:
        runs += [(name, (), LONG_US, policy, "ftc", "faulty") for policy in faulty_policies]
    return runs


_TWINS: dict[tuple[type, str, str | None], Twin | MatiecTwin] = {}


def run_trace(kind: type[Twin] | type[MatiecTwin], name: str,
              injections: tuple[Injection, ...], until_us: int, policy: str | None,
              diagnosis: str, control: str | None) -> Agreement:
    """One trace, in a worker: the engine and the export (`kind`: interpreted by
    tests/stsubset.py, or compiled by matiec) on the same scans; asserts inside."""
    twin = _TWINS.get((kind, name, control))
    if twin is None:
        twin = _TWINS[kind, name, control] = kind(load_project(PROJECTS / name),
                                                  control=control)
    engine = engine_for(twin.project, injections, policy=policy, control=control,
                        diagnosis=diagnosis)
    return twin.run(engine, until_us)


def agree_on(pool: Executor, runs: list[TraceRun], kind: type[Twin] | type[MatiecTwin]
             ) -> Agreement:
    """`runs` spread over `pool`'s workers, their coverage added up."""
    futures = [pool.submit(run_trace, kind, *run) for run in runs]
    total = Agreement()
    for future in futures:
        total.add(future.result())  # an AssertionError names the scans that disagreed
    return total


def shorter_ton1(valve_text: str) -> str:
    """The valve's export with TON1's preset 1.1 s instead of 2.45 s: a wrong program whose
    first difference from the engine is known (TON1 true at t = 1.1 s of an opening)."""
    # (TON1 is the memory's first timer: the first comparison with its preset)
    tampered = valve_text.replace("L_q := (Now - L_s) >= T#2s450ms;",
                                  "L_q := (Now - L_s) >= T#1s100ms;", 1)
    assert tampered != valve_text
    return tampered


def engine_for(project: Project, inject: Iterable[str | Injection] = (),
               policy: str | None = None, control: str | None = None,
               diagnosis: str = "ftc") -> Engine:
    plant = SimPlant(project)
    for item in inject:
        plant.inject(parse_injection(item) if isinstance(item, str) else item)
    return Engine(project, plant, control=control, policy=policy, diagnosis=diagnosis)


class MatiecTwin:
    """The exported program of a project compiled by matiec (tests/matiec.py), run beside
    engines: the engine's scans are recorded (inputs, FOV, policy, diagnosis mode, fault
    resets, and everything the safety layer computed), then the compiled program runs on the
    recorded writes, and each scan's values are compared. The same comparisons as
    :meth:`Twin.run`; `mismatches` lists every scan that differs, not only the first."""

    def __init__(self, project: Project, text: str | None = None, control: str | None = None):
        from tests.matiec import CompiledPlc  # (needs matiec: tests skip without it)

        self.project = project
        self.control_name = control or project.default_control
        model = build(project, control)
        sym = self.sym = {k: v.upper() for k, v in model.symbols.items()}
        self.text = text if text is not None else write_st(model)
        self.fov_names = [sym[f"FOV_{v.name}"] for v in project.outputs]
        lay_inputs = [v.name for v in project.inputs]
        self.input_names = lay_inputs
        # what Twin.run compares too: outputs, timers, observers, flags, filtered sensors
        self.value_names = ([v.name for v in project.outputs]
                            + [t.name for t in project.timers]
                            + [o.name for o in project.observers]
                            + [name for name, _ in layout_names(project)])
        self.diagnosers = [(d.name, [f"SAFETY.{sym['Diag_' + d.name]}.{sym[d.name + '.' + lab]}"
                                     for lab in d.labels])
                           for d in diagnosers_of(project)]
        self.monitor_specs = monitors_of(project)
        writes = ([sym[n] for n in lay_inputs]
                  + [sym["FaultReset"], sym["FilterPolicy"], sym["DiagnosisMode"]])
        reads = ([sym[n] for n in self.value_names]
                 + [sym["Violations"], sym["FilterLatched"], sym["FilterFallback"],
                    f"SAFETY.{sym['Filter']}.Tested", *self.fov_names])
        for name, labels in self.diagnosers:
            reads += [f"SAFETY.{sym['Diag_' + name]}.State", *labels]
        for t in self.monitor_specs:
            reads += [f"SAFETY.{sym['Mon_' + t.name]}.{port}" for port in MONITOR_PORTS]
            reads.append(sym[t.label])
        self.plc = CompiledPlc(self.text, writes, reads)

    def run(self, engine: Engine, until_us: int, resets_after: Iterable[int] = ()) -> Agreement:
        """Step `engine` every period up to `until_us`, run the compiled program on the same
        writes, compare. Raises an AssertionError naming the mismatches (all counted)."""
        assert engine.control_name == self.control_name, (
            f"the engine runs law {engine.control_name}, the export {self.control_name}")
        rows, expected, result = self.record(engine, until_us, resets_after)
        got = self.plc.run(rows)
        mismatches = self.compare(rows, expected, got)
        result.tested = max((row[self._tested] for row in got), default=0)
        assert not mismatches, (f"{len(mismatches)} of {len(rows)} scans differ; the first: "
                                + "; ".join(mismatches[:5]))
        return result

    @property
    def _tested(self) -> int:
        return len(self.value_names) + 3

    def record(self, engine: Engine, until_us: int, resets_after: Iterable[int] = ()
               ) -> tuple[list[tuple[int, ...]], list[tuple[int | None, ...]], Agreement]:
        """The engine's run: what the PLC is given before each scan, and what it must hold
        after it (None: not compared at that scan)."""
        project = self.project
        lay = engine.layout
        slots = lay.slots
        input_slots = itemgetter(*(slots[n] for n in self.input_names))
        value_slots = [slots[n] for n in self.value_names]
        constraints = [c.name for c in project.constraints]
        stage = engine.diagnosis
        mode = MODES[stage.mode if stage is not None else "ftc"]
        runtimes = stage.runtimes if stage is not None else []
        mstage = engine.monitors
        automata = mstage.automata if mstage is not None else []
        resets = set(resets_after)
        rows: list[tuple[int, ...]] = []
        expected: list[tuple[int | None, ...]] = []
        result = Agreement()
        for now in range(0, until_us + 1, project.scan_period_us):
            policy = POLICIES[engine.policy]
            snap = engine.step(now)
            image = snap.values
            reset = snap.scan in resets
            inputs = input_slots(image)
            rows.append((now, *(inputs if isinstance(inputs, tuple) else (inputs,)),
                         reset, policy, mode))
            report = snap.filter_report
            violated = set(report.violated_names) if report is not None else set()
            word = sum(1 << j for j, c in enumerate(constraints) if c in violated)
            latched = any(r.source == "filter" for r in snap.latched)
            fell_back = report is not None and report.fallback is not None
            want: list[int | None] = [int(image[s]) for s in value_slots]
            want += [word, latched, fell_back, None, *snap.fov]
            if reset:
                engine.apply(FaultReset())
                result.resets += 1
            for runtime in runtimes:
                want.append(runtime.current)
                held = runtime.labels  # (the decision: the High Level Diagnoser's if refined)
                want += [lab in held for lab in runtime.spec.labels]
                result.diagnoser_states.add(f"{runtime.spec.name}.{runtime.names[runtime.current]}")
            for a in automata:
                d = a.latched
                evidence = ((RULES[d.rule], d.x_us, d.y_us) if d is not None
                            else (None, None, None))
                want += [LOCATIONS[a.location], a.x_us, a.y_us, a.attempt, a.faults,
                         a.completed, d is not None, *evidence,
                         None if reset else d is not None]
                result.monitor_faults += d is not None
            expected.append(tuple(None if w is None else int(w) for w in want))
            result.scans += 1
            result.violations += bool(violated)
            result.corrected += snap.outputs != snap.fov
            result.latched += latched
            result.fallbacks += fell_back
        return rows, expected, result

    def compare(self, rows: list[tuple[int, ...]], expected: list[tuple[int | None, ...]],
                got: list[tuple[int, ...]]) -> list[str]:
        """Every scan whose compiled values differ from the engine's, named."""
        names = self._read_names()
        out = []
        for k, (row, want, have) in enumerate(zip(rows, expected, got, strict=True)):
            if len(want) != len(have):
                out.append(f"scan {k + 1}: {len(have)} values read, {len(want)} expected")
                continue
            wrong = [f"{names[j]} = {h}, engine {w}" for j, (w, h) in
                     enumerate(zip(want, have, strict=True)) if w is not None and w != h]
            if wrong:
                out.append(f"scan {k + 1} (t = {row[0]} us): " + ", ".join(wrong))
        return out

    def _read_names(self) -> list[str]:
        return list(self.plc.reads)

"""Mutation testing of the exported Structured Text: is every single-operator change to the
exported code caught by the agreement with the engine on the recorded traces?

A mutant is the exported text with one token changed in a POU's body (declarations and the
CONFIGURATION are left alone): AND<->OR, XOR->OR, NOT dropped, < <-> <=, > <-> >=, = <-> <>,
+ <-> -, TRUE <-> FALSE, an integer literal moved by one (0 -> 1, n -> n - 1), a TIME literal
one millisecond longer. Each mutant is loaded by the tests' interpreter (tests/stsubset.py):

* *stillborn*: it does not load (a type error a PLC compiler would refuse too, a CASE label
  twice): not a program, so neither caught nor survived, counted apart;
* *caught*: replayed on the engine's recorded traces, some scan's compared values differ from
  the engine's (or it stops with a run-time error: an index out of bounds, an overflow);
* *survived*: it agreed with the engine on every scan of every trace.

The traces are recorded once per project by running the engine beside the exported program
(tests/export_harness.py, Twin: it asserts they agree scan by scan), keeping what the Twin
writes before each scan (inputs, fault reset, policy, diagnosis mode) and what it compares
after it (outputs, FOV, violation word, latch, fallback, timers, observers, flags, filtered
sensors, each diagnoser's state and labels, each monitor's ports and label). A mutant is
replayed on those writes alone and compared with the same values (with the Twin's two
exceptions: a monitor's evidence only while it holds a fault, its global label not at a
reset's scan). The survivors are judged by tests/mutant_study.py, whose `python -m
tests.mutant_study PROJECT...` prints the figures.
"""

from __future__ import annotations

import random
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from hmi.engine.commands import ManualOutput, SetMode, SetPolicy
from hmi.engine.scan import Engine
from hmi.export.build import build
from hmi.export.st import write_st
from hmi.plant.base import Plant, PlantStatus
from hmi.project.diagnosers import diagnosers_of, layout_names
from hmi.project.loader import load_project
from hmi.project.model import Project
from hmi.project.monitors import monitors_of
from tests import stsubset
from tests.conftest import PROJECTS
from tests.export_harness import MONITOR_PORTS, TraceRun, Twin, engine_for
from tests.stsubset import TOKEN, Instance, Program, Runtime, StError, parse_int, parse_time

SWAPS = {"AND": "OR", "OR": "AND", "XOR": "OR", "<": "<=", "<=": "<", ">": ">=", ">=": ">",
         "=": "<>", "<>": "=", "+": "-", "-": "+", "TRUE": "FALSE", "FALSE": "TRUE"}
POU_START = re.compile(r"FUNCTION_BLOCK|PROGRAM|FUNCTION", re.IGNORECASE)
POU_END = re.compile(r"END_FUNCTION_BLOCK|END_PROGRAM|END_FUNCTION", re.IGNORECASE)
VAR_START = re.compile(r"VAR(_INPUT|_OUTPUT|_IN_OUT|_EXTERNAL|_GLOBAL|_TEMP)?", re.IGNORECASE)


@dataclass(frozen=True)
class Mutant:
    """One token of the text replaced: at `start`, `old` becomes `new` (`new` empty: dropped,
    with the space after it)."""

    start: int
    old: str
    new: str
    line: int
    pou: str
    source: str = ""  # the mutated line, as exported (stripped)

    def key(self) -> str:
        """What names the mutant across exports that only moved lines: its POU, its line's
        text and the change."""
        return f"{self.pou}: {self.source} [{self.old} -> {self.new or '(dropped)'}]"

    def apply(self, text: str) -> str:
        end = self.start + len(self.old)
        if not self.new and text[end:end + 1] == " ":
            end += 1
        return text[:self.start] + self.new + text[end:]

    def describe(self) -> str:
        return f"{self.pou} line {self.line}: {self.old} -> {self.new or '(dropped)'}"


def _time_plus_1ms(literal: str) -> str:
    return f"T#{parse_time(literal) // 1000 + 1}ms"


def _int_moved(literal: str) -> str:
    """An integer literal (plain or typed, e.g. WORD#16#0004) moved by one."""
    prefix, _, digits = literal.rpartition("#") if "#" in literal else ("", "", literal)
    if prefix.upper().endswith("16") or prefix.upper().endswith("2"):
        head, _, _base = prefix.rpartition("#")
        value = parse_int(literal[len(head) + 1 if head else 0:])
        moved = 1 if value == 0 else value - 1
        return f"{head}#{moved}" if head else str(moved)
    value = int(digits.replace("_", ""))
    moved = 1 if value == 0 else value - 1
    return f"{prefix}#{moved}" if prefix else str(moved)


def mutants(text: str) -> list[Mutant]:
    """Every single-operator mutant of the POU bodies of `text`, in file order."""
    out: list[Mutant] = []
    pou, in_vars, in_body, in_config = "", False, False, False
    line, pos = 1, 0
    by = False  # after BY (and its sign): a FOR's step
    while pos < len(text):
        match = TOKEN.match(text, pos)
        if match is None:
            raise StError(f"line {line}: unexpected character {text[pos]!r}")
        kind, value = match.lastgroup or "", match.group()
        upper = value.upper()
        if kind == "ident" and POU_END.fullmatch(upper):
            in_body = False
        elif kind == "ident" and POU_START.fullmatch(upper) and not in_config:
            name = re.compile(r"\s*(\w+)").match(text, match.end())
            pou = name.group(1) if name is not None else "?"
            in_body = True
        elif kind == "ident" and upper == "CONFIGURATION":
            in_body, in_config = False, True
        elif in_body and kind == "ident" and VAR_START.fullmatch(upper):
            in_vars = True
        elif in_body and kind == "ident" and upper == "END_VAR":
            in_vars = False
        elif in_body and not in_vars and kind not in ("ws", "comment"):
            new = None
            if kind in ("ident", "op") and upper in SWAPS:
                new = SWAPS[upper]
            elif kind == "ident" and upper == "NOT":
                new = ""
            elif kind == "int" and by:
                new = str(parse_int(value) + 1)  # a FOR's step: 0 would loop for ever
            elif kind in ("int", "typed"):
                new = _int_moved(value)
            elif kind == "time":
                new = _time_plus_1ms(value)
            if new is not None:
                start = text.rfind("\n", 0, match.start()) + 1
                end = text.find("\n", match.start())
                out.append(Mutant(match.start(), value, new, line, pou,
                                  text[start:end if end >= 0 else None].strip()))
        if kind not in ("ws", "comment"):
            by = upper == "BY" or (by and upper == "-")
        line += value.count("\n")
        pos = match.end()
    return out


# --------------------------------------------------------------------------------------------
# Recorded traces
# --------------------------------------------------------------------------------------------


@dataclass
class Trace:
    """One recorded run: before each scan, the time and the values written to the globals
    named by `Recording.writes`; after it, the compared values, and which of them not to
    compare at that scan (the Twin's exceptions)."""

    name: str
    scans: list[tuple[int, tuple]] = field(default_factory=list)
    values: list[tuple] = field(default_factory=list)
    skip: dict[int, frozenset[int]] = field(default_factory=dict)
    manual: bool = False  # the FOV given (the control law replaced): `fov`, one per scan
    fov: list[tuple[bool, ...]] = field(default_factory=list)


class Recording:
    """What a project's exported program is given and compared on, by name."""

    def __init__(self, project: Project, control: str | None = None):
        model = build(project, control)
        sym = {k: v.upper() for k, v in model.symbols.items()}
        self.text = write_st(model)
        self.writes = ([sym[v.name] for v in project.inputs]
                       + [sym["FilterPolicy"], sym["DiagnosisMode"], sym["FaultReset"]])
        values = ([v.name for v in project.outputs] + [t.name for t in project.timers]
                  + [o.name for o in project.observers]
                  + [name for name, _ in layout_names(project)])
        reads = [sym[n] for n in values] + [sym[f"FOV_{v.name}"] for v in project.outputs]
        reads += [sym["Violations"], sym["FilterLatched"], sym["FilterFallback"]]
        for d in diagnosers_of(project):
            block = f"Safety.{sym['Diag_' + d.name]}"
            reads += [f"{block}.State"] + [f"{block}.{sym[d.name + '.' + lab]}"
                                           for lab in d.labels]
        # each monitor: its ports, then its global label
        self.monitors: list[tuple[int, int]] = []  # (index of Fault, index of the label)
        for t in monitors_of(project):
            block = f"Safety.{sym['Mon_' + t.name]}"
            first = len(reads)
            reads += [f"{block}.{port}" for port in MONITOR_PORTS] + [sym[t.label]]
            self.monitors.append((first + MONITOR_PORTS.index("Fault"),
                                  first + len(MONITOR_PORTS)))
        self.reads = reads
        self.fov_names = [sym[f"FOV_{v.name}"] for v in project.outputs]
        self.control = next(p.name for p in model.pous if p.name.endswith("_Control")).upper()
        self.reset_index = len(self.writes) - 1

    def skipped(self, values: tuple, reset: bool) -> frozenset[int]:
        out: set[int] = set()
        for fault, label in self.monitors:
            if not values[fault]:
                out |= {fault + 1, fault + 2, fault + 3}  # Rule, FaultX, FaultY
            if reset:
                out.add(label)
        return frozenset(out)


def _places(rt: Runtime, paths: Sequence[str]) -> list[tuple[dict, str]]:
    return [rt._place(path) for path in paths]


class RandomPlant(Plant):
    """Inputs no physics drives: each input flips with probability `flip` at each read
    (seeded), so the exported program meets situations the simulated plant never shows (a
    sensor against its order, both ends of a travel at once), held long enough for its timers
    and diagnosers' windows to elapse. It ignores what is written."""

    kind: ClassVar[str] = "sim"

    def __init__(self, project: Project, seed: int, flip: float = 0.03):
        self.input_names = tuple(v.name for v in project.inputs)
        self.output_names = tuple(v.name for v in project.outputs)
        self._random = random.Random(seed)
        self._flip = flip
        self._values = {n: self._random.random() < 0.5 for n in self.input_names}

    def read(self, now_us: int) -> Mapping[str, bool]:
        for name in self.input_names:
            if self._random.random() < self._flip:
                self._values[name] = not self._values[name]
        return dict(self._values)

    def write(self, now_us: int, outputs: Mapping[str, bool]) -> None:
        return None

    def close(self) -> None:
        return None

    @property
    def status(self) -> PlantStatus:
        return PlantStatus("sim", "random inputs")


@dataclass(frozen=True)
class RandomRun:
    """A run on a RandomPlant: seeded random inputs, a policy switch and a fault reset now and
    then; `manual`: the operator's random requests are the FOV (manual mode, still filtered:
    the corrector meets vectors no control law writes), the exported control law replaced by
    them on both sides."""

    seed: int
    scans: int = 3000
    manual: bool = False
    flip: float = 0.03  # each input's chance to change at a scan

    def __str__(self) -> str:
        return (f"random {'manual' if self.manual else 'auto'} seed {self.seed}"
                + (f" flip {self.flip}" if self.flip != 0.03 else ""))


Run = TraceRun | RandomRun
POLICY_NAMES = ("monitor", "block", "correct")


def _random_engine(project: Project, run: RandomRun) -> tuple[Engine, Callable, set[int]]:
    rnd = random.Random(run.seed * 7919 + 1)
    engine = Engine(project, RandomPlant(project, run.seed, run.flip), policy="correct")
    outputs = [v.name for v in project.outputs]
    switches = {k: rnd.choice(POLICY_NAMES) for k in range(2, run.scans) if rnd.random() < 0.004}
    resets = {k for k in range(2, run.scans) if rnd.random() < 0.01}
    requests = [[rnd.random() < 0.5 for _ in outputs] for _ in range(run.scans + 1)]

    def before(scan: int, engine: Engine) -> None:
        if run.manual and scan == 1:
            engine.apply(SetMode(manual=True))
        if scan in switches:
            engine.apply(SetPolicy(switches[scan]))
        if run.manual and scan <= run.scans and (scan == 1 or rnd.random() < 0.05):
            for name, value in zip(outputs, requests[scan], strict=True):
                engine.apply(ManualOutput(name, value))

    return engine, before, resets


def _recorder(rec: Recording, trace: Trace, twin: Twin) -> type[Runtime]:
    """A Runtime that keeps, in `trace`, what each scan was given and what it held."""
    writes, reads = rec.writes, rec.reads
    places: list[tuple[dict, str]] = []

    class Recorder(Runtime):
        def scan(self, now_us: int) -> None:
            g = self.globals
            if not places:
                places[:] = _places(self, reads)
            given = tuple(g[w] for w in writes)
            super().scan(now_us)
            values = tuple(d[k] for d, k in places)
            trace.scans.append((now_us, given))
            if trace.manual:
                trace.fov.append(twin.fov)
            trace.values.append(values)
            skip = rec.skipped(values, bool(given[rec.reset_index]))
            if skip:
                trace.skip[len(trace.values) - 1] = skip

    return Recorder


def record(name: str, runs: Iterable[Run]) -> tuple[Recording, list[Trace]]:
    """Run the engine beside the exported program on `runs` (asserting every scan agrees, as
    the agreement tests do) and keep what the program was given and what it held."""
    project = load_project(PROJECTS / name)
    rec = Recording(project)
    traces: list[Trace] = []
    for run in runs:
        manual = isinstance(run, RandomRun) and run.manual
        twin = Twin(project, engine_fov=manual)
        if isinstance(run, RandomRun):
            trace = Trace(str(run), manual=manual)
            engine, before, resets = _random_engine(project, run)
            until = (run.scans - 1) * project.scan_period_us
        else:
            _name, injections, until, policy, diagnosis, control = run
            assert control is None, "the default control law only"
            trace = Trace(f"{policy or 'project policy'}/{diagnosis}/"
                          + (",".join(str(i) for i in injections) or "no fault"))
            engine = engine_for(project, injections, policy=policy, diagnosis=diagnosis)
            before, resets = None, set()
        twin.runtime = _recorder(rec, trace, twin)
        twin.run(engine, until, resets_after=resets, before=before)
        traces.append(trace)
    return rec, traces


# --------------------------------------------------------------------------------------------
# Replay
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Verdict:
    mutant: Mutant
    outcome: str  # stillborn, caught, survived
    why: str = ""
    scans: int = 0  # scans replayed


# A WHILE of the exported code runs at most a few hundred times a scan (the corrector's
# k-subsets); a mutant that never leaves one is stopped after this many (the interpreter's own
# guard, 1,000,000, costs minutes per such mutant): a run-time error, so caught.
MUTANT_LOOPS = 20_000


def replay(rec: Recording, traces: Sequence[Trace], text: str) -> tuple[str | None, int]:
    """The first scan at which `text` disagrees with the recorded values (None: it agreed on
    every scan), and how many scans it ran. Raises StError if it does not load."""
    saved, stsubset.MAX_LOOPS = stsubset.MAX_LOOPS, MUTANT_LOOPS
    try:
        program = Program(text)  # (the guard is compiled into the code)
    finally:
        stsubset.MAX_LOOPS = saved
    ran = 0
    fov: list[tuple[bool, ...]] = [()]

    def given_fov(inst: Instance, g: dict) -> None:
        for name, value in zip(rec.fov_names, fov[0], strict=True):
            g[name] = value

    for trace in traces:
        if trace.manual:
            program.set_native(rec.control, given_fov)
        else:
            program.fbs[rec.control] = program.code[rec.control]
        rt = Runtime(program)
        g = rt.globals
        places = _places(rt, rec.reads)
        # what the Twin writes: the inputs and the policy at every scan, the diagnosis mode
        # once, a fault reset at its scans (the program clears FaultReset itself)
        every = rec.writes[:-2]
        mode, reset = rec.writes[-2], rec.writes[-1]
        g[mode] = trace.scans[0][1][-2] if trace.scans else g[mode]
        skip = trace.skip
        expected = trace.values
        for k, (now, given) in enumerate(trace.scans):
            for w, value in zip(every, given, strict=False):
                g[w] = value
            if given[-1]:
                g[reset] = True
            ran += 1
            if trace.manual:
                fov[0] = trace.fov[k]
            try:
                rt.scan(now)
            except (StError, ZeroDivisionError) as error:
                return f"{trace.name}, scan {k + 1}: run-time error {error}", ran
            values = tuple(d[key] for d, key in places)
            if values != expected[k]:
                ignored = skip.get(k, frozenset())
                wrong = [rec.reads[j] for j, (a, b) in enumerate(zip(values, expected[k],
                                                                     strict=True))
                         if a != b and j not in ignored]
                if wrong:
                    return f"{trace.name}, scan {k + 1} (t = {now} us): {', '.join(wrong[:3])}", ran
    return None, ran


def judge(rec: Recording, traces: Sequence[Trace], mutant: Mutant) -> Verdict:
    try:
        found, ran = replay(rec, traces, mutant.apply(rec.text))
    except StError as error:
        return Verdict(mutant, "stillborn", str(error))
    if found is None:
        return Verdict(mutant, "survived", scans=ran)
    return Verdict(mutant, "caught", found, ran)


def sample(items: Sequence[Mutant], k: int, seed: int) -> list[Mutant]:
    if k >= len(items):
        return list(items)
    return sorted(random.Random(seed).sample(list(items), k), key=lambda m: m.start)


# (the slow ones let a task run for seconds: a monitor's verdicts at their bounds)
RANDOM_RUNS = ([RandomRun(seed) for seed in (1, 2, 3)]
               + [RandomRun(seed, manual=True) for seed in (11, 12, 13)]
               + [RandomRun(4, 6000, flip=0.004), RandomRun(14, 6000, manual=True, flip=0.004)])


def study_runs(name: str) -> list[Run]:
    """The runs a project's mutants are judged on: its scenarios (the default control law:
    the faulty program's runs are another export) and the random runs."""
    from tests.export_harness import export_traces
    return [r for r in export_traces(name, campaign=False) if r[5] is None] + RANDOM_RUNS

"""The compiled scan: a project's stages as generated functions, built once per engine.

Why: the stage objects (hmi.engine.stages, diagnoser, control, grafcet, filter, monitors)
interpret the project at every scan: a closure per expression node, a loop per table. They
stay, as the reference interpreter, and as the owners of every piece of state. What is
compiled here is the same work written out flat (hmi.engine.codegen): for the automatic mode,

* ``core(v, h, now, scan)``: stage 2 (timers, observers, step times), stage 3's common case
  (which diagnoser has a transition to fire), stage 4 (reconstruction), which recovery
  procedures the cell may need, and stage 5 (GRAFCET evolution, continuous actions,
  equations); it returns the functional output vector;
* ``held(v, h, now, scan)``: the same in manual mode, where the program waits: neither the
  step times nor stage 5 (the engine takes the operator's requests); built the first time
  manual mode needs it, so an engine that never enters manual mode never generates it;
* ``violated(v, h, f)``: whether the candidate `f` violates any safety constraint (stage 6's
  first question: most scans violate none, and then the filter has nothing else to do);
* ``monitors(v, h, now, scan)``: the stopwatch monitors after the output scan; True when an
  automaton moved;
* ``elapsed(now)``: the timers' ET for the snapshot;
* ``active_bits(v, h)``: which constraints are active, the key of the corrector's memory.

Every function works on the stage objects' own state (a timer's ``since``, a diagnoser's
``current``, a GRAFCET's ``activated_at``) and hands the rare events to the stage's own
method: a diagnoser transition that fires is fired by ``DiagnoserRuntime.step``, a GRAFCET
firing by ``GrafcetRuntime.fire``, a violation by the filter itself. So the compiled scan and
the interpreted one are interchangeable scan by scan (``Engine(..., compiled=False)`` runs
the interpreter; tests/test_compiled_scan.py runs both on seeded random runs of every
project and compares them).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from hmi.engine.codegen import Source, build, expr_source, print_program
from hmi.engine.diagnoser import GAP_SCANS, DiagnoserRuntime, DiagnosisStage, shift_outputs
from hmi.engine.stopwatch import Phase
from hmi.logic.expr import History, Image, Node, Var

if TYPE_CHECKING:
    from hmi.engine.control import ControlRuntime
    from hmi.engine.filter import SafetyFilter
    from hmi.engine.layout import Layout
    from hmi.engine.monitors import MonitorStage
    from hmi.engine.recovery import RecoveryStage
    from hmi.engine.stages import Memory

CoreFn = Callable[[Image, History, int, int], tuple[bool, ...]]
HeldFn = Callable[[Image, History, int, int], None]
ViolatedFn = Callable[[Image, History, tuple[bool, ...]], bool]
MonitorFn = Callable[[Image, History, int, int], bool]
ElapsedFn = Callable[[int], tuple[int, ...]]
ActiveFn = Callable[[Image, History], int]


class CompiledScan:
    """The generated functions of one engine (see the module docstring)."""

    def __init__(self, layout: Layout, memory: Memory, control: ControlRuntime,
                 diagnosis: DiagnosisStage | None, recovery: RecoveryStage | None,
                 safety_filter: SafetyFilter, monitors: MonitorStage | None, label: str):
        self.slots = layout.slots
        self.times = layout.step_times
        self.label = label
        self.sources: list[str] = []  # every function's generated text, in build order
        self.core: CoreFn = self._core(layout, memory, control, diagnosis, recovery)
        self._parts = (layout, memory, control, diagnosis, recovery)  # (for `held`)
        self._held: HeldFn | None = None
        self.violated: ViolatedFn = self._violated(safety_filter)
        self.active_bits: ActiveFn = self._active_bits(safety_filter)
        self.monitors: MonitorFn | None = (self._monitors(monitors) if monitors is not None
                                           else None)
        self.elapsed: ElapsedFn = self._elapsed(memory)

    def _expr(self, node: Node, times: Mapping[str, int] | None = None) -> str:
        return expr_source(node, self.slots, self.times if times is None else times)

    def _build(self, src: Source, name: str, params: str) -> Callable[..., Any]:
        fn = build(src, name, params, f"<plchmi compiled {name}: {self.label}>")
        self.sources.append(fn.__doc__ or "")
        return fn

    # -- stages 2 to 5 -----------------------------------------------------------------------
    @property
    def held(self) -> HeldFn:
        """``held(v, h, now, scan)``: stages 2-4 while the program waits in manual mode (see
        the module docstring), generated at the first call."""
        fn = self._held
        if fn is None:
            fn = self._held = self._core(*self._parts, law=False)
        return fn

    def _core(self, layout: Layout, memory: Memory, control: ControlRuntime,
              diagnosis: DiagnosisStage | None, recovery: RecoveryStage | None,
              law: bool = True) -> Any:
        """``core``, or without the program (`law` False: ``held``)."""
        src = Source()
        self._memory(src, layout, memory, control, law)
        if diagnosis is not None:
            self._diagnosis(src, diagnosis)
            src.line(1, f"for a, b in {src.ref(diagnosis)}.current.routes:")
            src.line(2, "v[a] = v[b]")
        if recovery is not None:
            self._needed(src, recovery)
        if not law:
            return self._build(src, "held", "v, h, now, scan")
        self._control(src, control)
        outs = layout.indices(layout.outputs)
        src.line(1, "return (" + "".join(f"v[{int(s)}], " for s in outs) + ")")
        return self._build(src, "core", "v, h, now, scan")

    def _memory(self, src: Source, layout: Layout, memory: Memory,
                control: ControlRuntime, law: bool) -> None:
        # the timers and observers: the stage's scan program (hmi.program), printed
        print_program(src, memory.program, 1, self.slots, self.times)
        grafcet = control.grafcet
        if law and grafcet is not None and grafcet.time_slots:
            # only the active steps' times move (GrafcetRuntime.timed); all of them after a
            # reset or a restored state
            g = src.ref(grafcet)
            src.line(1, f"a = {g}.timed")
            src.line(1, "if a is None:")
            src.line(2, f"{g}.update_times(v, now)")
            src.line(1, "else:")
            src.line(2, "for s, x in a:")
            src.line(3, "v[s] = now - x")

    def _diagnosis(self, src: Source, stage: DiagnosisStage) -> None:
        """Stage 3's common case inline: no gap, nothing dirty, and per diagnoser whether a
        transition of its current state is due (then DiagnoserRuntime.step fires it)."""
        d = src.ref(stage)
        if stage.mode == "off":  # the diagnosers do not run; the stage settles once
            src.line(1, f"if {d}.dirty:")
            src.line(2, f"{d}.step(v, h, now, scan)")
            return
        src.line(1, f"s = {d}.last_scan")
        src.line(1, f"if {d}.dirty or s is None or scan != s + 1 or "
                 f"now - {d}.last_now > {int(GAP_SCANS)} * {d}.period:")
        src.line(2, f"{d}.step(v, h, now, scan)")
        src.line(1, "else:")
        src.line(2, f"{d}.last_scan = scan")
        src.line(2, f"{d}.last_now = now")
        src.line(2, "changed = False")
        for runtime in stage.runtimes:
            due = src.ref(self._due(runtime))
            src.line(2, f"r = {src.ref(runtime)}")
            src.line(2, "su = r.since_us")
            src.line(2, f"if su is None or {due}[r.current](v, h, now - su):")
            src.line(3, "if r.step(v, h, now, scan):")
            src.line(4, "changed = True")
        if stage.high_level:  # the High Level Diagnoser, only while a decision it refines holds
            src.line(2, f"if {d}.hld_armed and {d}.refine(v, h):")
            src.line(3, "changed = True")
        src.line(2, "if changed:")
        src.line(3, f"{d}._settle(v)")

    def _due(self, runtime: DiagnoserRuntime) -> tuple[Callable[..., bool], ...]:
        """Per state of the diagnoser: ``due(v, h, t)``, whether a transition fires after
        `t` in the state (the conditions as DiagnoserRuntime compiles them: outputs one scan
        further back, no step times)."""
        spec = runtime.spec
        index = runtime.index
        per_state: list[list[str]] = [[] for _ in spec.states]
        timeouts: list[str] = ["" for _ in spec.states]
        for tr in spec.transitions:
            src_state = index[tr.source]
            if tr.when is None:
                timeouts[src_state] = f"t >= {int(tr.after_us or 0)}"
            else:
                root = shift_outputs(tr.when.root, runtime.outputs)
                window = f"t >= {int(tr.tmin_us)}"
                if tr.tmax_us is not None:
                    window += f" and t < {int(tr.tmax_us)}"
                per_state[src_state].append(f"({window} and {self._expr(root, {})})")
        fns = []
        for k, events in enumerate(per_state):
            terms = events + ([timeouts[k]] if timeouts[k] else [])
            src = Source()
            src.line(1, "return " + (" or ".join(terms) if terms else "False"))
            fns.append(self._build(src, f"due{k}", "v, h, t"))
        return tuple(fns)

    def _needed(self, src: Source, recovery: RecoveryStage) -> None:
        """Which recovery procedures the cell may need: RecoveryStage.check_needed runs only
        when some procedure's condition holds (it times how long)."""
        procedures = [p for p in recovery.procedures.values() if p.spec.needed is not None]
        if not procedures:
            src.line(1, f"{src.ref(recovery)}.needed = ()")
            return
        src.line(1, "moved = False")
        for proc in procedures:
            needed = proc.spec.needed
            assert needed is not None
            src.line(1, f"if {self._expr(needed.when.root, {})}:")
            src.line(2, "moved = True")
            src.line(1, "else:")
            src.line(2, f"{src.ref(proc)}.needed_since = None")
        rec = src.ref(recovery)
        src.line(1, "if moved:")
        src.line(2, f"{rec}.check_needed(v, h, now)")
        src.line(1, "else:")
        src.line(2, f"{rec}.needed = ()")

    def _control(self, src: Source, control: ControlRuntime) -> None:
        grafcet = control.grafcet
        if grafcet is not None:
            g = src.ref(grafcet)
            src.line(1, "fire = ()")  # (a tuple grown only when a transition fires: no list
            for k, (sources, _, _) in enumerate(grafcet.transitions):  # built at every scan)
                tr = grafcet.grafcet.transitions[k]
                cond = " and ".join([f"v[{int(s)}]" for s in sources]
                                    + [self._expr(tr.receptivity.root)])
                src.line(1, f"if {cond}:")
                src.line(2, f"fire += ({k},)")
            src.line(1, "if fire:")
            src.line(2, f"{g}.fire(fire, v, now)")
            src.line(1, "else:")
            src.line(2, f"{g}.fired = ()")
            for slot in grafcet.driven:
                src.line(1, f"v[{int(slot)}] = False")
            for (step_slot, target, _), cond_node in zip(grafcet.continuous,
                                                         grafcet.continuous_conditions,
                                                         strict=True):
                test = f"v[{int(step_slot)}]"
                if cond_node is not None:
                    test += f" and {self._expr(cond_node)}"
                src.line(1, f"if {test}:")
                src.line(2, f"v[{int(target)}] = True")
        print_program(src, control.equations, 1, self.slots, self.times)

    def _elapsed(self, memory: Memory) -> ElapsedFn:
        """``elapsed(now)``: each timer's ET for the snapshot, as Memory.elapsed."""
        src = Source()
        parts = []
        for runtime, _, _ in memory.timers:
            r, preset = src.ref(runtime), int(runtime.preset)
            parts.append(f"(0 if {r}.since is None else (now - {r}.since if now - {r}.since < "
                         f"{preset} else {preset})), ")
        src.line(1, "return (" + "".join(parts) + ")")
        fn: ElapsedFn = self._build(src, "elapsed", "now")
        return fn

    # -- stage 6's first question ------------------------------------------------------------
    def _violated(self, safety_filter: SafetyFilter) -> ViolatedFn:
        """Whether the candidate violates a constraint: the outputs' literals read in `f`,
        the others (inputs, memories, earlier scans) in the image and the history, as
        hmi.engine.filter.compile_constraints splits them."""
        index = {name: k for k, name in enumerate(safety_filter.outputs)}
        terms = []
        for c in safety_filter.compiled:
            parts = []
            for lit in c.constraint.literals:
                if lit.depth == 0 and lit.name in index:
                    read = f"f[{int(index[lit.name])}]"
                else:
                    read = self._expr(Var(0, lit.name, lit.depth))
                parts.append(read if lit.positive else f"(not {read})")
            terms.append("(" + " and ".join(parts) + ")" if parts else "True")
        src = Source()
        src.line(1, "return " + (" or ".join(terms) if terms else "False"))
        fn: ViolatedFn = self._build(src, "violated", "v, h, f")
        return fn

    def _active_bits(self, safety_filter: SafetyFilter) -> ActiveFn:
        """``active_bits(v, h)``: which constraints are active (their literals over inputs,
        memories and earlier scans all true), bit k for safety_filter.compiled[k]: the
        corrector's memory is keyed on it (SafetyFilter.active_bits)."""
        index = {name: k for k, name in enumerate(safety_filter.outputs)}
        always = 0
        terms = []
        for k, c in enumerate(safety_filter.compiled):
            parts = []
            for lit in c.constraint.literals:
                if lit.depth == 0 and lit.name in index:
                    continue
                read = self._expr(Var(0, lit.name, lit.depth))
                parts.append(read if lit.positive else f"(not {read})")
            if parts:
                terms.append((k, " and ".join(parts)))
            else:
                always |= 1 << k
        # One statement per constraint: a project may have thousands. A bit is written as a
        # shift, not as its value (folded by the compiler up to bit 127): constraint
        # 5,000's bit has 1,506 decimal digits, and 5,000 such literals made the text
        # megabytes long (seconds to parse and check); the constant part is handed over.
        src = Source()
        src.line(1, f"b = {src.ref(always)}")
        for k, test in terms:
            src.line(1, f"if {test}:")
            src.line(2, f"b |= 1 << {k}")
        src.line(1, "return b")
        fn: ActiveFn = self._build(src, "active_bits", "v, h")
        return fn

    # -- after the output scan ----------------------------------------------------------------
    def _monitors(self, stage: MonitorStage) -> MonitorFn:
        """MonitorStage.step without its loop: a waiting task whose start is false is left
        as it is; a running task that neither ends, changes phase, breaks a rule nor
        trips its watchdog only has its stopwatches advanced (TaskAutomaton.step would do
        nothing else, and the snapshot's states are then its base moved on, see
        MonitorStage); any other calls TaskAutomaton.step with the conditions' values."""
        src = Source()
        idle, running, suspended = (src.ref(p) for p in (Phase.IDLE, Phase.RUNNING,
                                                          Phase.SUSPENDED))
        dirty = src.ref(stage._dirty)
        src.line(1, "moved = False")
        for k, (automaton, spec) in enumerate(zip(stage.automata, stage.specs, strict=True)):
            start, end = self._expr(spec.start.root), self._expr(spec.end.root)
            if spec.interrupted is not None:
                sus, res = self._expr(spec.interrupted.root), "not s"
            elif spec.interrupt is not None and spec.resume is not None:
                sus, res = self._expr(spec.interrupt.root), self._expr(spec.resume.root)
            else:
                sus, res = "False", "False"
            w = automaton.window
            alpha, beta, gamma = int(w.alpha_us), int(w.beta_us), int(w.gamma_us)
            src.line(1, f"a = {src.ref(automaton)}")
            src.line(1, "p = a.phase")
            src.line(1, f"if p is {idle}:")
            src.line(2, f"if {start}:")
            src.line(3, f"s = {sus}")
            src.line(3, f"a.step(now, scan, True, {end}, s, {res})")
            src.line(3, f"{dirty}[{k}] = True")
            src.line(3, "moved = True")
            # (a waiting task that does not start: TaskAutomaton.step would only note the
            # time in last_us, which nothing reads before the task starts and step sets it)
            src.line(1, "else:")
            src.line(2, f"e = {end}")
            src.line(2, f"s = {sus}")
            src.line(2, f"r = {res}")
            src.line(2, "el = now - a.last_us")
            src.line(2, "x = a.x_us + el")
            src.line(2, f"y = a.y_us + el if p is {running} else a.y_us")
            stays = f"((p is {running} and not s) or (p is {suspended} and not r))"
            rules = (f"(y < {alpha} and x + ({alpha} - y) >= {gamma}) or "
                     f"(y >= {alpha} and x >= {gamma}) or y > {beta} or "
                     f"(y == {beta} and p is {running})")
            src.line(2, f"if not e and {stays} and (a.attempt_fault is not None or not "
                        f"({rules})) and not (a.watchdog._armed and x >= {gamma}):")
            src.line(3, "a.last_us = now")
            src.line(3, "a.x_us = x")
            src.line(3, "a.y_us = y")
            src.line(2, "else:")
            src.line(3, "a.step(now, scan, False, e, s, r)")
            src.line(3, f"{dirty}[{k}] = True")
            src.line(3, "moved = True")
        src.line(1, "return moved")
        fn: MonitorFn = self._build(src, "monitors", "v, h, now, scan")
        return fn

"""Local diagnosers in the scan, their flags, reconstruction and masking (000 §2.1-2.2, §3.2).

Stage 3 of the scan (hmi.engine.stages), run after the memory phase and before the control
law; it decides what stages 4 and 6 do and returns it as a :class:`Diagnosis`:

3. every diagnoser steps once on I(t), the orders written at t-1 and the clock; its state's
   decision sets the partition flags `def_<partition>`;
4. a sensor whose flag is set is read from its estimate: `x_filter = not def and x or def and
   x_hat` (000 eq. 7-8) — the routes, hmi.program.diagnosers' lowering of stage 4; an
   actuator partition whose flag is set has its orders masked, `C_filter = not defV and C`
   (eq. 9-10) — the mask, applied by the filter stage (hmi.engine.filter_stage).

**Why outputs are read one scan back.** At this stage the output slots of the image still hold
the vector written at t-1, and `history[0]` holds it too, so `rise(O)` compiled as written
would compare O(t-1) with itself and never be true. A diagnoser observes the *validated*
orders (000 §2: the filtered outputs of the previous scan), so every output reference is
compiled one scan further back: `O` is the order written at t-1, `rise(O)` that it rose at
t-1 (O(t-1) and not O(t-2)). Inputs, timers and observers are read at t.

**One transition per scan.** The current state's event transitions are tried in file order;
the first whose condition holds while the time in state lies in its window [tmin, tmax) fires.
If none fires, the state's timeout fires once the time in state reaches `after`. An event
therefore wins over a timeout at the same scan. A state entered at this scan is not left
before the next one (like one GRAFCET clearing per scan), so each state is seen by the filter.

**Masking wins over the filter**, except under the `monitor` policy: see
hmi.engine.filter_stage.

**Gaps in the observation.** When the stage did not run for some scans (the inputs were
unknown: plant connection lost) or a step between two scans is longer than 10 scan periods (a
pause of a live run), a diagnoser in a normal state returns to its initial, synchronising
state: its state and clock no longer describe a plant it did not see. Faulty decisions stay.
The period is the nominal one, the period the scans are meant to run at (the project's, or a
session's slower one), never a step measured between two scans: a live run's scans come at
uneven times, and a 1 ms catch-up scan after a late one must not make the next normal step
look like ten missed scans.

Modes (for the campaign's configurations): `ftc` (flags drive reconstruction and masking),
`observe` (the diagnosers run and set their flags, nothing uses them: x_filter = x), `off`
(the diagnosers do not run: flags stay 0 and x_filter = x).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, overload

from hmi.engine.codegen import Vocabulary
from hmi.engine.layout import Layout
from hmi.logic.expr import BoolFn, History, Image, Node, Var, compile_bool, to_text, walk
from hmi.program import order
from hmi.program.diagnosers import (
    MODES,
    lower_diagnosis,
    lower_reconstruction,
    shift_outputs,
)
from hmi.program.ir import Stmt
from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import DiagnoserSpec, DiagState, HighLevelSpec, Project, ResyncRule
from hmi.timefmt import format_duration

GAP_SCANS = 10  # a step longer than this many nominal scan periods is a gap in the observation
MODE_HELP = {
    "ftc": "diagnosers drive reconstruction and masking (fault-tolerant control)",
    "observe": "diagnosers run and set their flags; nothing uses them",
    "off": "diagnosers do not run; flags stay 0 and every x_filter = x",
}


@dataclass(frozen=True)
class DiagnoserState:
    """One diagnoser at the end of a scan; immutable, for snapshots, traces and the UI."""

    name: str
    device: str | None
    state: str
    description: str
    labels: tuple[str, ...]  # the decision; empty in a normal state
    label_texts: tuple[str, ...]
    since_scan: int
    since_us: int
    via: str  # the transition (or reset) that led here; "" for the initial state
    flags: tuple[tuple[str, bool], ...]
    final: bool  # no transition leaves this state: only a fault reset does
    # What a fault reset right after this scan would do (faulty states only): the normal
    # state a resync rule matches on the current I/O ("" if none), and the values tested.
    resync: str = ""
    resync_values: str = ""
    # The High Level Diagnoser refined the local decision (hmi/project/high_level.py): why,
    # in plain words; the labels above are the refined decision.
    refined_by: str = ""

    @property
    def faulty(self) -> bool:
        return bool(self.labels)

    @property
    def certain(self) -> bool:
        """Detected and isolated with certainty: exactly one label."""
        return len(self.labels) == 1

    def decision(self) -> str:
        """'F1 (fsc stuck at 0) or F13 (...)', or 'normal'."""
        if not self.labels:
            return "normal"
        return " or ".join(f"{lab} ({text})" for lab, text in
                           zip(self.labels, self.label_texts, strict=True))

    def what(self) -> str:
        """One line for the operator."""
        where = f"{self.state} ({self.description})" if self.description else self.state
        if not self.faulty:
            return f"{self.name}: {where}"
        kind = "certain" if self.certain else ("ambiguous" if self.final else
                                               "ambiguous, not yet isolated")
        if self.refined_by:
            kind += ", by the high level diagnoser"
        return f"{self.name}: {where}: {self.decision()} [{kind}]"


def _depth(node: Node) -> int:
    return max((n.depth for n in walk(node) if isinstance(n, Var)), default=0)


class DiagnoserRuntime:
    """One compiled diagnoser: integer states, compiled conditions, the current state."""

    def __init__(self, spec: DiagnoserSpec, slots: Mapping[str, int],
                 outputs: frozenset[str]):
        self.spec = spec
        self.slots = slots
        self.outputs = outputs
        self.names = [s.name for s in spec.states]
        index = {name: k for k, name in enumerate(self.names)}
        self.index = index
        self.depth = 1
        leaves = [False] * len(spec.states)
        for tr in spec.transitions:
            leaves[index[tr.source]] = True
            if tr.when is not None:
                self.depth = max(self.depth, _depth(shift_outputs(tr.when.root, outputs)))
        self.resync_rules: list[tuple[BoolFn, int, int, ResyncRule]] = []
        for k, rule in enumerate(spec.resync, start=1):
            root = shift_outputs(rule.when.root, outputs)
            self.depth = max(self.depth, _depth(root))
            self.resync_rules.append((compile_bool(root, slots), index[rule.target], k, rule))
        self.flag_names = tuple(p.flag for p in spec.partitions)
        self.flag_slots = tuple(slots[p.flag] for p in spec.partitions)
        self.state_flags = [tuple(bool(set(p.labels) & set(s.labels)) for p in spec.partitions)
                            for s in spec.states]
        self.final = [not leave for leave in leaves]
        self.flags_of = {s.labels: self.state_flags[k] for k, s in enumerate(spec.states)}
        # The High Level Diagnoser's refinement of the current decision: (labels, why,
        # flags), until the diagnoser moves or a fault reset.
        self.refined: tuple[tuple[str, ...], str, tuple[bool, ...]] | None = None
        self.initial = index[spec.initial]
        self.current = self.initial
        self.since_us: int | None = None
        self.since_scan = 0
        self.via = ""
        self.record = self._record()
        self._resync_reads: tuple[tuple[str, int, int], ...] | None = None
        self._preview: tuple[DiagnoserState, str, str, DiagnoserState] | None = None

    @property
    def state(self) -> DiagState:
        return self.spec.states[self.current]

    @property
    def flags(self) -> tuple[bool, ...]:
        if self.refined is not None:
            return self.refined[2]
        return self.state_flags[self.current]

    @property
    def labels(self) -> tuple[str, ...]:
        """The decision: the state's, or the High Level Diagnoser's refinement of it."""
        if self.refined is not None:
            return self.refined[0]
        return self.spec.states[self.current].labels

    def refine(self, labels: tuple[str, ...], why: str) -> None:
        """The High Level Diagnoser's decision replaces the state's (and its flags)."""
        flags = tuple(bool(set(p.labels) & set(labels)) for p in self.spec.partitions)
        self.refined = (labels, why, flags)
        self.record = self._record()

    def _record(self) -> DiagnoserState:
        s = self.spec.states[self.current]
        labels = self.labels
        return DiagnoserState(
            self.spec.name, self.spec.device, s.name, s.description, labels,
            tuple(self.spec.label_text(lab) for lab in labels), self.since_scan,
            self.since_us or 0, self.via, tuple(zip(self.flag_names, self.flags, strict=True)),
            self.final[self.current],
            refined_by=self.refined[1] if self.refined is not None else "")

    def enter(self, target: int, now: int, scan: int, via: str) -> None:
        self.refined = None
        self.current = target
        self.since_us = now
        self.since_scan = scan
        self.via = via
        self.record = self._record()

    # -- the scan program's handlers (hmi.program.diagnosers: the transitions' tests) --------
    def begin(self, now: int, scan: int) -> None:
        """The first scan this diagnoser sees: its time in the initial state counts from now."""
        self.since_us, self.since_scan = now, scan
        self.record = self._record()

    def take(self, k: int, now: int, scan: int) -> None:
        """Transition k of the specification fires at this scan."""
        tr = self.spec.transitions[k]
        self.enter(self.index[tr.target], now, scan, tr.text())

    def resync_match(self, image: Image, hist: History) -> tuple[int, int, ResyncRule] | None:
        """The first resync rule the I/O satisfies: (target, rule number, rule), or None."""
        for fn, target, k, rule in self.resync_rules:
            if fn(image, hist):
                return target, k, rule
        return None

    def preview(self, image: Image, hist: History) -> DiagnoserState:
        """The record, with what a fault reset would do now (for the reset dialog).

        Called after the scan, before its image joins the history; the reset itself runs
        after that, so the history is seen as the reset will see it: this image first."""
        record = self.record
        if not record.faulty:
            return record
        seen = _Shifted(image, hist)
        match = self.resync_match(image, seen)
        resync = self.names[match[0]] if match else ""
        values = self._resync_values(image, seen)
        # A faulty diagnoser usually stays put for many scans: the same preview, built once.
        last = self._preview
        if last is not None and last[0] is record and last[1] == resync and last[2] == values:
            return last[3]
        shown = replace(record, resync=resync, resync_values=values)
        self._preview = (record, resync, values, shown)
        return shown

    def resync(self, image: Image, hist: History, now: int, scan: int) -> str:
        """Fault reset: back to the normal state the current I/O is consistent with."""
        spec = self.spec
        state = self.state
        if not state.faulty:
            return ""
        shown = self._resync_values(image, hist)
        was = f"{state.name} {{{', '.join(state.labels)}}}"
        match = self.resync_match(image, hist)
        if match is not None:
            target, k, rule = match
            self.enter(target, now, scan, f"fault reset (resync rule {k}: {rule.when})")
            new = self.state
            return (f"diagnoser {spec.name}: {was} reset, re-synchronised to {new.name}"
                    + (f" ({new.description})" if new.description else "")
                    + (f" on {shown}" if shown else "") + "; flags cleared")
        if not self.resync_rules:
            return (f"diagnoser {spec.name} stays in {was}: it declares no resync rule, so "
                    "it cannot tell which normal state the plant is in")
        return (f"diagnoser {spec.name} stays in {was}: {shown} match no normal state: the "
                "fault is still visible")

    def _resync_values(self, image: Image, hist: History) -> str:
        """`fsc=0, fso=0, C=0, O=0`: the values the resync rules test, as they see them."""
        reads = self._resync_reads
        if reads is None:  # what the rules read, found once (this runs at every faulty scan)
            seen: dict[tuple[str, int], None] = {}
            for rule in self.spec.resync:
                for node in walk(rule.when.root):
                    if isinstance(node, Var):
                        seen.setdefault((node.name, node.depth))
            reads = self._resync_reads = tuple(
                (to_text(Var(0, name, depth)), self.slots[name],
                 depth + (1 if name in self.outputs else 0)) for name, depth in seen)
        return ", ".join(f"{text}={int(bool(image[slot] if back == 0 else hist[back - 1][slot]))}"
                         for text, slot, back in reads)


class _Shifted(Sequence[Image]):
    """The history as it will be once this scan's image is in it (index 0: the image)."""

    __slots__ = ("hist", "image")

    def __init__(self, image: Image, hist: History):
        self.image, self.hist = image, hist

    def __len__(self) -> int:
        return len(self.hist) + 1

    @overload
    def __getitem__(self, k: int) -> Image: ...

    @overload
    def __getitem__(self, k: slice) -> Sequence[Image]: ...

    def __getitem__(self, k: int | slice) -> Image | Sequence[Image]:
        if isinstance(k, slice):
            return [self.image, *self.hist][k]
        return self.image if k == 0 else self.hist[k - 1]


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """What stage 3 decided, for stages 4 and 6 and the snapshot. The stage keeps returning
    the same object while no diagnoser changes state. Slotted, not a named tuple: the
    printed frame reads three of its fields at every scan (ScanNews says why)."""

    routes: tuple[tuple[int, int], ...]  # filtered slot <- sensor or estimate slot
    mask: tuple[bool, ...] | None  # per output: forced to 0 (ftc only); None: nothing masked
    records: tuple[DiagnoserState, ...]
    reconstructed: tuple[str, ...]  # sensors read from their estimate
    masked: tuple[str, ...]  # outputs whose orders are masked


NO_DIAGNOSIS = Diagnosis((), None, (), (), ())  # a scan without diagnosers (or before them)


class DiagnosisStage:
    """Stage 3 of the scan: the diagnosers, their flags, and what stages 4 and 6 must do."""

    # the stage's and each diagnoser's state and handlers (hmi.program.diagnosers)
    PRINTED = Vocabulary(
        frozenset({"dirty", "last_scan", "last_now", "gap_us", "since_us", "current", "begin",
                   "take", "lost_sight", "settle", "hld_armed", "refine",
                   # (its publication's quiet test, printed in the frame: program_stages)
                   "faulty", "records"}),
        frozenset({"c", "changed", "ls", "delta", "su", "t"}))

    def __init__(self, specs: Sequence[DiagnoserSpec], layout: Layout, mode: str,
                 period_us: int, high_level: Sequence[HighLevelSpec] = ()):
        if mode not in MODES:
            raise ValueError(f"unknown diagnosis mode {mode!r}")
        self.mode = mode
        self.gap_us = 0
        self.period = period_us  # nominal: a step longer than GAP_SCANS of it is a gap
        lay = layout
        slots = lay.slots
        outputs = frozenset(lay.outputs)
        self.runtimes = [DiagnoserRuntime(spec, slots, outputs) for spec in specs]
        # (filtered slot, sensor slot, estimate slot, flag slot, sensor, estimate)
        self.sensors = [(slots[p.filtered], slots[p.sensor], slots[p.estimate], slots[p.flag],
                         p.sensor, p.estimate)
                        for spec in specs for p in spec.partitions
                        if p.sensor and p.estimate and p.filtered]
        masks: dict[int, list[int]] = {}
        for spec in specs:
            for p in spec.partitions:
                for out in p.actuators:
                    masks.setdefault(lay.outputs.index(out), []).append(slots[p.flag])
        self.masks = sorted(masks.items())
        # Each actuator partition's flag and the orders it masks, in the diagnosers' order
        # (the PLC's filter block masks them so), and which flags mask each masked output,
        # for the filter's report.
        self.masking = tuple((p.flag, tuple(p.actuators)) for spec in specs
                             for p in spec.partitions if p.actuators)
        self.mask_flags = {lay.outputs[k]: tuple(
            flag for flag, actuators in self.masking if lay.outputs[k] in actuators)
            for k, _ in self.masks}
        self.outputs = lay.outputs
        # The High Level Diagnoser (hmi/project/high_level.py): per specification, its
        # diagnoser, the decision it refines and its compiled rules (label, why).
        by_name = {rt.spec.name: rt for rt in self.runtimes}
        self.high_level = [
            (by_name[h.diagnoser], h.decision,
             [(compile_bool(shift_outputs(r.when.root, outputs), slots), r.decide, r.because)
              for r in h.rules])
            for h in high_level]
        self.hld_armed = False  # some specification's decision holds, not yet refined
        self.depth = max((rt.depth for rt in self.runtimes), default=1)
        for h in high_level:
            for r in h.rules:
                self.depth = max(self.depth, _depth(shift_outputs(r.when.root, outputs)))
        self.dirty = True  # flags, routes and masks to recompute at the next scan
        self.last_scan: int | None = None  # the last scan the stage ran
        self.last_now = 0
        self.faulty = False  # some diagnoser holds a faulty decision
        self.current = Diagnosis((), None, (), (), ())  # nothing shown before the first run
        # Stages 3 and 4 as the scan program (hmi.program.diagnosers): what runs at each
        # scan, hmi.engine.compiled puts it in its place
        self.program = lower_diagnosis(self, [(rt, rt.spec) for rt in self.runtimes], mode,
                                       outputs, bool(self.high_level))
        self.reconstruction = lower_reconstruction(
            [(f, sensor, estimate, flag) for f, sensor, estimate, flag, _, _ in self.sensors],
            mode)

    @property
    def parts(self) -> dict[str, tuple[Stmt, ...]]:
        return {order.DIAGNOSERS: self.program, order.RECONSTRUCTION: self.reconstruction}

    @property
    def period(self) -> int:
        return self._period

    @period.setter
    def period(self, period_us: int) -> None:
        self._period = period_us
        self.gap_us = GAP_SCANS * period_us  # (what the scan program compares a step with)

    def refine(self, image: Image, history: History) -> bool:
        """The High Level Diagnoser, after the local diagnosers: a specification whose
        decision a diagnoser holds tries its rules in order; the first that holds refines
        the decision. True when a decision was refined (the flags must follow)."""
        refined = False
        for rt, decision, rules in self.high_level:
            if rt.refined is not None or rt.labels != decision:
                continue
            for fn, label, why in rules:
                if fn(image, history):
                    rt.refine((label,), why)
                    refined = True
                    break
        return refined

    def lost_sight(self, now: int, scan: int, delta: int) -> bool:
        """The plant was not observed for `delta` (inputs unknown, or no scan: a pause).

        A normal state and its clock no longer describe the plant (the valve may have moved,
        or stopped, unseen), so the diagnoser goes back to its initial, synchronising state
        rather than read a missed arrival as a fault. A faulty decision stays latched; an
        intermediate one keeps its state with its clock frozen during the gap, and refines
        on what it sees next.
        """
        changed = False
        for rt in self.runtimes:
            if rt.state.faulty:
                if rt.since_us is not None:
                    rt.since_us += max(0, delta - self.period)
                continue
            if rt.current != rt.initial:
                rt.enter(rt.initial, now, scan, f"plant not observed for "
                         f"{format_duration(delta)}: re-synchronising")
                changed = True
        return changed

    def settle(self, image: Image) -> None:
        self.dirty = False
        if self.mode != "off":
            for rt in self.runtimes:
                for slot, value in zip(rt.flag_slots, rt.flags, strict=True):
                    image[slot] = value
        ftc = self.mode == "ftc"
        routes = []
        reconstructed = []
        for fslot, sslot, eslot, flag, sensor, _estimate in self.sensors:
            if ftc and image[flag]:
                routes.append((fslot, eslot))
                reconstructed.append(sensor)
            else:
                routes.append((fslot, sslot))
        mask = [False] * len(self.outputs)
        if ftc:
            for k, flags in self.masks:
                mask[k] = any(image[f] for f in flags)
        records = tuple(rt.record for rt in self.runtimes)
        self.faulty = any(r.faulty for r in records)
        self.hld_armed = self.mode != "off" and any(
            rt.refined is None and rt.labels == decision for rt, decision, _ in self.high_level)
        self.current = Diagnosis(
            tuple(routes), tuple(mask) if any(mask) else None, records, tuple(reconstructed),
            tuple(self.outputs[k] for k, m in enumerate(mask) if m))

    def publish(self, image: Image, history: History) -> tuple[DiagnoserState, ...]:
        """The diagnosers for the snapshot, at the end of the scan: a faulty one with what a
        fault reset would do now (for the reset dialog); the records as they stand when the
        stage did not run this scan (inputs unknown)."""
        if self.faulty:
            return tuple(rt.preview(image, history) for rt in self.runtimes)
        return self.current.records

    def capture(self) -> tuple[Any, ...]:
        """The stage's and its diagnosers' state (Engine.capture)."""
        return (self.current, self.dirty, self.last_scan, self.last_now, self.faulty,
                self.hld_armed,
                tuple((rt.current, rt.since_us, rt.since_scan, rt.via, rt.record, rt.refined)
                      for rt in self.runtimes))

    def restore(self, state: tuple[Any, ...]) -> None:
        (self.current, self.dirty, self.last_scan, self.last_now, self.faulty,
         self.hld_armed, runtimes) = state
        for rt, (current, since_us, since_scan, via, record, refined) in zip(
                self.runtimes, runtimes, strict=True):
            rt.current, rt.since_us, rt.since_scan, rt.via, rt.record, rt.refined = (
                current, since_us, since_scan, via, record, refined)

    def resynchronise(self, devices: set[str], now: int, scan: int, why: str) -> None:
        """The devices' diagnosers in a normal state go back to their initial, synchronising
        state (a recovery is about to move the device in ways no normal state describes);
        faulty decisions stay until a fault reset."""
        for rt in self.runtimes:
            if rt.spec.device in devices and not rt.state.faulty and rt.current != rt.initial:
                rt.enter(rt.initial, now, scan, why)
                self.dirty = True

    def reset(self, image: Image, history: History, now: int, scan: int) -> list[str]:
        """Fault reset: re-synchronise every faulty diagnoser, or say why not."""
        if self.mode == "off":
            return []
        lines = []
        for rt in self.runtimes:
            line = rt.resync(image, history, now, scan)
            if line:
                lines.append(line)
        self.dirty = True  # flags follow the new states at the next scan
        return lines


def diagnosis_stage(project: Project, layout: Layout, mode: str = "ftc",
                    high_level: bool = True) -> DiagnosisStage | None:
    """The project's diagnosers as a scan stage (None for a project without diagnosers),
    with its High Level Diagnoser unless `high_level` is false (the campaign's "before")."""
    if mode not in MODES:
        raise ValueError(f"unknown diagnosis mode {mode!r}")
    specs = diagnosers_of(project)
    if not specs:
        return None
    return DiagnosisStage(specs, layout, mode, project.scan_period_us,
                          project.high_level if high_level else ())

"""Local diagnosers in the scan, their flags, reconstruction and masking (000 §2.1-2.2, §3.2).

Scan stages 3 and 4 of DESIGN.md, run after the memory phase and before the control law:

3. every diagnoser steps once on I(t), the orders written at t-1 and the clock; its state's
   decision sets the partition flags `def_<partition>`;
4. a sensor whose flag is set is read from its estimate: `x_filter = not def and x or def and
   x_hat` (000 eq. 7-8); an actuator partition whose flag is set has its orders masked,
   `C_filter = not defV and C` (eq. 9-10).

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

**Masking wins over the filter** (except under the `monitor` policy, which alters nothing and
only says what it would have masked). Masked orders are forced to 0 in the candidate vector the
filter sees (so the filter judges what will really be sent), and again after the filter: a
simple constraint of the form `not o . h1` (e.g. CSs4, never drop O before fso) would
otherwise switch a masked order back on. The scan where masking starts may therefore leave
such a constraint violated; the filter report says so in its note, and counts it as accepted
(the order is withdrawn from a device the diagnoser no longer trusts; 000 §3: "when a fault is
on an actuator, all outputs must be deactivated by the filter").

**Gaps in the observation.** When the stage did not run for some scans (the inputs were
unknown: plant connection lost) or a step between two scans is longer than 10 scan periods (a
pause of a live run), a diagnoser in a normal state returns to its initial, synchronising
state: its state and clock no longer describe a plant it did not see. Faulty decisions stay.

Modes (for the campaign's configurations): `ftc` (flags drive reconstruction and masking),
`observe` (the diagnosers run and set their flags, nothing uses them: x_filter = x), `off`
(the diagnosers do not run: flags stay 0 and x_filter = x).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from hmi.logic.expr import (
    And,
    BoolFn,
    Compare,
    Node,
    Not,
    Or,
    Var,
    compile_bool,
    to_text,
    walk,
)
from hmi.project.diagnosers import DiagnoserSpec, DiagTransition, diagnosers_of
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from hmi.engine.scan import Engine

MODES = ("ftc", "observe", "off")
GAP_SCANS = 10  # a step this many scan periods long is a gap in the observation
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
        return f"{self.name}: {where}: {self.decision()} [{kind}]"


def shift_outputs(node: Node, outputs: frozenset[str]) -> Node:
    """The same condition with every output read one scan further back (see module doc)."""
    if isinstance(node, Var):
        return replace(node, depth=node.depth + 1) if node.name in outputs else node
    if isinstance(node, Not):
        return replace(node, operand=shift_outputs(node.operand, outputs))
    if isinstance(node, (And, Or)):
        return replace(node, operands=tuple(shift_outputs(op, outputs)
                                            for op in node.operands))
    if isinstance(node, Compare):
        return node
    return node


def _depth(node: Node) -> int:
    return max((n.depth for n in walk(node) if isinstance(n, Var)), default=0)


class DiagnoserRuntime:
    """One compiled diagnoser: integer states, compiled conditions, the current state."""

    def __init__(self, spec: DiagnoserSpec, slots, outputs: frozenset[str]):
        self.spec = spec
        self.slots = slots
        self.outputs = outputs
        self.names = [s.name for s in spec.states]
        index = {name: k for k, name in enumerate(self.names)}
        self.index = index
        self.depth = 1
        events: list[list[tuple[BoolFn, int, int | None, int, DiagTransition]]] = [
            [] for _ in spec.states]
        timeouts: list[tuple[int, int, DiagTransition] | None] = [None] * len(spec.states)
        leaves = [False] * len(spec.states)
        for tr in spec.transitions:
            src = index[tr.source]
            leaves[src] = True
            if tr.when is None:
                timeouts[src] = (tr.after_us or 0, index[tr.target], tr)
            else:
                root = shift_outputs(tr.when.root, outputs)
                self.depth = max(self.depth, _depth(root))
                events[src].append((compile_bool(root, slots), tr.tmin_us, tr.tmax_us,
                                    index[tr.target], tr))
        self.events = events
        self.timeouts = timeouts
        self.resync_rules = []
        for k, rule in enumerate(spec.resync, start=1):
            root = shift_outputs(rule.when.root, outputs)
            self.depth = max(self.depth, _depth(root))
            self.resync_rules.append((compile_bool(root, slots), index[rule.target], k, rule))
        self.flag_names = tuple(p.flag for p in spec.partitions)
        self.flag_slots = tuple(slots[p.flag] for p in spec.partitions)
        self.state_flags = [tuple(bool(set(p.labels) & set(s.labels)) for p in spec.partitions)
                            for s in spec.states]
        self.final = [not leave for leave in leaves]
        self.initial = index[spec.initial]
        self.current = self.initial
        self.since_us: int | None = None
        self.since_scan = 0
        self.via = ""
        self.record = self._record()

    @property
    def state(self):
        return self.spec.states[self.current]

    @property
    def flags(self) -> tuple[bool, ...]:
        return self.state_flags[self.current]

    def _record(self) -> DiagnoserState:
        s = self.spec.states[self.current]
        return DiagnoserState(
            self.spec.name, self.spec.device, s.name, s.description, s.labels,
            tuple(self.spec.label_text(lab) for lab in s.labels), self.since_scan,
            self.since_us or 0, self.via, tuple(zip(self.flag_names, self.flags, strict=True)),
            self.final[self.current])

    def enter(self, target: int, now: int, scan: int, via: str) -> None:
        self.current = target
        self.since_us = now
        self.since_scan = scan
        self.via = via
        self.record = self._record()

    def step(self, image, hist, now: int, scan: int) -> bool:
        """One scan of the automaton; True when the state changed."""
        if self.since_us is None:
            self.since_us, self.since_scan = now, scan
            self.record = self._record()
        t = now - self.since_us
        cur = self.current
        for fn, tmin, tmax, target, tr in self.events[cur]:
            if t >= tmin and (tmax is None or t < tmax) and fn(image, hist):
                self.enter(target, now, scan, tr.text())
                return True
        timeout = self.timeouts[cur]
        if timeout is not None and t >= timeout[0]:
            self.enter(timeout[1], now, scan, timeout[2].text())
            return True
        return False

    def resync_match(self, image, hist) -> tuple[int, int, object] | None:
        """The first resync rule the I/O satisfies: (target, rule number, rule), or None."""
        for fn, target, k, rule in self.resync_rules:
            if fn(image, hist):
                return target, k, rule
        return None

    def preview(self, image, hist) -> DiagnoserState:
        """The record, with what a fault reset would do now (for the reset dialog).

        Called after the scan, before its image joins the history; the reset itself runs
        after that, so the history is seen as the reset will see it: this image first."""
        record = self.record
        if not record.faulty:
            return record
        seen = _Shifted(image, hist)
        match = self.resync_match(image, seen)
        return replace(record, resync=self.names[match[0]] if match else "",
                       resync_values=self._resync_values(image, seen))

    def resync(self, image, hist, now: int, scan: int) -> str:
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

    def _resync_values(self, image, hist) -> str:
        """`fsc=0, fso=0, C=0, O=0`: the values the resync rules test, as they see them."""
        seen: dict[tuple[str, int], None] = {}
        for rule in self.spec.resync:
            for node in walk(rule.when.root):
                if isinstance(node, Var):
                    seen.setdefault((node.name, node.depth))
        parts = []
        for name, depth in seen:
            back = depth + (1 if name in self.outputs else 0)
            slot = self.slots[name]
            value = image[slot] if back == 0 else hist[back - 1][slot]
            parts.append(f"{to_text(Var(0, name, depth))}={int(bool(value))}")
        return ", ".join(parts)


class _Shifted:
    """The history as it will be once this scan's image is in it (index 0: the image)."""

    __slots__ = ("hist", "image")

    def __init__(self, image, hist):
        self.image, self.hist = image, hist

    def __getitem__(self, k: int):
        return self.image if k == 0 else self.hist[k - 1]


class DiagnosisStage:
    """The engine's diagnosers, flags, reconstructed sensors and masks (one stage)."""

    def __init__(self, engine: Engine, specs: Sequence[DiagnoserSpec], mode: str):
        if mode not in MODES:
            raise ValueError(f"unknown diagnosis mode {mode!r}")
        self.mode = mode
        lay = engine.layout
        slots = lay.slots
        outputs = frozenset(lay.outputs)
        self.runtimes = [DiagnoserRuntime(spec, slots, outputs) for spec in specs]
        self.flag_slots = {p.flag: slots[p.flag] for spec in specs for p in spec.partitions}
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
        self.mask_flags = {lay.outputs[k]: tuple(
            p.flag for spec in specs for p in spec.partitions if lay.outputs[k] in p.actuators)
            for k, _ in self.masks}
        self.outputs = lay.outputs
        self.mask: tuple[bool, ...] | None = None  # this scan's mask (ftc only)
        self.depth = max((rt.depth for rt in self.runtimes), default=1)
        self.dirty = True  # flags, routes and masks to recompute at the next scan
        self.last_scan: int | None = None  # the last scan the stage ran
        self.last_now = 0
        self.period: int | None = None  # the shortest step seen between two scans
        self.routes: tuple[tuple[int, int], ...] = ()  # filtered slot <- sensor or estimate
        self.records: tuple[DiagnoserState, ...] = ()
        self.faulty = False  # some diagnoser holds a faulty decision (its records + preview)
        self.reconstructed: tuple[str, ...] = ()
        self.masked: tuple[str, ...] = ()

    def __call__(self, engine: Engine) -> None:
        image, hist = engine.image, engine.history
        changed = self.dirty
        if self.mode != "off":
            now, scan = engine.now, engine.scan
            if self.last_scan is not None:
                delta = now - self.last_now
                if scan != self.last_scan + 1 or (self.period and delta > GAP_SCANS * self.period):
                    changed = self._lost_sight(now, scan, delta) or changed
                elif delta > 0:
                    self.period = min(self.period or delta, delta)
            self.last_scan, self.last_now = scan, now
            for rt in self.runtimes:
                if rt.step(image, hist, now, scan):
                    changed = True
        if changed:  # flags, routes and masks only move when a diagnoser changes state
            self._settle(image)
        for fslot, source in self.routes:
            image[fslot] = image[source]
        extras = engine.extras
        extras["diagnosers"] = self.records
        self.faulty = any(r.faulty for r in self.records)
        extras["reconstructed"] = self.reconstructed
        extras["masked"] = self.masked if engine.policy != "monitor" else ()

    def _lost_sight(self, now: int, scan: int, delta: int) -> bool:
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
                    rt.since_us += max(0, delta - (self.period or 0))
                continue
            if rt.current != rt.initial:
                rt.enter(rt.initial, now, scan, f"plant not observed for "
                         f"{format_duration(delta)}: re-synchronising")
                changed = True
        return changed

    def _settle(self, image) -> None:
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
        self.routes = tuple(routes)
        mask = [False] * len(self.outputs)
        if ftc:
            for k, flags in self.masks:
                mask[k] = any(image[f] for f in flags)
        self.mask = tuple(mask) if any(mask) else None
        self.masked = tuple(self.outputs[k] for k, m in enumerate(mask) if m)
        self.reconstructed = tuple(reconstructed)
        self.records = tuple(rt.record for rt in self.runtimes)

    def publish(self, engine: Engine, extras: dict) -> None:
        """Snapshot hook: a scan that skipped the stage (inputs unknown) still shows the
        diagnosers, as they stand; a faulty one with what a fault reset would do now."""
        if self.faulty:
            extras["diagnosers"] = tuple(rt.preview(engine.image, engine.history)
                                         for rt in self.runtimes)
        extras.setdefault("diagnosers", self.records)
        extras.setdefault("reconstructed", self.reconstructed)
        extras.setdefault("masked", self.masked if engine.policy != "monitor" else ())

    def reset(self, engine: Engine) -> list[str]:
        """The fault-reset hook: re-synchronise every faulty diagnoser, or say why not."""
        if self.mode == "off" or not engine.started:
            return []
        lines = []
        for rt in self.runtimes:
            line = rt.resync(engine.image, engine.history, engine.now, engine.scan)
            if line:
                lines.append(line)
        self.dirty = True  # flags follow the new states at the next scan
        return lines


class MaskedOutputStage:
    """Wraps the output stage (the safety filter) so masked orders are never sent."""

    def __init__(self, inner, stage: DiagnosisStage):
        self.inner = inner
        self.stage = stage

    def __getattr__(self, name: str):  # the filter's own attributes (compiled, active...)
        return getattr(self.inner, name)

    def __call__(self, engine: Engine, fov: tuple[bool, ...]):
        mask = self.stage.mask
        if mask is None:
            return self.inner(engine, fov)
        if engine.policy == "monitor":  # monitor alters nothing, masks included: it says so
            written, report = self.inner(engine, fov)
            return written, self._unapplied(report)
        candidate = tuple(v and not m for v, m in zip(fov, mask, strict=True))
        written, report = self.inner(engine, candidate)
        forced = tuple(bool(w) and not m for w, m in zip(written, mask, strict=True))
        return forced, self._report(engine, report, fov, candidate, written, forced, mask)

    def _unapplied(self, report):
        from hmi.engine.filter import FilterReport
        if not isinstance(report, FilterReport):
            return report
        masked = [self.stage.outputs[k] for k, m in enumerate(self.stage.mask or ()) if m]
        flags = sorted({f for n in masked for f in self.stage.mask_flags[n]})
        extra = (f"{', '.join(flags)} would mask {', '.join(masked)}; not applied under the "
                 "monitor policy")
        return report._replace(note=f"{report.note}; {extra}" if report.note else extra)

    def _report(self, engine: Engine, report, fov, candidate, written, forced, mask):
        from hmi.engine.filter import Change, FilterReport, pack
        if not isinstance(report, FilterReport):
            return report
        outputs = self.stage.outputs
        masked = {outputs[k] for k, m in enumerate(mask) if m}
        changes = [c for c in report.changes if c.output not in masked]
        for k, name in enumerate(outputs):
            if mask[k] and (fov[k] or written[k]):
                changes.append(Change(name, bool(fov[k]), False, self.stage.mask_flags[name],
                                      "masked"))
        residual = report.residual
        accepted: tuple[str, ...] = ()
        active = getattr(self.inner, "active", None)
        if active is not None and forced != tuple(written):
            value = pack(forced)
            violated = [c for c in active(engine.image, engine.history)
                        if value & c.pos == c.pos and not value & c.neg]
            accepted = tuple(c.name for c in violated if set(c.constraint.outputs) <= masked)
            residual = tuple(c.name for c in violated if c.name not in accepted)
        note = report.note
        extra = f"orders {', '.join(sorted(masked))} masked by " + ", ".join(
            sorted({f for n in masked for f in self.stage.mask_flags[n]}))
        if accepted:
            extra += (f" (accepted: {', '.join(accepted)} stays violated this scan; the mask "
                      "has the last word)")
        note = f"{note}; {extra}" if note else extra
        return report._replace(changes=tuple(changes), residual=residual, note=note,
                       distance=sum(a != b for a, b in zip(candidate, forced, strict=True)))


def install_diagnosers(engine: Engine, mode: str = "ftc") -> DiagnosisStage | None:
    """Add the diagnosis stage, the masking wrapper and the reset hook to an engine."""
    specs = diagnosers_of(engine.project)
    if not specs:
        return None
    stage = DiagnosisStage(engine, specs, mode)
    engine.stages_after_memory.append(stage)
    engine.output_stage = MaskedOutputStage(engine.output_stage, stage)
    engine.reset_hooks.append(stage.reset)
    engine.snapshot_extras.append(stage.publish)
    if stage.depth > (engine.history.maxlen or 0) and not engine.started:
        engine.history = deque(maxlen=stage.depth)
    engine.diagnosis = stage
    explainer = getattr(engine, "explainer", None)
    if explainer is not None:
        from hmi.explain.diagnoses import diagnosis_explanations
        explainer.extra_builders.append(diagnosis_explanations)
    return stage

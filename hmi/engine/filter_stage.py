"""Stage 6 of the scan: the safety filter, with the diagnosers' mask as an argument.

The mask (hmi.engine.diagnoser.Diagnosis.mask: per output, its orders forced to 0 because a
diagnoser no longer trusts the actuator, 000 eq. 9-10) **wins over the filter**, except under
the `monitor` policy, which alters nothing and only says what it would have masked. Masked
orders are forced to 0 in the candidate vector the filter sees (so the filter judges what will
really be sent), and again after the filter: a simple constraint of the form `not o . h1`
(e.g. CSs4, never drop O before fso) would otherwise switch a masked order back on. The scan
where masking starts may therefore leave such a constraint violated; the report says so in its
note and counts it as accepted (the order is withdrawn from a device the diagnoser no longer
trusts; 000 §3: "when a fault is on an actuator, all outputs must be deactivated by the
filter").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any, ClassVar, Protocol

from hmi.engine.codegen import Vocabulary
from hmi.engine.filter import Change, FilterDecision, FilterReport, SafetyFilter, pack
from hmi.logic.expr import History, Image
from hmi.program import ir


class Recoveries(Protocol):
    """What takes the filter's place in recovery mode (hmi.engine.recovery.RecoveryStage):
    the running procedure's own filter stage, and the diagnosers' mask without the orders
    that procedure drives."""

    @property
    def filter_stage(self) -> FilterStage | None: ...

    def unmask(self, mask: tuple[bool, ...] | None) -> tuple[bool, ...] | None: ...


class FilterStage:
    """The safety filter and the masking around it; returns its decision to the engine.

    A declared stage (hmi.engine.program_stages.FILTER) whose part of the scan the engine
    runs itself (hmi.program.order.FILTER), between the mode's program and the output scan:
    none of the mode's program. Its lowering is the filter's own (:attr:`functions`,
    hmi.program.constraints), which the compiled scan builds in its form and hands back
    (:meth:`bind`) and the PLC's filter block prints (hmi.export.filter_pou); its handler
    at that part is :meth:`decide` (the engine's scan), and the printed frame's, when its
    first question (:meth:`question`) is not quiet, :attr:`unmasked` (nothing masked nor
    latched: given the word) or :meth:`apply`."""

    # the handlers its functions call, and the first question the printed frame reads
    PRINTED = SafetyFilter.PRINTED.union(Vocabulary(frozenset({"violations"})))
    parts: ClassVar[Mapping[str, tuple[ir.Stmt, ...]]] = {}

    def __init__(self, safety_filter: SafetyFilter, mask_flags: Mapping[str, tuple[str, ...]],
                 masking: tuple[tuple[str, tuple[str, ...]], ...] = (),
                 recovery: Recoveries | None = None):
        self.filter = safety_filter
        # The scan's report, as the engine's part of the scan decided it (None: the filter
        # was not reached): what the stage publishes (Engine._keep hands it over)
        self.report: FilterReport | None = None
        self.outputs = safety_filter.outputs
        self.mask_flags = mask_flags  # masked output -> the flags that mask it
        # each actuator partition's flag and the orders it masks (the PLC's block masks so)
        self.masking = masking
        # the recovery procedures, whose running one's filter replaces this one in recovery
        # mode (its own constraints), the orders it drives unmasked
        self.recovery = recovery
        self.clean = safety_filter.clean
        # The decision on a candidate nothing masks, given its violation word when the caller
        # has it (the printed frame's, not computed again): the filter's own, handed out
        # whole so that a violated scan makes one call (Engine._auto_filter)
        self.unmasked: Callable[..., FilterDecision] = safety_filter.apply
        # The last masked scan's report when the mask had the last word on nothing the
        # filter wrote: ((report, fov, written, mask), the report shown).
        self._masked_report: tuple[tuple[object, ...], FilterReport] | None = None

    @property
    def functions(self) -> dict[str, ir.Function]:
        """Its lowering as the scan program's functions of its own (outside the mode's
        program), by name: the candidate's violation word, the policy, the active word."""
        return self.filter.program.functions()

    def bind(self, built: Mapping[str, Callable[..., Any]]) -> None:
        """The compiled scan's form of :attr:`functions`, which the filter then calls."""
        inner = self.filter
        inner.violations = built["violated"]
        inner.decide = built["decide"]
        inner.active_bits = built["active_bits"]

    def question(self, image: ir.Value, history: ir.Value, candidate: ir.Value,
                 local: ir.Local) -> tuple[ir.Stmt, ir.Value]:
        """Its first question at a scan, as the printed frame asks it: the statement that
        reads its function into `local` (at each scan: whoever replaces it is called) and the
        violation word of `candidate` (0: nothing violated, the candidate passes clean)."""
        return (ir.Assign(local, ir.Cell(self.filter, "violations")),
                ir.Apply(local, (image, history, candidate)))

    def decide(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
               latched: bool, mask: tuple[bool, ...] | None, recovering: bool
               ) -> FilterDecision:
        """Its part of the engine's scan (Engine._cycle): :meth:`apply`, or in recovery mode
        the running procedure's filter, never under the monitor policy (a recovery is never
        unfiltered), given the mask without the orders the procedure drives."""
        recovery = self.recovery
        if recovering:
            stage = self
            if recovery is not None:
                stage = recovery.filter_stage or self
                mask = recovery.unmask(mask)
            if policy == "monitor":
                policy = "correct"
            return stage.apply(image, history, fov, policy, latched, mask)
        return self.apply(image, history, fov, policy, latched, mask)

    def apply(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
              latched: bool, mask: tuple[bool, ...] | None) -> FilterDecision:
        """The decision on the candidate `fov`, masked by `mask`."""
        inner = self.filter
        if mask is None:
            # the scan program's violation word; nothing violated and no block latch: the
            # candidate unchanged with the clean report, without the policy's call
            word = inner.violations(image, history, fov)
            if not word and not (latched and policy == "block"):
                return FilterDecision(fov, self.clean[policy])
            return inner.apply(image, history, fov, policy, latched, word)
        if policy == "monitor":  # monitor alters nothing, masks included: it says so
            decision = inner.apply(image, history, fov, policy, latched)
            return decision._replace(report=self._unapplied(decision.report, mask))
        candidate = tuple(v and not m for v, m in zip(fov, mask, strict=True))
        word = inner.violations(image, history, candidate)
        if not word and not (latched and policy == "block"):
            written, report, latch = candidate, self.clean[policy], None
        else:
            written, report, latch = inner.apply(image, history, candidate, policy, latched,
                                                 word)
        forced = tuple(bool(w) and not m for w, m in zip(written, mask, strict=True))
        if forced == tuple(written):
            # The report then depends on these only: a device masked for many scans with the
            # same orders asked gets the same report, built once.
            key = (report, fov, written, mask)
            last = self._masked_report
            if last is not None and last[0] == key:
                return FilterDecision(forced, last[1], latch)
            shown = self._report(image, history, report, fov, candidate, written, forced, mask)
            self._masked_report = (key, shown)
            return FilterDecision(forced, shown, latch)
        return FilterDecision(forced, self._report(image, history, report, fov, candidate,
                                                   written, forced, mask), latch)

    def _flags(self, masked: Iterable[str]) -> list[str]:
        return sorted({f for name in masked for f in self.mask_flags[name]})

    def _unapplied(self, report: FilterReport, mask: tuple[bool, ...]) -> FilterReport:
        masked = [self.outputs[k] for k, m in enumerate(mask) if m]
        extra = (f"{', '.join(self._flags(masked))} would mask {', '.join(masked)}; not "
                 "applied under the monitor policy")
        return report._replace(note=f"{report.note}; {extra}" if report.note else extra)

    def _report(self, image: Image, history: History, report: FilterReport,
                fov: tuple[bool, ...], candidate: tuple[bool, ...], written: tuple[bool, ...],
                forced: tuple[bool, ...], mask: tuple[bool, ...]) -> FilterReport:
        outputs = self.outputs
        masked = {outputs[k] for k, m in enumerate(mask) if m}
        changes = [c for c in report.changes if c.output not in masked]
        for k, name in enumerate(outputs):
            if mask[k] and (fov[k] or written[k]):
                changes.append(Change(name, bool(fov[k]), False, self.mask_flags[name],
                                      "masked"))
        residual = report.residual
        accepted: tuple[str, ...] = ()
        if forced != tuple(written):
            value = pack(forced)
            violated = [c for c in self.filter.active(image, history)
                        if value & c.pos == c.pos and not value & c.neg]
            accepted = tuple(c.name for c in violated if set(c.constraint.outputs) <= masked)
            residual = tuple(c.name for c in violated if c.name not in accepted)
        note = report.note
        extra = f"orders {', '.join(sorted(masked))} masked by " + ", ".join(self._flags(masked))
        if accepted:
            extra += (f" (accepted: {', '.join(accepted)} stays violated this scan; the mask "
                      "has the last word)")
        note = f"{note}; {extra}" if note else extra
        return report._replace(changes=tuple(changes), residual=residual, note=note,
                               distance=sum(a != b for a, b in
                                            zip(candidate, forced, strict=True)))

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

from collections.abc import Iterable, Mapping
from typing import ClassVar

from hmi.engine.filter import Change, FilterDecision, FilterReport, SafetyFilter, pack
from hmi.logic.expr import History, Image
from hmi.program import ir


class FilterStage:
    """The safety filter and the masking around it; returns its decision to the engine.

    A declared stage (hmi.engine.program_stages.FILTER) whose part of the scan the engine
    runs itself (hmi.program.order.FILTER): none of the mode's program (its lowerings are
    the filter's own functions, hmi.program.constraints, printed by the compiled scan)."""

    PRINTED = SafetyFilter.PRINTED  # (the handlers its functions call)
    parts: ClassVar[Mapping[str, tuple[ir.Stmt, ...]]] = {}

    def __init__(self, safety_filter: SafetyFilter, mask_flags: Mapping[str, tuple[str, ...]]):
        self.filter = safety_filter
        # The scan's report, as the engine's part of the scan decided it (None: the filter
        # was not reached): what the stage publishes (Engine._keep hands it over)
        self.report: FilterReport | None = None
        self.outputs = safety_filter.outputs
        self.mask_flags = mask_flags  # masked output -> the flags that mask it
        self.clean = safety_filter.clean
        # The last masked scan's report when the mask had the last word on nothing the
        # filter wrote: ((report, fov, written, mask), the report shown).
        self._masked_report: tuple[tuple[object, ...], FilterReport] | None = None

    def apply(self, image: Image, history: History, fov: tuple[bool, ...], policy: str,
              latched: bool, mask: tuple[bool, ...] | None) -> FilterDecision:
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

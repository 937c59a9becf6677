"""Offline checks of a constraint set, printed by `plchmi check` (004 eq. 4, §4).

* Conflicts: a simple constraint `o.h0` and another `not o.h1` on the same output whose
  contexts can hold together (004 demands h0 xor h1) — the corrector could not satisfy both.
* Situations with no safe output vector: assignments of the uncontrollable variables Y in
  which every output vector violates some constraint, so the filter would fall back to the
  safe state. Searched exhaustively when Y has at most EXHAUSTIVE_VARS variables, otherwise
  on a bounded random sample (said so in the report).
* The worst-case Hamming distance the corrector may need, over those situations and every
  functional vector (exhaustive for small projects), and the outputs in combined constraints.

A situation is skipped as unreachable when it needs the previous outputs to violate a
constraint that involves only outputs (like `C and O`): the filter never writes such a vector
(and the safe state satisfies it), so `prev(C) and prev(O)` cannot both hold.
"""

from __future__ import annotations

import itertools
import random
from collections.abc import Iterator
from dataclasses import dataclass, field

from hmi.engine.solver import Problem
from hmi.limits import MAX_ANALYSIS_STEPS
from hmi.logic.expr import Literal
from hmi.program.constraints import lower_constraints
from hmi.project.model import Constraint, Project

# A constraint with its output masks (must be 1, must be 0) and its literals over Y.
_Item = tuple[Constraint, int, int, tuple[Literal, ...]]

EXHAUSTIVE_VARS = 16
SAMPLES = 20_000
MIN_SAMPLES = 100
WORK = 1_000_000  # constraint evaluations over all situations (about half a second)
MAX_CONFLICTS_SHOWN = 20
EXHAUSTIVE_FOV_OUTPUTS = 10


@dataclass
class FilterAnalysis:
    variables: list[tuple[str, int]]
    exhaustive: bool
    situations: int = 0
    unreachable: int = 0
    conflicts: list[str] = field(default_factory=list)  # the first MAX_CONFLICTS_SHOWN
    conflicts_total: int = 0
    no_solution: list[str] = field(default_factory=list)
    no_solution_count: int = 0
    worst_distance: int = 0
    worst_example: str = ""
    worst_exhaustive: bool = True
    combined_outputs: list[str] = field(default_factory=list)
    steps: int = 0  # work done, in the corrector's steps (constraints read)
    stopped: bool = False  # the work limit (MAX_ANALYSIS_STEPS) ended it early
    conflicts_stopped: bool = False  # ... before every pair of simple constraints was compared

    def lines(self, outputs: int) -> list[str]:
        variables = f"{len(self.variables)} uncontrollable variables"
        if self.stopped:
            how = (f"bounded: {self.situations} {'' if self.exhaustive else 'random '}"
                   f"situations of {variables}, stopped at the analysis's work limit of "
                   f"{MAX_ANALYSIS_STEPS:,} steps")
        elif self.exhaustive:
            how = f"exhaustive over {self.situations} situations of {variables}"
        else:
            how = f"bounded: {self.situations} random situations of {variables}"
        lines = [f"Safety filter analysis ({how})"]
        if self.unreachable:
            lines.append(f"  {self.unreachable} situations skipped as unreachable (previous "
                         "outputs violating an output-only constraint)")
        if self.conflicts:
            lines.append(f"  conflicts between simple constraints: "
                         f"{'at least ' if self.conflicts_stopped else ''}"
                         f"{self.conflicts_total}")
            lines += [f"    {c}" for c in self.conflicts]
            if self.conflicts_total > len(self.conflicts):
                lines.append(f"    ... and {self.conflicts_total - len(self.conflicts)} more")
        elif self.conflicts_stopped:
            lines.append("  conflicts between simple constraints: none found before the "
                         "work limit")
        else:
            lines.append("  conflicts between simple constraints: none")
        if self.no_solution_count:
            lines.append(f"  situations with no safe output vector (the filter falls back to "
                         f"the safe state): {self.no_solution_count}, e.g.")
            lines += [f"    {c}" for c in self.no_solution[:3]]
        else:
            lines.append("  situations with no safe output vector: none")
        scope = "" if self.worst_exhaustive else " (over sampled functional vectors)"
        lines.append(f"  worst-case Hamming distance the corrector may need: "
                     f"{self.worst_distance}{scope}"
                     + (f", e.g. {self.worst_example}" if self.worst_example else ""))
        lines.append(f"  outputs in combined constraints: {len(self.combined_outputs)} of "
                     f"{outputs}" + (f" ({', '.join(self.combined_outputs)})"
                                     if self.combined_outputs else ""))
        return lines


def _lit_text(name: str, depth: int, value: bool) -> str:
    text = name if depth == 0 else (f"prev({name})" if depth == 1 else f"prev({name}, {depth})")
    return text if value else f"not {text}"


def analyse(project: Project, seed: int = 0) -> FilterAnalysis:
    outputs = [v.name for v in project.outputs]
    # Each constraint: output masks and context literals (the filters' own table)
    table = lower_constraints(project)
    safe = table.safe
    items: list[_Item] = [(row.constraint, row.pos, row.neg, row.context)
                          for row in table.rows]
    variables = sorted({(lit.name, lit.depth) for _, _, _, ctx in items for lit in ctx})
    var_index = {v: i for i, v in enumerate(variables)}
    # Output-only constraints the safe state satisfies can be shifted to previous scans.
    invariants: list[tuple[str, int, int]] = []
    for c, pos, neg, ctx in items:
        violated_by_safe_state = safe & pos == pos and not safe & neg
        if not ctx and not violated_by_safe_state:
            invariants.append((c.name, pos, neg))
    # Every situation evaluates every constraint: bound that work (WORK), so that a project
    # of thousands of constraints is checked in about a second by sampling fewer situations
    # (the report says how many) rather than in minutes.
    per_situation = max(1, len(items))
    exhaustive = len(variables) <= EXHAUSTIVE_VARS and \
        (1 << len(variables)) * per_situation <= WORK
    samples = max(MIN_SAMPLES, min(SAMPLES, WORK // per_situation))
    analysis = FilterAnalysis(variables, exhaustive)
    in_combined = 0
    for c, p, n, _ in items:
        if c.kind == "combined":
            in_combined |= p | n
    analysis.combined_outputs = [outputs[k] for k in range(len(outputs)) if in_combined >> k & 1]
    # Everything below counts its work in the corrector's steps (one constraint read), and
    # stops at MAX_ANALYSIS_STEPS: a deterministic bound on the time `check` spends here
    # whatever the constraints (2,000 combined ones over 24 outputs took 46 CPU s unbounded).
    # (the pairs of simple constraints get half of it, so that the situations get the rest)
    conflicts, total, steps = _conflicts(items, outputs, invariants, MAX_ANALYSIS_STEPS // 2)
    analysis.conflicts, analysis.conflicts_total, analysis.steps = conflicts, total, steps
    analysis.conflicts_stopped = steps >= MAX_ANALYSIS_STEPS // 2

    # A situation is a bit mask over `variables`; a set of literals is (mask, wanted bits).
    def literals_mask(pairs) -> tuple[int, int] | None:
        mask = want = 0
        for key, value in pairs:
            i = var_index.get(key)
            if i is None:
                return None
            mask |= 1 << i
            if value:
                want |= 1 << i
        return mask, want

    # Previous outputs violating an output-only constraint: never written, so unreachable.
    depths = sorted({d for (_, d) in variables if d >= 1})
    unreachable_masks = []
    for _, pos, neg in invariants:
        for depth in depths:
            found = literals_mask([((name, depth), bool(pos >> k & 1))
                                   for k, name in enumerate(outputs) if (pos | neg) >> k & 1])
            if found is not None:
                unreachable_masks.append(found)
    contexts = [(c, pos, neg, literals_mask(((lit.name, lit.depth), lit.positive)
                                            for lit in ctx)) for c, pos, neg, ctx in items]

    situations: Iterator[tuple[bool, ...]]
    if analysis.exhaustive:
        situations = itertools.product((False, True), repeat=len(variables))
    else:
        rng = random.Random(seed)
        situations = (tuple(rng.random() < 0.5 for _ in variables) for _ in range(samples))
    fovs_exhaustive = len(outputs) <= EXHAUSTIVE_FOV_OUTPUTS
    analysis.worst_exhaustive = fovs_exhaustive
    rng = random.Random(seed + 1)
    all_bits = (1 << len(outputs)) - 1
    # Many situations activate the same constraints: the corrector's problem depends only on
    # (F0, F1, the active combined constraints), so each distinct problem is solved once.
    solvable: dict[tuple[object, ...], bool] = {}
    def prepare(combined: list[tuple[int, int]], unforced: int, forced: int) -> Problem:
        """One corrector problem, its preparation counted (a step per constraint and per
        literal: it is linear in them, and with thousands of active constraints it costs
        more than the search)."""
        analysis.steps += len(combined) + sum((p | n).bit_count() for p, n in combined)
        return Problem(combined, unforced, forced)

    def solve(problem: Problem, start: int):
        """The exact search within what is left of the work limit; None once it is used
        up."""
        left = MAX_ANALYSIS_STEPS - analysis.steps
        if left <= 0:
            analysis.stopped = True
            return None
        solution = problem.solve(start, budget=left)
        analysis.steps += solution.steps
        if solution.how == "budget" or analysis.steps > MAX_ANALYSIS_STEPS:
            analysis.stopped = True
            return None
        return solution

    for assign in situations:
        analysis.steps += len(items)  # each constraint's context read once
        if analysis.steps > MAX_ANALYSIS_STEPS:
            analysis.stopped = True
        if analysis.stopped:
            break
        analysis.situations += 1
        bits = sum(1 << i for i, value in enumerate(assign) if value)
        if any(bits & mask == want for mask, want in unreachable_masks):
            analysis.unreachable += 1
            continue
        active = [(c, pos, neg) for c, pos, neg, (mask, want) in contexts
                  if bits & mask == want]
        f0 = f1 = 0
        for c, pos, neg in active:
            if c.kind == "simple":
                if pos:
                    f0 |= pos
                else:
                    f1 |= neg
        combined = [(pos, neg) for c, pos, neg in active if c.kind == "combined"]
        key = (f0, f1, tuple(combined))
        seen = key in solvable
        problem = None
        if not (seen and solvable[key] and fovs_exhaustive) and not f0 & f1:
            # f1 is the forced outputs' values whatever the functional vector: one Problem
            # serves every vector tried in this situation
            problem = prepare(combined, all_bits & ~(f0 | f1), f1)
        if not seen:
            first = None if problem is None else solve(problem, f1)
            if analysis.stopped:
                analysis.situations -= 1  # not analysed to its end: not counted
                break
            solvable[key] = first is not None and first.vector is not None
        if seen and solvable[key] and fovs_exhaustive:
            continue  # every functional vector was already tried on this very problem
        situation = ", ".join(_lit_text(n, d, assign[var_index[(n, d)]]) for n, d in variables)
        if not solvable[key]:
            analysis.no_solution_count += 1
            if len(analysis.no_solution) < 3:
                forced = [outputs[k] for k in range(len(outputs)) if (f0 & f1) >> k & 1]
                why = (f"{', '.join(forced)} forced both ways" if forced
                       else "the combined constraints cannot all be satisfied")
                analysis.no_solution.append(f"{situation}: {why}")
            continue
        fovs = range(1 << len(outputs)) if fovs_exhaustive else (
            rng.getrandbits(len(outputs)) for _ in range(64))
        for fov in fovs:
            mem = (fov & ~f0) | f1
            assert problem is not None  # solvable: f0 and f1 are disjoint
            solution = solve(problem, mem)
            if solution is None:
                break
            if solution.vector is None:
                continue
            distance = (solution.vector ^ fov).bit_count()
            if distance > analysis.worst_distance:
                analysis.worst_distance = distance
                asked = " ".join(f"{o}={fov >> k & 1}" for k, o in enumerate(outputs))
                analysis.worst_example = f"FOV {asked} with {situation}"
    return analysis


def _conflicts(items, outputs, invariants, budget: int) -> tuple[list[str], int, int]:
    """The pairs of simple constraints forcing one output both ways in a common context:
    the first MAX_CONFLICTS_SHOWN described, how many there are in all, and the steps spent
    (a literal read is one). Only pairs on the same output are compared (grouped by output,
    not every pair of constraints); still, 5,000 forcing one output each way are 25 million
    pairs, so the comparison stops once `budget` steps are spent."""
    found = []
    total = 0
    steps = 0
    simple = [item for item in items if item[0].kind == "simple"]
    forcing1: dict[int, list] = {}  # output bit -> the constraints forcing it to 1
    for item in simple:
        if item[2]:
            forcing1.setdefault(item[2], []).append(item)
    pairs = ((a, b) for a in simple if a[1] for b in forcing1.get(a[1], ()))
    for (a, apos, _, actx), (b, _, _, bctx) in pairs:
        steps += 1 + len(actx) + len(bctx) + len(invariants)
        if steps >= budget:
            return found, total, budget
        joint: dict[tuple[str, int], bool] = {}
        compatible = True
        for lit in (*actx, *bctx):
            key = (lit.name, lit.depth)
            if joint.setdefault(key, lit.positive) != lit.positive:
                compatible = False
                break
        if compatible:
            for _, pos, neg in invariants:
                for depth in {d for (_, d) in joint if d >= 1}:
                    need = {(outputs[k], depth): True for k in range(len(outputs))
                            if pos >> k & 1}
                    need.update({(outputs[k], depth): False for k in range(len(outputs))
                                 if neg >> k & 1})
                    if all(joint.get(key) == value for key, value in need.items()):
                        compatible = False
        if compatible:
            total += 1
            if len(found) >= MAX_CONFLICTS_SHOWN:
                continue
            output = outputs[apos.bit_length() - 1]
            when = " and ".join(_lit_text(n, d, v) for (n, d), v in joint.items()) or "always"
            found.append(f"{a.name} forces {output} to 0 and {b.name} forces it to 1 when "
                         f"{when}")
    return found, total, steps

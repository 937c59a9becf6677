"""The safety filter as a function block (scan step 6): detection, policy, exact corrector.

It does what hmi/engine/filter.py and the masking around it (hmi/engine/diagnoser.py,
MaskedOutputStage) do, in the same order:

1. the candidate vector is the program's outputs (FOV), with the orders of a masked actuator
   partition forced to 0 (not under the monitor policy, which alters nothing);
2. a constraint is violated when its context (the literals over Y) holds and the candidate
   makes its output literals true; the violation word has bit j for constraint j. The
   constraints' table (POS, NEG, SIMPLE, SAFE), the detection (the word Violations), which
   are active (the word Act) and the policy are the scan program's
   (hmi.program.constraints), printed from the lowerings the engine prints as its
   ``violated``, ``active_bits`` and ``decide``: they are written once;
3. `monitor` passes the candidate; `block` latches the safe vector on the first violation
   until a fault reset (the policy's handler ``blocked``: ``Latched := TRUE``); `correct`
   (the handler ``corrected``) applies the simple constraints' F0/F1 (004 eq. 6) and then
   searches the safe vector at minimum Hamming distance over the unforced outputs of the
   active combined constraints, by increasing distance (every k-subset at distance k), and
   keeps, among those at the first distance that has any, the one the engine's tie-break
   prefers: fewest outputs switched on, then the outputs declared first spared (the set whose
   lowest-numbered output differs loses). That is the exact strategy's unique answer,
   whatever search the engine uses to find it. No safe vector (or F0 and F1 on one output):
   the safe vector;
4. masked orders are forced to 0 again (the mask has the last word), and a latched filter
   writes the safe vector.

The search stops at MAX_DISTANCE, the worst case the static checks (`plchmi check`) proved;
past it the safe vector is written. So the number of vectors one scan may test is known
before the PLC runs (:func:`vectors_bound`, docs/plc-export.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from typing import TYPE_CHECKING

from hmi.errors import ProjectError
from hmi.export import model as m
from hmi.export import source
from hmi.export.names import Scope
from hmi.export.program_st import Handler, NotPrintable, Place, Places, StPrinter
from hmi.export.views import Block, Durations, Views
from hmi.program.constraints import (
    ACTIVE,
    CANDIDATE,
    DECISION,
    LATCHED,
    MONITOR,
    POLICY,
    POLICY_CODES,
    VIOLATIONS,
)
from hmi.project.model import Project

if TYPE_CHECKING:
    from hmi.engine.filter_stage import FilterStage

FIXED = ("Policy", "Reset", "Ftc", "Violations", "Latched", "Fallback", "Tested", "Cand",
         "Mem", "F0", "F1", "Mask", "Free", "Flip", "Vec", "Best", "Diff", "OutV", "Act",
         "Idx", "Comb", "N", "K", "I", "J", "OnCount", "BestOn", "Found", "More", "Ok", "Better",
         "POS", "NEG", "SIMPLE", "SAFE", "MAX_DISTANCE")
WORDS = ("Cand", "Mem", "F0", "F1", "Mask", "Free", "Flip", "Vec", "Best", "Diff", "OutV")


def vectors_bound(free_outputs: int, max_distance: int) -> int:
    """Vectors the corrector may test in one scan: every k-subset for k = 0..max."""
    return sum(comb(free_outputs, k) for k in range(min(free_outputs, max_distance) + 1))


def max_distance(bound: source.FilterBound) -> int:
    """The search limit: the proven worst case, else every output (a complete search)."""
    return bound.worst_distance if bound.proven else bound.combined_outputs


@dataclass
class _Code:
    """Short names for the statements of this FB: its identifiers and its word type."""

    t: dict[str, str]
    word: str
    vword: str
    no: int
    nc: int

    def __call__(self, key: str) -> m.Name:
        return m.Name(self.t[key])

    def bits(self, value: int) -> m.BitsLit:
        return m.BitsLit(value, self.word)

    def bit(self, index: m.Expr) -> m.Expr:
        return m.Call("SHL", (self.bits(1), index))

    def at(self, key: str, index: m.Expr) -> m.Index:
        return m.Index(self(key), index)

    def nonzero(self, expr: m.Expr) -> m.Expr:
        return m.Binary("<>", expr, self.bits(0))

    def set(self, key: str, value: m.Expr) -> m.Assign:
        return m.Assign(self(key), value)

    def loop(self, var: str, last: m.Expr | int, *body: m.Stmt) -> m.For:
        end = m.IntLit(last) if isinstance(last, int) else last
        return m.For(self.t[var], m.IntLit(0), end, tuple(body))

    def active(self, index: m.Expr) -> m.Expr:
        """Constraint `index` is active (its bit of the word Act)."""
        one, zero = m.BitsLit(1, self.vword), m.BitsLit(0, self.vword)
        return m.Binary("<>", band(self("Act"), m.Call("SHL", (one, index))), zero)

    def violated(self, vec: str) -> m.Expr:
        """Combined constraint J (active) is made true by the vector `vec`."""
        j = self("J")
        return m.and_(self.active(j), m.not_(self.at("SIMPLE", j)),
                      m.eq(band(self(vec), self.at("POS", j)), self.at("POS", j)),
                      m.eq(band(self(vec), self.at("NEG", j)), self.bits(0)))


def band(a: m.Expr, b: m.Expr) -> m.Expr:
    return m.Binary("AND", a, b)


def bor(a: m.Expr, b: m.Expr) -> m.Expr:
    return m.Binary("OR", a, b)


def plus(a: m.Expr, b: int) -> m.Expr:
    return m.Binary("+", a, m.IntLit(b))


def minus(a: m.Expr, b: m.Expr | int) -> m.Expr:
    return m.Binary("-", a, m.IntLit(b) if isinstance(b, int) else b)


def build_filter(stage: FilterStage, project: Project, pou_name: str, scope: Scope,
                 bound: source.FilterBound) -> Block:
    """The engine's filter stage `stage` (of `project`) as FB `pou_name`: its lowering
    printed (the table, the active word, the violation word and the policy the engine's
    compiled scan prints as Python: FilterStage.functions), its policy's handler's calls as
    the statements below, its masking partitions as the mask, the search limited by
    `bound`."""
    lowered = stage.filter.program
    table = lowered.table
    outputs = source.outputs(project)
    rows = table.rows
    no, nc = len(table.outputs), len(rows)
    for count, what in ((no, "outputs"), (nc, "safety constraints")):
        if count > 64:
            raise ProjectError.single(project.pos, f"the project has {count} {what}: the "
                                      "export packs them in one 64-bit word", "at most 64")
    sc = scope.child()
    c = _Code({key: sc.take(key) for key in FIXED}, m.bits_type(no).name,
              m.bits_type(max(nc, 1)).name, no, nc)
    fov = {v.name: sc.take(f"FOV_{v.name}") for v in outputs}
    out = {v.name: sc.take(v.name) for v in outputs}
    views = Views(sc)
    index = {name: k for k, name in enumerate(table.outputs)}
    # Which constraints are active, which the candidate violates and what the policy does:
    # the stage's lowerings (the engine's active_bits, violated and decide), printed into
    # the words Act and Violations and the policy's IF; the corrector, the policy's handler
    # (the engine's SafetyFilter, which its calls name), is the search below (_correct)
    active = lowered.active
    handler = stage.filter
    places = Places(slot=_no_slot, read=views.name, step_time=_no_step_time,
                    locals={ACTIVE.name: Place(c.t["Act"], c.vword),
                            VIOLATIONS.name: Place(c.t["Violations"], c.vword),
                            CANDIDATE.name: Place(c.t["Cand"], c.word),
                            POLICY.name: Place(c.t["Policy"], "INT"),
                            LATCHED.name: Place(c.t["Latched"], "BOOL")},
                    unkept=frozenset({DECISION.name}))
    # the policy's handlers (hmi.program.constraints.HANDLERS) in this block: `blocked`
    # sets the latch, `corrected` is the search (_correct), `monitored` nothing
    places.handler(handler, "blocked", Handler(print=lambda printer, args: [
        c.set("Latched", m.TRUE)]))
    places.handler(handler, "corrected", Handler(print=lambda printer, args: list(
        _correct(c))))
    places.handler(handler, "monitored", Handler(print=lambda printer, args: []))
    printer = StPrinter(places, sc, Durations(), project.pos, "the safety filter")
    contexts: list[m.Stmt] = list(printer.block((active.start,)))
    for row, stmts in zip(rows, active.rows, strict=True):
        con = row.constraint
        always = "" if stmts else " (always active)"
        contexts.append(m.Comment(f"{con.name} ({con.kind}): {con.expr}{always}"))
        contexts += printer.block(stmts)
    masks = [(flag, sum(1 << index[o] for o in actuators))
             for flag, actuators in stage.masking]
    limit = max_distance(bound)

    scan: list[m.Stmt] = [m.Comment("1. The candidate vector: bit k is output k"),
                          c.set("Cand", c.bits(0))]
    for v in outputs:
        scan.append(m.if_(m.Name(fov[v.name]),
                          c.set("Cand", bor(c("Cand"), c.bits(1 << index[v.name])))))
    scan.append(c.set("Mask", c.bits(0)))
    if masks:
        scan.append(m.Comment("orders of an actuator partition the diagnosers distrust are "
                              "masked (000 eq. 9-10), except under the monitor policy"))
        for flag, mask in masks:
            scan.append(m.if_(m.and_(c("Ftc"), views.name(flag)),
                              c.set("Mask", bor(c("Mask"), c.bits(mask)))))
        scan.append(m.if_(m.Binary("<>", c("Policy"), m.IntLit(MONITOR)),
                          c.set("Cand", band(c("Cand"), m.not_(c("Mask"))))))
    scan += [c.set("Tested", m.IntLit(0)), c.set("Fallback", m.FALSE),
             c.set("OutV", c("Cand"))]
    scan.append(m.Comment("2. Detection: bit j of Violations, constraint j violated by the "
                          "candidate (its literals over the outputs and over Y)"))
    scan += printer.block(lowered.violations)
    if nc:
        scan.append(m.Comment("Contexts (the literals over Y): bit j of Act, constraint j "
                              "active (what the corrector searches against)"))
        scan += contexts
        scan.append(m.Comment("3. The policy: 0 monitor, 1 block, 2 (or anything else) "
                              "correct"))
        scan += printer.block(lowered.policy)
    scan.append(m.Comment("4. No safe vector: the safe state; the mask has the last word; "
                          "a latched filter writes the safe state"))
    scan.append(m.if_(c("Fallback"), c.set("OutV", c("SAFE"))))
    scan.append(m.if_(m.Binary("<>", c("Policy"), m.IntLit(MONITOR)),
                      c.set("OutV", band(c("OutV"), m.not_(c("Mask"))))))
    scan.append(m.if_(c("Latched"), c.set("OutV", c("SAFE"))))
    for v in outputs:
        scan.append(m.Assign(m.Name(out[v.name]),
                             c.nonzero(band(c("OutV"), c.bits(1 << index[v.name])))))
    body = (m.Comment("Reset: a fault reset releases the latch (a call of its own, after the "
                      "scan, as the engine resets between scans)"),
            m.If(((c("Reset"), (c.set("Latched", m.FALSE),)),), tuple(scan)))

    nout = m.Elementary(c.word)
    last = max(nc, 1) - 1
    blocks = (
        m.VarBlock("input", (
            m.Var(c.t["Policy"], m.INT, m.IntLit(POLICY_CODES[source.policy(project)]),
                  comment="0 monitor, 1 block, 2 correct (other values: correct)"),
            m.Var(c.t["Reset"], m.BOOL, comment="TRUE: a fault reset (a call of its own)"),
            m.Var(c.t["Ftc"], m.BOOL, m.TRUE, comment="diagnosers in FTC mode: masks apply"),
            *(m.Var(fov[v.name], m.BOOL, comment=f"the program's {v.name}") for v in outputs),
            *(m.Var(ident, m.BOOL) for ident in views.idents.values()),
        )),
        m.VarBlock("output", (
            *(m.Var(out[v.name], m.BOOL, comment=v.description) for v in outputs),
            m.Var(c.t["Violations"], m.Elementary(c.vword),
                  comment="bit j: constraint j violated by the candidate"),
            m.Var(c.t["Latched"], m.BOOL, comment="block policy: outputs held safe until reset"),
            m.Var(c.t["Fallback"], m.BOOL, comment="correct policy: no safe vector, safe state"),
            m.Var(c.t["Tested"], m.DINT, comment="vectors the corrector tested this scan"),
        )),
        m.VarBlock("local", (
            *(m.Var(c.t[k], nout) for k in WORDS),
            m.Var(c.t["Act"], m.Elementary(c.vword), comment="bit j: constraint j is active"),
            m.Var(c.t["Idx"], m.Array(0, max(no, 1) - 1, m.INT), comment="the free outputs"),
            m.Var(c.t["Comb"], m.Array(0, max(no, 1) - 1, m.INT),
                  comment="a k-subset of Idx"),
            *(m.Var(c.t[k], m.INT) for k in ("N", "K", "I", "J", "OnCount", "BestOn")),
            *(m.Var(c.t[k], m.BOOL) for k in ("Found", "More", "Ok", "Better")),
        )),
        m.VarBlock("local", (
            m.Var(c.t["POS"], m.Array(0, last, nout),
                  m.ArrayInit(tuple(c.bits(row.pos) for row in rows) or (c.bits(0),)),
                  comment="outputs at 1 in constraint j"),
            m.Var(c.t["NEG"], m.Array(0, last, nout),
                  m.ArrayInit(tuple(c.bits(row.neg) for row in rows) or (c.bits(0),)),
                  comment="outputs at 0 in constraint j"),
            m.Var(c.t["SIMPLE"], m.Array(0, last, m.BOOL),
                  m.ArrayInit(tuple(m.BoolLit(row.simple) for row in rows)
                              or (m.BoolLit(False),))),
            m.Var(c.t["SAFE"], nout, c.bits(table.safe), comment="the safe vector"),
            m.Var(c.t["MAX_DISTANCE"], m.INT, m.IntLit(limit),
                  comment="search limit: plchmi check's worst case"),
        ), constant=True),
    )
    order = ", ".join(f"{k} {name}" for k, name in enumerate(table.outputs))
    cons = ", ".join(f"{j} {row.constraint.name}" for j, row in enumerate(rows))
    simple = [row.simple for row in rows]
    comment = (
        "Scan step 6, the safety filter (004): detection, policy, exact corrector.\n"
        f"Output bits: {order}.\nViolation bits: {cons}.\n"
        f"Corrector budget: at most {vectors_bound(bound.combined_outputs, limit)} vectors "
        f"tested per scan ({bound.combined_outputs} outputs in combined constraints, "
        f"MAX_DISTANCE {limit}), each a loop over the {nc} constraints "
        f"({sum(not s for s in simple)} combined).")
    pou = m.Pou(pou_name, "functionBlock", blocks, body, comment)
    ports = {k: c.t[k] for k in ("Violations", "Latched", "Fallback", "Tested", "Policy",
                                 "Reset", "Ftc")}
    return Block(pou, dict(views.idents), out,
                 {**ports, **{f"FOV_{k}": v for k, v in fov.items()}})


def _no_slot(index: int) -> Place:
    raise NotPrintable(f"the safety filter reads no image slot ({index})")


def _no_step_time(step: str) -> m.Expr:
    raise NotPrintable(f"the safety filter reads no step time ({step})")


def _correct(c: _Code) -> tuple[m.Stmt, ...]:
    """The `correct` branch: F0/F1, then the exact search (see the module's docstring)."""
    j, i, k = c("J"), c("I"), c("K")
    search = (
        c.set("Mem", bor(band(c("Cand"), m.not_(c("F0"))), c("F1"))),
        c.set("Free", band(c("Free"), m.not_(bor(c("F0"), c("F1"))))),
        m.Comment("the free outputs: unforced outputs of the active combined constraints"),
        c.set("N", m.IntLit(0)),
        c.loop("I", c.no - 1, m.if_(c.nonzero(band(c("Free"), c.bit(i))),
                                    m.Assign(c.at("Idx", c("N")), i),
                                    c.set("N", plus(c("N"), 1)))),
        m.Comment("every k-subset of the free outputs, k = 0, 1, ... until a distance has a "
                  "safe vector"),
        c.set("Found", m.FALSE),
        c.set("K", m.IntLit(0)),
        m.While(m.and_(m.not_(c("Found")), m.Binary("<=", k, c("N")),
                       m.Binary("<=", k, c("MAX_DISTANCE"))), (
            c.loop("I", minus(k, 1), m.Assign(c.at("Comb", i), i)),
            c.set("More", m.TRUE),
            m.While(c("More"), (
                c.set("Flip", c.bits(0)),
                c.loop("I", minus(k, 1),
                       c.set("Flip", bor(c("Flip"), c.bit(c.at("Idx", c.at("Comb", i)))))),
                c.set("Vec", m.Binary("XOR", c("Mem"), c("Flip"))),
                c.set("Tested", plus(c("Tested"), 1)),
                c.set("Ok", m.TRUE),
                c.loop("J", c.nc - 1, m.if_(c.violated("Vec"),
                                            c.set("Ok", m.FALSE), m.Exit())),
                m.if_(c("Ok"), *_keep_best(c)),
                m.Comment("the next k-subset (lexicographic order)"),
                c.set("More", m.FALSE),
                m.For(c.t["I"], minus(k, 1), m.IntLit(0), (
                    m.if_(m.Binary("<", c.at("Comb", i), m.Binary("+", minus(c("N"), k), i)),
                          m.Assign(c.at("Comb", i), plus(c.at("Comb", i), 1)),
                          m.For(c.t["J"], plus(i, 1), minus(k, 1), (
                              m.Assign(c.at("Comb", j), plus(c.at("Comb", minus(j, 1)), 1)),)),
                          c.set("More", m.TRUE),
                          m.Exit()),), step=-1),
            )),
            c.set("K", plus(k, 1)),
        )),
        m.If(((c("Found"), (c.set("OutV", m.Binary("XOR", c("Mem"), c("Best"))),)),),
             orelse=(m.Comment("no safe vector within MAX_DISTANCE"),
                     c.set("Fallback", m.TRUE))),
    )
    return (
        c.set("F0", c.bits(0)), c.set("F1", c.bits(0)), c.set("Free", c.bits(0)),
        c.loop("J", c.nc - 1, m.If((
            (m.and_(c.active(j), c.at("SIMPLE", j)),
             (c.set("F0", bor(c("F0"), c.at("POS", j))),
              c.set("F1", bor(c("F1"), c.at("NEG", j))))),
            (c.active(j), (c.set("Free", bor(c("Free"), bor(c.at("POS", j),
                                                               c.at("NEG", j)))),)),
        ))),
        m.If(((c.nonzero(band(c("F0"), c("F1"))),
               (m.Comment("simple constraints force an output both to 0 and to 1"),
                c.set("Fallback", m.TRUE))),), orelse=search),
    )


def _keep_best(c: _Code) -> tuple[m.Stmt, ...]:
    """Keep the safe vector if the tie-break prefers it to the best one so far."""
    i = c("I")
    return (
        c.set("OnCount", m.IntLit(0)),
        c.set("Diff", band(c("Flip"), m.not_(c("Mem")))),
        c.loop("I", c.no - 1, m.if_(c.nonzero(band(c("Diff"), c.bit(i))),
                                    c.set("OnCount", plus(c("OnCount"), 1)))),
        m.Comment("fewest outputs switched on, then spare the outputs declared first"),
        c.set("Better", m.or_(m.not_(c("Found")), m.Binary("<", c("OnCount"), c("BestOn")))),
        m.if_(m.and_(c("Found"), m.eq(c("OnCount"), c("BestOn"))),
              c.set("Diff", m.Binary("XOR", c("Flip"), c("Best"))),
              c.loop("I", c.no - 1, m.if_(c.nonzero(band(c("Diff"), c.bit(i))),
                                          c.set("Better", c.nonzero(band(c("Best"),
                                                                         c.bit(i)))),
                                          m.Exit()))),
        m.if_(c("Better"), c.set("Best", c("Flip")), c.set("BestOn", c("OnCount")),
              c.set("Found", m.TRUE)),
    )

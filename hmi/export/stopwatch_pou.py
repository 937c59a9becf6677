"""The stopwatch monitor of one interruptible task (002), as hmi/engine/stopwatch.py runs it.

One function block type for every task; the calling program evaluates each task's start,
end and interruption conditions and passes them with the task's [alpha, beta, gamma].

The stopwatches are built as 002 §3 builds them in GRAFCET, from timers and shifting
variables: x (time since the start) is the TON `TX`, running through executing (l2) and
interrupted (l3), so its shifting variable stays 0 and is left out; y (effective work) is
`DY + TY.ET`, where the TON `TY` runs in executing only and the shifting action
`DY := DY + TY.ET` is done on leaving executing (002's `↓ δy := δy + x_Tj`). Each scan:
the stopwatches are read (the location held since the previous scan decided which ran),
this scan's observations move the location, the rules are checked on the exact values, and
the timers are re-armed for the location entered. The fault condition is the complement of
Property 1's acceptable space (002 §2.3, §4: `(δx + x_T) - δy >= gamma - alpha`), see
docs/monitors.md.
"""

from __future__ import annotations

from hmi.export import model as m
from hmi.export.names import Scope
from hmi.export.views import TMAX_MS

WAITING, EXECUTING, INTERRUPTED, FAULTY = 0, 1, 2, 3
RULES = {1: "cannot_finish", 2: "deadline", 3: "overrun", 4: "late_end", 5: "too_fast"}
RULE_CODES = {name: code for code, name in RULES.items()}
FIXED = ("Start", "Finish", "Suspend", "Resume", "Alpha", "Beta", "Gamma", "Reset",
         "Location", "X", "Y", "Fault", "Rule", "FaultX", "FaultY", "Attempt", "Faults",
         "Completed", "Phase", "AttemptFault", "TX", "TY", "DY", "Verdict")


def build_stopwatch(pou_name: str, scope: Scope) -> tuple[m.Pou, dict[str, str]]:
    sc = scope.child()
    t = {key: sc.take(key) for key in FIXED}

    def v(key: str) -> m.Name:
        return m.Name(t[key])

    def set_(key: str, value: m.Expr | int) -> m.Assign:
        return m.Assign(v(key), m.IntLit(value) if isinstance(value, int) else value)

    def is_(key: str, value: int) -> m.Expr:
        return m.eq(v(key), m.IntLit(value))

    def incr(key: str) -> m.Assign:
        return set_(key, m.Binary("+", v(key), m.IntLit(1)))

    zero = m.TimeLit(0)
    tmax = m.TimeLit(TMAX_MS)
    x, y = v("X"), v("Y")
    alpha, beta, gamma = v("Alpha"), v("Beta"), v("Gamma")
    running = m.Binary("<>", v("Phase"), m.IntLit(WAITING))
    judge_end = m.If((
        (m.Binary(">=", x, gamma), (set_("Verdict", RULE_CODES["late_end"]),)),
        (m.Binary(">", y, beta), (set_("Verdict", RULE_CODES["overrun"]),)),
        (m.Binary("<", y, alpha), (set_("Verdict", RULE_CODES["too_fast"]),)),
    ))
    judge_running = m.If((
        (m.and_(m.Binary("<", y, alpha),
                m.Binary(">=", m.Binary("+", x, m.Binary("-", alpha, y)), gamma)),
         (set_("Verdict", RULE_CODES["cannot_finish"]),)),
        (m.and_(m.Binary(">=", y, alpha), m.Binary(">=", x, gamma)),
         (set_("Verdict", RULE_CODES["deadline"]),)),
        (m.or_(m.Binary(">", y, beta), m.and_(m.eq(y, beta), is_("Phase", EXECUTING))),
         (set_("Verdict", RULE_CODES["overrun"]),)),
    ))
    step = (
        m.Comment("read the stopwatches (the location held since the previous scan ran them)"),
        m.FbCall(t["TX"], (("IN", running), ("PT", tmax))),
        m.FbCall(t["TY"], (("IN", is_("Phase", EXECUTING)), ("PT", tmax))),
        set_("Verdict", 0),
        m.If(((is_("Phase", WAITING),
               (m.if_(v("Start"),
                      m.Comment("l1 -> l2: a new attempt, x = y = 0"),
                      set_("Phase", EXECUTING), incr("Attempt"),
                      set_("AttemptFault", m.FALSE), set_("DY", zero), set_("X", zero),
                      set_("Y", zero),
                      m.if_(v("Suspend"), set_("Phase", INTERRUPTED))),)),),
             orelse=(
            set_("X", m.Member(v("TX"), "ET")),
            set_("Y", m.Binary("+", v("DY"), m.Member(v("TY"), "ET"))),
            m.If(((v("Finish"), (
                m.Comment("the end: judged against Property 1"), judge_end,
                m.if_(m.and_(is_("Verdict", 0), m.not_(v("AttemptFault"))), incr("Completed")),
                set_("Phase", WAITING))),),
                orelse=(
                m.If((
                    (m.and_(is_("Phase", EXECUTING), v("Suspend")),
                     (m.Comment("l2 -> l3, shifting action: y is kept in DY"),
                      set_("DY", y), set_("Phase", INTERRUPTED))),
                    (m.and_(is_("Phase", INTERRUPTED), v("Resume")),
                     (set_("Phase", EXECUTING),)),
                )),
                m.Comment("can the task still end inside [alpha, gamma) with y <= beta?"),
                judge_running)),
            m.if_(m.and_(m.Binary("<>", v("Verdict"), m.IntLit(0)), m.not_(v("AttemptFault"))),
                  set_("AttemptFault", m.TRUE), incr("Faults"),
                  m.if_(m.not_(v("Fault")), set_("Fault", m.TRUE), set_("Rule", v("Verdict")),
                        set_("FaultX", x), set_("FaultY", y))),
        )),
        m.Comment("re-arm the timers for the location entered at this scan"),
        m.FbCall(t["TX"], (("IN", running),)),
        m.FbCall(t["TY"], (("IN", is_("Phase", EXECUTING)),)),
    )
    location = m.If(((v("Fault"), (set_("Location", FAULTY),)),),
                    orelse=(set_("Location", v("Phase")),))
    body = (
        m.If(((v("Reset"), (
            m.Comment("fault reset: released unless the attempt that failed is still running"),
            m.if_(m.and_(v("Fault"), m.not_(m.and_(running, v("AttemptFault")))),
                  set_("Fault", m.FALSE), set_("Rule", 0)),)),), orelse=step),
        location,
    )
    blocks = (
        m.VarBlock("input", (
            m.Var(t["Start"], m.BOOL, comment="the task starts (looked at while waiting)"),
            m.Var(t["Finish"], m.BOOL, comment="the task ends (looked at while running)"),
            m.Var(t["Suspend"], m.BOOL, comment="interruption (while executing)"),
            m.Var(t["Resume"], m.BOOL, comment="resumption (while interrupted)"),
            m.Var(t["Alpha"], m.TIME), m.Var(t["Beta"], m.TIME), m.Var(t["Gamma"], m.TIME),
            m.Var(t["Reset"], m.BOOL, comment="TRUE: a fault reset (a call of its own)"),
        )),
        m.VarBlock("output", (
            m.Var(t["Location"], m.INT,
                  comment="0 waiting (l1), 1 executing (l2), 2 interrupted (l3), 3 faulty"),
            m.Var(t["X"], m.TIME, comment="time since the start"),
            m.Var(t["Y"], m.TIME, comment="effective work"),
            m.Var(t["Fault"], m.BOOL, comment="the fault label, latched until a reset"),
            m.Var(t["Rule"], m.INT, comment="1 cannot_finish, 2 deadline, 3 overrun, "
                  "4 late_end, 5 too_fast"),
            m.Var(t["FaultX"], m.TIME), m.Var(t["FaultY"], m.TIME),
            m.Var(t["Attempt"], m.DINT), m.Var(t["Faults"], m.DINT),
            m.Var(t["Completed"], m.DINT, comment="attempts ended in time"),
        )),
        m.VarBlock("local", (
            m.Var(t["Phase"], m.INT, comment="the task as observed: 0, 1, 2"),
            m.Var(t["AttemptFault"], m.BOOL),
            m.Var(t["TX"], m.Derived("TON"), comment="stopwatch x"),
            m.Var(t["TY"], m.Derived("TON"), comment="stopwatch y since the last resumption"),
            m.Var(t["DY"], m.TIME, comment="shifting variable of y"),
            m.Var(t["Verdict"], m.INT),
        )),
    )
    comment = ("Stopwatch monitor of an interruptible task (002): x and y from TONs and a "
               "shifting variable; the fault as soon as the task can no longer end inside "
               "[alpha, gamma) with y in [alpha, beta].")
    return m.Pou(pou_name, "functionBlock", blocks, body, comment), t

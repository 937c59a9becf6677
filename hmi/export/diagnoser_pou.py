"""A local diagnoser as a function block (scan steps 3-4), as hmi/engine/diagnoser.py runs it.

* **Conditions read what the project writes**: the FB's input `O` is the order O *as the
  diagnoser observes it*, i.e. written at the previous scan (the engine compiles every output
  one scan further back); the calling program wires `O := prev_O`. Inputs, timers and
  observers are read at this scan.
* **Time in state** is a TON started when the state is entered (`InState.ET`), so windows
  are `InState.ET >= tmin AND InState.ET < tmax` and a timeout is `InState.ET >= after`. The
  current state's event transitions are tried in file order, the timeout last: one
  transition per scan, an event wins over a timeout at the same scan.
* **Gaps**: a call more than 10 scan periods after the previous one (the interval measured by
  the TON `Clock`, the period the task's nominal one: never an interval measured, so a late
  cycle's catch-up does not make the next normal one a gap) means the plant was not
  observed: a normal state goes back to the initial one, a faulty one keeps its decision with
  its clock frozen over the gap (`Frozen`).
* **Decision, flags, reconstruction**: each label is true in the states that decide it; a
  partition flag `def_p` while the decision holds one of its labels; a sensor partition gives
  `x_filter = not def and x or def and x_hat` (000 eq. 7-8) in FTC mode (`Mode = 0`), the
  sensor itself otherwise. Actuator masks are applied by the filter FB.
* **Fault reset** is a call of its own with `Reset := TRUE`, after the scan (the engine
  resets between scans): a faulty diagnoser re-synchronises to the first resync rule that
  holds on the values of the scan just ended, entered at that scan's time; its flags follow
  at the next scan, as in the engine.
* `Mode`: 0 FTC, 1 observe (flags set, nothing uses them), 2 off (not run, flags 0); any
  other value is FTC, the mode that protects the plant.
"""

from __future__ import annotations

from hmi.export import model as m
from hmi.export import source
from hmi.export.names import Scope
from hmi.export.views import TMAX_MS, Block, Durations, Views, convert
from hmi.project.model import DiagnoserSpec, Project

FTC, OBSERVE, OFF = 0, 1, 2
MODE_CODES = {"ftc": FTC, "observe": OBSERVE, "off": OFF}


def ftc_mode(mode: m.Expr) -> m.Expr:
    """FTC unless the mode says observe or off (an unknown value is FTC)."""
    return m.and_(m.Binary("<>", mode, m.IntLit(OBSERVE)), m.Binary("<>", mode, m.IntLit(OFF)))
FIXED = ("Mode", "Reset", "State", "Faulty", "Started", "Ftc", "Next", "InState", "Tis",
         "Clock", "Delta", "Period", "Frozen")


def build_diagnoser(project: Project, spec: DiagnoserSpec, pou_name: str, scope: Scope,
                    durations: Durations) -> Block:
    sc = scope.child()
    t = {key: sc.take(key) for key in FIXED}
    labels = {lab: sc.take(lab) for lab in spec.labels}
    flags = {p.flag: sc.take(p.flag) for p in spec.partitions}
    filtered = {p.filtered: sc.take(p.filtered) for p in spec.partitions if p.filtered}
    views = Views(sc)
    numbers = {s.name: k for k, s in enumerate(spec.states)}
    initial = numbers[spec.initial]

    def v(key: str) -> m.Name:
        return m.Name(t[key])

    def resolve(name: str, depth: int) -> m.Expr:
        return views.name(name, depth)

    tmax = m.TimeLit(TMAX_MS)
    in_state = v("Tis")

    def go(target: str) -> m.Stmt:
        return m.Assign(v("Next"), m.IntLit(numbers[target]))

    # Entering a state: its number, its clock restarted at this scan, nothing frozen.
    enter_next = m.if_(m.Binary(">=", v("Next"), m.IntLit(0)),
                       m.Assign(v("State"), v("Next")),
                       m.FbCall(t["InState"], (("IN", m.FALSE),)),
                       m.FbCall(t["InState"], (("IN", m.TRUE), ("PT", tmax))),
                       m.Assign(v("Frozen"), m.TimeLit(0)))

    cases: list[tuple[tuple[int, ...], tuple[m.Stmt, ...]]] = []
    for state in spec.states:
        branches: list[tuple[m.Expr, tuple[m.Stmt, ...]]] = []
        timeout = None
        for tr in spec.transitions:
            if tr.source != state.name:
                continue
            what = f"transition {tr.index} ({tr.text()})"
            if tr.when is None:
                timeout = tr
                continue
            terms = []
            if tr.tmin_us:
                terms.append(m.Binary(">=", in_state, durations.time(
                    tr.tmin_us, tr.pos, f"the window of {what}")))
            if tr.tmax_us is not None:
                terms.append(m.Binary("<", in_state, durations.time(
                    tr.tmax_us, tr.pos, f"the window of {what}")))
            terms.append(convert(tr.when.root, resolve))
            branches.append((m.and_(*terms), (m.Comment(tr.text()), go(tr.target))))
        if timeout is not None:
            after = durations.time(timeout.after_us or 0, timeout.pos,
                                   f"the timeout of transition {timeout.index}")
            branches.append((m.Binary(">=", in_state, after),
                             (m.Comment(timeout.text()), go(timeout.target))))
        if branches:
            cases.append(((numbers[state.name],), (m.If(tuple(branches)),)))

    resync: list[tuple[m.Expr, tuple[m.Stmt, ...]]] = []
    reset_reads: dict[tuple[str, int], None] = {}
    for k, rule in enumerate(spec.resync, start=1):
        for ref in source.refs(rule.when):
            reset_reads.setdefault(ref)
        resync.append((convert(rule.when.root, resolve),
                       (m.Comment(f"resync rule {k}: {rule.when} -> {rule.target}"),
                        go(rule.target))))

    decide: list[m.Stmt] = []
    for label, ident in labels.items():
        states = [numbers[s.name] for s in spec.states if label in s.labels]
        decide.append(m.Assign(m.Name(ident), m.or_(*(m.eq(v("State"), m.IntLit(n))
                                                      for n in states))))
    for p in spec.partitions:
        decide.append(m.Assign(m.Name(flags[p.flag]),
                               m.or_(*(m.Name(labels[lab]) for lab in p.labels))))
    decide.append(m.Assign(v("Faulty"), m.or_(*(m.Name(i) for i in labels.values()))))
    route: list[m.Stmt] = []
    for p in spec.partitions:
        if p.filtered and p.sensor and p.estimate:
            trust = m.and_(v("Ftc"), m.Name(flags[p.flag]))
            route.append(m.Comment(f"{p.filtered} = not def and {p.sensor} or def and "
                                   f"{p.estimate} (000 eq. 7-8), in FTC mode"))
            route.append(m.Assign(m.Name(filtered[p.filtered]), m.or_(
                m.and_(m.not_(trust), views.name(p.sensor)),
                m.and_(trust, views.name(p.estimate)))))
    off: list[m.Stmt] = [m.Assign(m.Name(ident), m.FALSE) for ident in flags.values()]
    off += [m.Assign(m.Name(filtered[p.filtered]), views.name(p.sensor))
            for p in spec.partitions if p.filtered and p.sensor]

    clock = m.Member(v("Clock"), "ET")
    step: list[m.Stmt] = [
        m.Comment("the time since the previous call: a gap longer than 10 periods means the "
                  "plant was not observed"),
        m.FbCall(t["Clock"], (("IN", m.TRUE), ("PT", tmax))),
        m.Assign(v("Delta"), clock),
        m.FbCall(t["Clock"], (("IN", m.FALSE),)),
        m.FbCall(t["Clock"], (("IN", m.TRUE),)),
        m.if_(m.and_(v("Started"),
                     m.Binary(">", v("Delta"), m.Binary("*", v("Period"), m.IntLit(10)))),
              m.If(((v("Faulty"), (m.Assign(v("Frozen"), m.Binary(
                  "-", m.Binary("+", v("Frozen"), v("Delta")), v("Period"))),)),
                    (m.Binary("<>", v("State"), m.IntLit(initial)),
                     (m.Comment("re-synchronise"), go(spec.initial), enter_next))))),
        m.Assign(v("Started"), m.TRUE),
        m.Assign(v("Next"), m.IntLit(-1)),
        m.FbCall(t["InState"], (("IN", m.TRUE), ("PT", tmax))),
        m.Assign(v("Tis"), m.Binary("-", m.Member(v("InState"), "ET"), v("Frozen"))),
        m.Comment("one transition per scan: events in file order, then the timeout"),
    ]
    if cases:
        step.append(m.Case(v("State"), tuple(cases)))
        step.append(enter_next)
    step += decide + route
    body = (
        m.Assign(v("Ftc"), ftc_mode(v("Mode"))),
        m.If((
            (m.eq(v("Mode"), m.IntLit(OFF)), (m.Comment("off: not run, flags 0"), *off)),
            (v("Reset"), (m.Comment("fault reset: re-synchronise a faulty diagnoser"),
                          *((m.Assign(v("Next"), m.IntLit(-1)),
                             m.if_(v("Faulty"), m.If(tuple(resync))), enter_next)
                            if resync else ()))),
        ), tuple(step)),
    )

    state_list = ", ".join(f"{k} {s.name}" + (f" {{{', '.join(s.labels)}}}" if s.labels else "")
                           for k, s in enumerate(spec.states))
    blocks = (
        m.VarBlock("input", (
            m.Var(t["Mode"], m.INT, comment="0 FTC, 1 observe, 2 off (other values: FTC)"),
            m.Var(t["Reset"], m.BOOL, comment="TRUE: a fault reset (a call of its own)"),
            *(m.Var(ident, m.BOOL) for ident in views.idents.values()),
        )),
        m.VarBlock("output", (
            m.Var(t["State"], m.INT, m.IntLit(initial), comment="see the state numbers above"),
            m.Var(t["Faulty"], m.BOOL, comment="the decision holds a label"),
            *(m.Var(ident, m.BOOL, comment=spec.label_text(lab)) for lab, ident in
              labels.items()),
            *(m.Var(ident, m.BOOL, comment=f"partition {p.name}") for p, ident in
              zip(spec.partitions, flags.values(), strict=True)),
            *(m.Var(ident, m.BOOL) for ident in filtered.values()),
        )),
        m.VarBlock("local", (
            m.Var(t["Started"], m.BOOL),
            m.Var(t["Ftc"], m.BOOL),
            m.Var(t["Next"], m.INT, comment="the state entered at this scan, -1 none"),
            m.Var(t["InState"], m.Derived("TON"), comment="since the current state was entered"),
            m.Var(t["Tis"], m.TIME, comment="time in the current state"),
            m.Var(t["Clock"], m.Derived("TON"), comment="time since the previous call"),
            m.Var(t["Delta"], m.TIME),
            m.Var(t["Period"], m.TIME, m.TimeLit(project.scan_period_us // 1000),
                  comment="the task's nominal period (the project's scan period)"),
            m.Var(t["Frozen"], m.TIME, comment="time in state not counted (gaps)"),
        )),
    )
    comment = (f"Scan steps 3-4: local diagnoser {spec.name}"
               + (f" ({spec.description})" if spec.description else "") + ".\n"
               f"States: {state_list}.\n"
               "An output O among the inputs is the order written at the previous scan.")
    pou = m.Pou(pou_name, "functionBlock", blocks, body, comment)
    ports = {k: t[k] for k in ("Mode", "Reset", "State", "Faulty")}
    ports.update({f"label:{lab}": ident for lab, ident in labels.items()})
    return Block(pou, dict(views.idents), {**flags, **filtered}, ports, tuple(reset_reads))

"""The `diagnosers:` section: local diagnosers as timed automata (000 §2.1, §3.1).

    diagnosers:
      V1:
        description: Valve V1 local diagnoser
        device: Valve V1
        labels: {F1: fsc stuck at 0, ...}             # operator text of every fault label
        partitions:
          fsc: {labels: [F1, F2, F7, F8], sensor: fsc, estimate: fsc_hat}
          V:   {labels: [F5, F6, F11, F12, F13], actuators: [C, O]}
        initial: N0
        states:
          N1: {description: Closed at rest}
          B1: {labels: [F1, F8, F11], description: fsc fell at closed rest}
        transitions:
          - {from: N1, to: N2, when: O}
          - {from: N2, to: N3, when: not fsc, within: [0ms, 300ms]}
          - {from: N2, to: B2, after: 300ms}
        resync:
          - {when: fsc and not fso and not C and not O, to: N1}

Names it declares: a flag `def_<partition>` per partition (true while the diagnoser's
decision holds one of the partition's labels) and, per sensor partition, `<sensor>_filter`
(the sensor, or its estimate while the flag is set: 000 eq. 7-8). Both are computed after the
memory phase and before the control law: constraints and the control law read them at t;
timers and observers only through prev().

What a diagnoser's conditions read: inputs at t, timers and observers (already updated this
scan), and outputs *as written at the previous scan* — the filtered orders, which is what the
diagnoser observes (000 §2: it "does not use directly the orders sent by the controller but
the orders validated by the filter"). So in a diagnoser `O` means the order written at t-1
and `rise(O)` that it rose then; the engine compiles every output one scan further back.

Windows are half-open, [tmin, tmax): an event exactly at tmax is late, which is what the
timeout `after: tmax` then says. Validation (file:line:column) covers names, labels and
partitions, determinism (two event transitions of one state whose windows overlap and whose
conditions can hold together, decided by enumerating the variables involved), faulty to
normal transitions (a faulty decision is latched), the initial state, and unreachable states
(a warning).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING

from hmi.errors import SourcePos
from hmi.limits import MAX_DETERMINISM_ASSIGNMENTS
from hmi.logic.expr import (
    And,
    Const,
    Expr,
    Node,
    Not,
    NotMonomial,
    Or,
    Var,
    monomial_literals,
    walk,
)
from hmi.logic.names import NAME_RE
from hmi.project.model import (
    FILTERED_SUFFIX,
    FLAG_PREFIX,
    DiagnoserSpec,
    DiagState,
    DiagTransition,
    Partition,
    ResyncRule,
)
from hmi.project.yamlnodes import YNode
from hmi.timefmt import format_duration

if TYPE_CHECKING:
    from hmi.project.model import Project
    from hmi.project.reader import ProjectReader

DIAG_KINDS = {"input", "output", "timer", "observer"}
DIAG_CONTEXT = ("in a diagnoser (it observes inputs, the orders written at the previous scan, "
                "timers and observers, never the control law nor the flags it sets)")
ESTIMATE_KINDS = {"input", "timer", "observer"}
DIAGNOSER_KEYS = {"description", "device", "labels", "partitions", "initial", "states",
                  "transitions", "resync", "variants"}
MAX_ENUMERATED_VARS = 16
INF = None  # no upper bound on a window


def diagnosers_of(project: Project) -> tuple[DiagnoserSpec, ...]:
    return project.diagnosers


def layout_names(project: Project) -> list[tuple[str, str]]:
    """Extra image slots: every partition flag, then every filtered sensor."""
    specs = diagnosers_of(project)
    names = [(p.flag, "flag") for d in specs for p in d.partitions]
    names += [(p.filtered, "filtered") for d in specs for p in d.partitions if p.filtered]
    return names


# --------------------------------------------------------------------------------------------
# Pass 1: declare the flags and filtered sensors, before any expression is parsed
# --------------------------------------------------------------------------------------------


def declare_diagnoser_names(loader: ProjectReader) -> None:
    """Add `def_<partition>` (kind flag) and `<sensor>_filter` (kind filtered) to the names.

    Runs after inputs, outputs, memories, timers and observers are declared, so a clash with
    any of them is found here. Malformed structure is left for :func:`parse_diagnosers`,
    which reports it; this pass only reads what it can.
    """
    flags: dict[str, SourcePos] = {}
    for _dname, dnode, _kpos in loader.section_items("diagnosers"):
        if dnode.kind != "map":
            continue
        pnode = dnode.value.get("partitions")
        if pnode is None or pnode.kind != "map":
            continue
        for pname, node in pnode.value.items():
            pname = str(pname)
            kpos = pnode.key_pos.get(pname, pnode.pos)
            if not NAME_RE.match(pname):
                continue  # reported by parse_diagnosers
            flag = FLAG_PREFIX + pname
            if flag in flags:
                loader.diag.error(kpos, f"partition {pname!r} gives the flag {flag!r}, already "
                                  f"given by the partition at {flags[flag]}",
                                  "partition names unique across all diagnosers")
                continue
            flags[flag] = kpos
            loader.namespace[flag] = "flag"
            loader.declared_at[flag] = kpos
            sensor = node.value.get("sensor") if node.kind == "map" else None
            if sensor is None or sensor.kind != "scalar" or not isinstance(sensor.value, str):
                continue
            filtered = sensor.value + FILTERED_SUFFIX
            if filtered in loader.namespace:
                kind = loader.namespace[filtered]
                where = loader.declared_at.get(filtered)
                if kind == "filtered":
                    loader.diag.error(sensor.pos, f"sensor {sensor.value!r} is already "
                                      f"reconstructed by the partition at {where}",
                                      "one partition per sensor")
                else:
                    loader.diag.error(sensor.pos, f"the filtered sensor {filtered!r} clashes "
                                      f"with the {kind} declared at {where}",
                                      f"no variable named {filtered!r} (the engine provides it)")
                continue
            loader.namespace[filtered] = "filtered"
            loader.declared_at[filtered] = sensor.pos


# --------------------------------------------------------------------------------------------
# Pass 2: parse and validate
# --------------------------------------------------------------------------------------------


def parse_diagnosers(loader: ProjectReader) -> tuple[DiagnoserSpec, ...]:
    """Read the `diagnosers:` section after every name is declared; report, never raise."""
    out = []
    for name, node, kpos in loader.section_items("diagnosers"):
        name = str(name)
        if not NAME_RE.match(name):
            loader.diag.error(kpos, f"{name!r} is not a valid diagnoser name",
                              "letters, digits and _, not starting with a digit")
            continue
        spec = _Parser(loader, name, node, kpos).parse()
        if spec is not None:
            out.append(spec)
    wanted = getattr(loader, "diagnoser_variant", None)
    if wanted is not None and not loader.diag.errors and not any(s.variants for s in out):
        from hmi.errors import SourcePos as _Pos
        pos = loader.section_pos.get("diagnosers", _Pos(str(loader.file)))
        loader.diag.error(pos, f"--diagnoser {wanted}: no diagnoser of the project declares "
                          "variants", "a project whose diagnosers list 'variants:'")
    return tuple(out)


class _Parser:
    def __init__(self, loader: ProjectReader, name: str, node: YNode, kpos: SourcePos):
        self.loader = loader
        self.diag = loader.diag
        self.name = name
        self.node = node
        self.kpos = kpos
        self.what = f"diagnoser {name!r}"
        self._ok = True
        self.errors_before = len(loader.diag.errors)

    @property
    def ok(self) -> bool:
        """No error so far in this diagnoser (including those reported through the loader)."""
        return self._ok and len(self.diag.errors) == self.errors_before

    @ok.setter
    def ok(self, value: bool) -> None:
        self._ok = self._ok and value

    def error(self, pos: SourcePos, message: str, expected: str | None = None) -> None:
        self.diag.error(pos, message, expected)
        self.ok = False

    def parse(self) -> DiagnoserSpec | None:
        loader = self.loader
        fields = loader.guard(lambda: self.node.check_keys(
            self.what, DIAGNOSER_KEYS, ["labels", "partitions", "initial", "states",
                                        "transitions"]))
        if fields is None:
            return None
        text = {key: loader.guard(lambda k=key: fields[k].as_str(k), "") if key in fields
                else "" for key in ("description", "device", "initial")}
        self.variants, self.variant = self._variants(fields.get("variants"))
        labels = self._labels(fields["labels"])
        partitions = self._partitions(fields["partitions"], labels)
        # Declared even if this diagnoser is rejected: explanations naming them are checked
        # against what the project says, not reported as unknown on top of the real error.
        loader.declared_labels.update(labels)
        loader.declared_partitions.update(p.name for p in partitions)
        states = self._states(fields["states"], labels)
        names = {s.name for s in states}
        initial = text["initial"]
        if initial and initial not in names:
            self.error(fields["initial"].pos, f"{self.what}: the initial state {initial!r} is "
                       "not declared", _one_of(names))
        elif initial and states and next(s for s in states if s.name == initial).faulty:
            self.error(fields["initial"].pos, f"{self.what}: the initial state {initial!r} is "
                       "faulty", "a normal state (no labels), e.g. a synchronising state")
        elif not initial:
            self.error(fields["initial"].pos, f"{self.what} has no initial state",
                       "'initial:' naming a normal state")
        transitions = self._transitions(fields["transitions"], states)
        resync = self._resync(fields.get("resync"), states)
        if not self.ok:
            return None
        spec = DiagnoserSpec(self.name, text["description"], text["device"] or None, labels,
                             partitions, initial, tuple(states), tuple(transitions),
                             tuple(resync), self.kpos, self.variant, self.variants)
        self._check_labels_used(spec, fields["labels"])
        self._check_determinism(spec)
        self._check_reachability(spec)
        return spec if self.ok else None

    # -- variants ------------------------------------------------------------------------------
    def _variants(self, node: YNode | None) -> tuple[tuple[str, ...], str]:
        """`variants: [improved, paper]`: the variants this diagnoser declares (the first is
        loaded by default) and the one loaded (`--diagnoser NAME` chooses another)."""
        wanted = getattr(self.loader, "diagnoser_variant", None)
        if node is None:
            return (), ""
        items = self.loader.guard(lambda: node.as_seq(f"the variants of {self.what}"), [])
        names: list[str] = []
        for item in items:
            name = self.loader.guard(lambda i=item: i.as_str("a variant name"))
            if name is None:
                self.ok = False
            elif not NAME_RE.match(name) or name in names:
                self.error(item.pos, f"{name!r} is not a valid, new variant name",
                           "letters, digits and _, each variant once")
            else:
                names.append(name)
        if not names:
            self.error(node.pos, f"{self.what} declares an empty variant list",
                       "variants: [NAME, ...] (the first is the default)")
            return (), ""
        if wanted is not None and wanted not in names:
            self.error(node.pos, f"{self.what} has no variant {wanted!r}", _one_of(names))
            return tuple(names), names[0]
        return tuple(names), wanted or names[0]

    def _in_variant(self, fields: dict[str, YNode], what: str) -> bool:
        """Whether an item tagged `variant: NAME` (or a list) belongs to the loaded variant."""
        node = fields.get("variant")
        if node is None:
            return True
        items = node.value if node.kind == "seq" else [node]
        names = [self.loader.guard(lambda i=i: i.as_str(f"the variant of {what}"))
                 for i in items]
        for name, item in zip(names, items, strict=True):
            if name is not None and name not in self.variants:
                self.error(item.pos, f"{what}: unknown variant {name!r}",
                           _one_of(self.variants) if self.variants else
                           "a name declared in the diagnoser's 'variants:' list")
        return self.variant in names

    # -- labels and partitions ---------------------------------------------------------------
    def _labels(self, node: YNode) -> dict[str, str]:
        mapping = self.loader.guard(lambda: node.as_map(f"the labels of {self.what}"), {})
        labels: dict[str, str] = {}
        for label, lnode in mapping.items():
            label = str(label)
            if not NAME_RE.match(label):
                self.error(node.key_pos.get(label, node.pos), f"{label!r} is not a valid "
                           "fault label", "letters, digits and _, e.g. F1")
                continue
            labels[label] = self.loader.guard(
                lambda n=lnode, lab=label: n.as_str(f"the text of label {lab}"), label)
        if not labels and mapping is not None:
            self.error(node.pos, f"{self.what} declares no fault label",
                       "labels: {F1: what the fault is, ...}")
        return labels

    def _label_list(self, node: YNode, what: str, labels: dict[str, str]) -> tuple[str, ...]:
        # An unknown label is reported and kept: the state stays faulty, so its transitions
        # are not also reported as "faulty to normal" (the diagnoser is rejected anyway).
        return tuple(label for label, _ in self._label_items(node, what, labels,
                                                             keep_unknown=True))

    def _label_items(self, node: YNode, what: str, labels: dict[str, str],
                     keep_unknown: bool = False) -> list[tuple[str, SourcePos]]:
        items = self.loader.guard(lambda: node.as_seq(what), [])
        out: list[tuple[str, SourcePos]] = []
        for item in items:
            label = self.loader.guard(lambda i=item: i.as_str("a fault label"))
            if label is None:
                self.ok = False
                continue
            if label not in labels:
                self.error(item.pos, f"unknown label {label!r} in {what}",
                           _suggest(label, labels))
                if keep_unknown:
                    out.append((label, item.pos))
                continue
            if any(label == seen for seen, _ in out):
                self.error(item.pos, f"label {label!r} is listed twice in {what}",
                           "each label once")
                continue
            out.append((label, item.pos))
        return out

    def _partitions(self, node: YNode, labels: dict[str, str]) -> tuple[Partition, ...]:
        loader = self.loader
        mapping = loader.guard(lambda: node.as_map(f"the partitions of {self.what}"), {})
        out: list[Partition] = []
        owner: dict[str, tuple[str, SourcePos]] = {}
        for pname, pnode in mapping.items():
            pname = str(pname)
            kpos = node.key_pos.get(pname, node.pos)
            what = f"partition {pname!r}"
            if not NAME_RE.match(pname):
                self.error(kpos, f"{pname!r} is not a valid partition name",
                           "letters, digits and _ (the flag is def_<partition>)")
                continue
            fields = loader.guard(lambda n=pnode, w=what: n.check_keys(
                w, {"labels", "sensor", "estimate", "actuators", "description"}, ["labels"]))
            if fields is None:
                self.ok = False
                continue
            items = self._label_items(fields["labels"], what, labels)
            plabels = tuple(label for label, _ in items)
            for label, lpos in items:
                if label in owner:
                    other, where = owner[label]
                    self.error(lpos, f"label {label!r} is in partition {other!r} (at "
                               f"{where}) and in {what}", "each label in exactly one partition")
                else:
                    owner[label] = (pname, lpos)
            description = loader.guard(lambda f=fields: f["description"].as_str(
                "description"), "") if "description" in fields else ""
            sensor = estimate = None
            actuators: tuple[str, ...] = ()
            if ("sensor" in fields) == ("actuators" in fields):
                self.error(pnode.pos, f"{what} needs either a 'sensor' (reconstructed from an "
                           "'estimate') or 'actuators' (masked)", "sensor: NAME, estimate: "
                           "NAME  or  actuators: [NAME, ...]")
                continue
            if "sensor" in fields:
                sensor = self._name(fields["sensor"], "sensor", {"input"}, f"the sensor of {what}")
                if "estimate" not in fields:
                    self.error(pnode.pos, f"{what} has a sensor but no estimate",
                               "estimate: a timer or observer giving the sensor's value "
                               "while it is not trusted (000 Fig. 4)")
                else:
                    estimate = self._name(fields["estimate"], "estimate", ESTIMATE_KINDS,
                                          f"the estimate of {what}")
            else:
                if "estimate" in fields:
                    self.error(fields["estimate"].pos, f"{what} masks actuators; an estimate "
                               "only applies to a sensor partition", "no 'estimate:' here")
                items = loader.guard(lambda f=fields: f["actuators"].as_seq("actuators"), [])
                acts = [self._name(i, "actuator", {"output"}, f"the actuators of {what}")
                        for i in items]
                actuators = tuple(a for a in acts if a)
                if not items:
                    self.error(fields["actuators"].pos, f"{what} lists no actuator",
                               "actuators: [an output, ...]")
            out.append(Partition(pname, plabels, sensor, estimate, actuators, description,
                                 kpos))
        for label in labels:
            if label not in owner:
                self.error(self.node.value["labels"].key_pos.get(label, self.kpos),
                           f"label {label!r} is outside every partition of {self.what}",
                           "each label in one partition (the partition gives its flag)")
        return tuple(out)

    def _name(self, node: YNode, role: str, kinds: set[str], what: str) -> str | None:
        name: str | None = self.loader.guard(lambda: node.as_str(what))
        if name is None:
            self.ok = False
            return None
        kind = self.loader.namespace.get(name)
        if kind is None:
            self.error(node.pos, f"unknown name {name!r} as {what}",
                       _suggest(name, {n: k for n, k in self.loader.namespace.items()
                                       if k in kinds}))
            return None
        if kind not in kinds:
            article = "an" if kind[0] in "aeiou" else "a"
            self.error(node.pos, f"{name!r} is {article} {kind}, not usable as the {role} of a "
                       "partition", "a name of kind " + " or ".join(sorted(kinds)))
            return None
        return name

    # -- states ------------------------------------------------------------------------------
    def _states(self, node: YNode, labels: dict[str, str]) -> list[DiagState]:
        loader = self.loader
        mapping = loader.guard(lambda: node.as_map(f"the states of {self.what}"), {})
        out = []
        for sname, snode in mapping.items():
            sname = str(sname)
            kpos = node.key_pos.get(sname, node.pos)
            if not NAME_RE.match(sname):
                self.error(kpos, f"{sname!r} is not a valid state name",
                           "letters, digits and _")
                continue
            if snode.kind == "scalar" and snode.value is None:
                out.append(DiagState(sname, (), "", kpos))
                continue
            fields = loader.guard(lambda n=snode, s=sname: n.check_keys(
                f"state {s!r}", {"labels", "description", "variant"}))
            if fields is None:  # reported; keep the name so transitions to it do not cascade
                self.ok = False
                out.append(DiagState(sname, (), "", kpos))
                continue
            if not self._in_variant(fields, f"state {sname!r}"):
                continue
            slabels = self._label_list(fields["labels"], f"state {sname!r}", labels) \
                if "labels" in fields else ()
            if "labels" in fields and not slabels and not fields["labels"].value:
                self.error(fields["labels"].pos, f"state {sname!r} has an empty label list",
                           "no 'labels:' for a normal state, or the labels of its decision")
            description = loader.guard(lambda f=fields: f["description"].as_str(
                "description"), "") if "description" in fields else ""
            out.append(DiagState(sname, slabels, description, kpos))
        if not out and mapping:
            self.ok = False
        elif not mapping:
            self.error(node.pos, f"{self.what} has no state", "states: {N1: ..., ...}")
        return out

    # -- transitions -------------------------------------------------------------------------
    def _transitions(self, node: YNode, states: list[DiagState]) -> list[DiagTransition]:
        items = self.loader.guard(lambda: node.as_seq(f"the transitions of {self.what}"), [])
        by_name = {s.name: s for s in states}
        out = []
        index = 0
        for item in items:
            if item.kind == "map" and "variant" in item.value:
                fields = {"variant": item.value["variant"]}
                if not self._in_variant(fields, f"a transition of {self.what}"):
                    continue
            index += 1
            tr = self._transition(index, item, by_name)
            if tr is not None:
                out.append(tr)
        timeouts: dict[str, DiagTransition] = {}
        for tr in out:
            if tr.is_timeout:
                if tr.source in timeouts:
                    self.error(tr.pos, f"state {tr.source!r} has a second timeout (the first "
                               f"is transition {timeouts[tr.source].index} at "
                               f"{timeouts[tr.source].pos})", "one timeout per state")
                else:
                    timeouts[tr.source] = tr
        for tr in out:
            timeout = timeouts.get(tr.source)
            if not tr.is_timeout and timeout is not None and \
                    tr.tmin_us >= (timeout.after_us or 0) and tr is not timeout:
                self.diag.warning(tr.pos, f"transition {tr.index} ({tr.text()}) can never "
                                  f"fire: its window opens when the timeout of {tr.source!r} "
                                  f"({timeout.window_text()}) has already left the state")
        return out

    def _transition(self, index: int, node: YNode,
                    states: dict[str, DiagState]) -> DiagTransition | None:
        loader = self.loader
        what = f"transition {index} of {self.what}"
        fields = loader.guard(lambda: node.check_keys(
            what, {"from", "to", "when", "within", "after", "description", "variant"},
            ["from", "to"]))
        if fields is None:
            self.ok = False
            return None
        ends = []
        for key in ("from", "to"):
            name = loader.guard(lambda k=key: fields[k].as_str(f"'{k}' of {what}"))
            if name is not None and name not in states:
                self.error(fields[key].pos, f"{what}: unknown state {name!r}",
                           _suggest(name, states))
                name = None
            ends.append(name)
        source, target = ends
        description = loader.guard(lambda: fields["description"].as_str("description"), "") \
            if "description" in fields else ""
        if "when" in fields and "after" in fields:
            self.error(fields["after"].pos, f"{what} has both 'when' and 'after'",
                       "'when:' (an event, optionally 'within: [tmin, tmax]') or 'after:' "
                       "(a timeout), not both")
            return None
        if "when" not in fields and "after" not in fields:
            self.error(node.pos, f"{what} has neither an event nor a timeout duration",
                       "'when: condition' or 'after: 300ms'")
            return None
        when = None
        tmin, tmax, after = 0, INF, None
        if "when" in fields:
            when = loader.expr(fields["when"], f"the condition of {what}", DIAG_KINDS,
                               context=DIAG_CONTEXT)
            if when is None:
                self.ok = False
            else:
                self._check_output_depth(when)
            if "within" in fields:
                window = self._window(fields["within"], what)
                if window is None:
                    return None
                tmin, tmax = window
        else:
            if "within" in fields:
                self.error(fields["within"].pos, f"{what} is a timeout; a window only applies "
                           "to an event", "'when:' with 'within:', or 'after:' alone")
                return None
            after = loader.guard(lambda: fields["after"].as_duration(f"'after' of {what}"))
            if after is None:
                self.ok = False
                return None
        if source is None or target is None or (when is None and after is None):
            return None
        if source == target:
            self.error(node.pos, f"{what} goes from {source!r} to itself",
                       "another state (a loop would restart the state's clock)")
            return None
        if states[source].faulty and not states[target].faulty:
            self.error(fields["to"].pos, f"{what} goes from the faulty state {source!r} to the "
                       f"normal state {target!r}: a faulty decision is latched until a fault "
                       "reset", "a faulty target (a refinement), or a 'resync:' rule for "
                       "the reset")
            return None
        return DiagTransition(index, source, target, when, tmin, tmax, after, description,
                              node.pos)

    def _window(self, node: YNode, what: str) -> tuple[int, int | None] | None:
        hint = "[tmin, tmax] as durations, e.g. [0ms, 300ms], or [2s, inf] with no upper bound"
        items = self.loader.guard(lambda: node.as_seq(f"the window of {what}"))
        if items is None:
            self.ok = False
            return None
        if len(items) != 2:
            self.error(node.pos, f"the window of {what} has {len(items)} values", hint)
            return None
        tmin = self.loader.guard(lambda: items[0].as_duration("tmin", allow_zero=True))
        if items[1].kind == "scalar" and str(items[1].raw).lower() in ("inf", ".inf"):
            tmax = INF
        else:
            tmax = self.loader.guard(lambda: items[1].as_duration("tmax"))
            if tmax is None:
                self.ok = False
                return None
        if tmin is None:
            self.ok = False
            return None
        if tmax is not None and tmax <= tmin:
            self.error(node.pos, f"the window of {what} is empty ([{format_duration(tmin)}, "
                       f"{format_duration(tmax)}))", "tmin < tmax")
            return None
        return tmin, tmax

    def _check_output_depth(self, expr: Expr) -> None:
        from hmi.logic.expr import MAX_PREV_DEPTH
        for node in walk(expr.root):
            if isinstance(node, Var) and self.loader.namespace.get(node.name) == "output" \
                    and node.depth + 1 > MAX_PREV_DEPTH:
                self.error(expr.pos_of(node), f"prev({node.name}, {node.depth}) reaches back "
                           f"{node.depth + 1} scans in a diagnoser (outputs are read one scan "
                           "back)", f"a depth up to {MAX_PREV_DEPTH - 1}")

    # -- resync ------------------------------------------------------------------------------
    def _resync(self, node: YNode | None, states: list[DiagState]) -> list[ResyncRule]:
        if node is None:
            return []
        by_name = {s.name: s for s in states}
        items = self.loader.guard(lambda: node.as_seq(f"the resync rules of {self.what}"), [])
        out = []
        for k, item in enumerate(items, start=1):
            what = f"resync rule {k} of {self.what}"
            fields = self.loader.guard(lambda i=item, w=what: i.check_keys(
                w, {"when", "to"}, ["when", "to"]))
            if fields is None:
                self.ok = False
                continue
            target = self.loader.guard(lambda f=fields, w=what: f["to"].as_str(f"'to' of {w}"))
            when = self.loader.expr(fields["when"], f"the condition of {what}", DIAG_KINDS,
                                    context=DIAG_CONTEXT)
            if target is not None and target not in by_name:
                self.error(fields["to"].pos, f"{what}: unknown state {target!r}",
                           _suggest(target, by_name))
                continue
            if target is not None and by_name[target].faulty:
                self.error(fields["to"].pos, f"{what} re-synchronises to the faulty state "
                           f"{target!r}", "a normal state consistent with the condition")
                continue
            if when is None or target is None:
                self.ok = False
                continue
            self._check_output_depth(when)
            out.append(ResyncRule(when, target, item.pos))
        return out

    # -- whole-automaton checks --------------------------------------------------------------
    def _check_labels_used(self, spec: DiagnoserSpec, node: YNode) -> None:
        used = {lab for s in spec.states for lab in s.labels}
        for label in spec.labels:
            if label not in used:
                self.diag.warning(node.key_pos.get(label, node.pos), f"label {label!r} of "
                                  f"{self.what} is in no state's decision: it is never "
                                  "diagnosed")

    def _check_determinism(self, spec: DiagnoserSpec) -> None:
        events: dict[str, list[DiagTransition]] = {}
        for tr in spec.transitions:
            if not tr.is_timeout:
                events.setdefault(tr.source, []).append(tr)
        # Enumerating assignments is exponential: a budget for the whole diagnoser keeps a
        # hostile one (dozens of 16-variable conditions from one state) from taking hours.
        budget = [MAX_DETERMINISM_ASSIGNMENTS]
        for trs in events.values():
            for a, b in itertools.combinations(trs, 2):
                if not _windows_overlap(a, b):
                    continue
                witness = jointly_satisfiable(a.when, b.when, budget)  # type: ignore[arg-type]
                if witness is None:
                    continue
                if witness == "too many":
                    self.diag.warning(b.pos, f"transitions {a.index} and {b.index} of "
                                      f"{self.what} were not checked for determinism (more "
                                      f"than {MAX_ENUMERATED_VARS} variables)")
                    continue
                if witness == "budget":
                    self.diag.warning(b.pos, f"transitions {a.index} and {b.index} of "
                                      f"{self.what} were not checked for determinism (the "
                                      f"check's limit of {MAX_DETERMINISM_ASSIGNMENTS:,} "
                                      "assignments for one diagnoser is used up)")
                    continue
                self.error(b.pos, f"{self.what} is not deterministic: from {a.source!r}, "
                           f"transition {a.index} ({a.text()}, at {a.pos}) and transition "
                           f"{b.index} ({b.text()}) can fire at the same scan, e.g. when "
                           f"{witness}", "conditions that exclude each other, or windows "
                           "that do not overlap")

    def _check_reachability(self, spec: DiagnoserSpec) -> None:
        reached = reachable_states(spec)
        for state in spec.states:
            if state.name not in reached:
                self.diag.warning(state.pos, f"state {state.name!r} of {self.what} is "
                                  "unreachable (no path of transitions from the initial state "
                                  "or a resync target)")


# --------------------------------------------------------------------------------------------
# Helpers shared with the analysis
# --------------------------------------------------------------------------------------------


def reachable_states(spec: DiagnoserSpec) -> set[str]:
    """States reachable from the initial state or a resync target (after a fault reset)."""
    reached = {spec.initial, *(r.target for r in spec.resync)}
    leaving: dict[str, list[str]] = {}
    for tr in spec.transitions:
        leaving.setdefault(tr.source, []).append(tr.target)
    frontier = list(reached)
    while frontier:
        for target in leaving.get(frontier.pop(), ()):
            if target not in reached:
                reached.add(target)
                frontier.append(target)
    return reached


def _windows_overlap(a: DiagTransition, b: DiagTransition) -> bool:
    a_hi = a.tmax_us if a.tmax_us is not None else float("inf")
    b_hi = b.tmax_us if b.tmax_us is not None else float("inf")
    return a.tmin_us < b_hi and b.tmin_us < a_hi


def _vars(expr: Expr) -> list[tuple[str, int]]:
    seen: dict[tuple[str, int], None] = {}
    for node in walk(expr.root):
        if isinstance(node, Var):
            seen.setdefault((node.name, node.depth))
    return list(seen)


def evaluate(node: Node, values: dict[tuple[str, int], bool]) -> bool:
    """A condition's value under an assignment of its variables (for the offline checks)."""
    if isinstance(node, Const):
        return node.value
    if isinstance(node, Var):
        return values[(node.name, node.depth)]
    if isinstance(node, Not):
        return not evaluate(node.operand, values)
    if isinstance(node, And):
        return all(evaluate(op, values) for op in node.operands)
    if isinstance(node, Or):
        return any(evaluate(op, values) for op in node.operands)
    raise TypeError(f"not a condition of a diagnoser: {node!r}")


def jointly_satisfiable(a: Expr, b: Expr, budget: list[int] | None = None) -> str | None:
    """A witness assignment making both conditions true (the first in enumeration order),
    None if none; "too many" (variables) or "budget" (`budget[0]` assignments left, spent
    here) if unknown."""
    names = list(dict.fromkeys([*_vars(a), *_vars(b)]))
    values = _product_witness(a, b, names)
    if values is not None:
        return _witness_text(values) if values else None
    if len(names) > MAX_ENUMERATED_VARS:
        return "too many"
    if budget is not None:
        if budget[0] < 1 << len(names):
            return "budget"
        budget[0] -= 1 << len(names)
    for bits in itertools.product((False, True), repeat=len(names)):
        values = dict(zip(names, bits, strict=True))
        if evaluate(a.root, values) and evaluate(b.root, values):
            return _witness_text(values)
    return None


def _product_witness(a: Expr, b: Expr, names: Sequence[tuple[str, int]]
                     ) -> dict[tuple[str, int], bool] | None:
    """When both conditions are products of literals (the usual case), the answer without
    enumerating: {} if they contradict each other, else the first satisfying assignment in
    enumeration order (every free variable 0). None if either is not a product."""
    try:
        parts = (monomial_literals(a), monomial_literals(b))
    except NotMonomial:
        return None
    if parts[0] is None or parts[1] is None:
        return {}  # one of them can never be true
    fixed: dict[tuple[str, int], bool] = {}
    for lit in (*parts[0], *parts[1]):
        if fixed.setdefault((lit.name, lit.depth), lit.positive) != lit.positive:
            return {}
    values = dict.fromkeys(names, False)
    values.update(fixed)
    return values


def _witness_text(values: Mapping[tuple[str, int], bool]) -> str:
    return ", ".join(f"{_var_text(n, d)}={int(v)}" for (n, d), v in values.items())


def _var_text(name: str, depth: int) -> str:
    if depth == 0:
        return name
    return f"prev({name})" if depth == 1 else f"prev({name}, {depth})"


def _one_of(names: Iterable[str]) -> str:
    return "one of " + ", ".join(sorted(names)) if names else "a declared state"


def _suggest(name: str, known: Iterable[str]) -> str:
    import difflib
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.5)
    if close:
        return "a known name; did you mean " + " or ".join(repr(c) for c in close) + "?"
    return _one_of(known)


__all__ = [
    "DIAG_KINDS", "DiagState", "DiagTransition", "DiagnoserSpec", "Partition",
    "ResyncRule", "declare_diagnoser_names", "diagnosers_of", "evaluate",
    "jointly_satisfiable", "layout_names", "parse_diagnosers", "reachable_states",
]

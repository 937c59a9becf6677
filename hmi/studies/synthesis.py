"""A local diagnoser built from the plant model, the fault models and the control law (000
§2.1, construction steps 1-3), on the closed loop plchmi explores.

000 builds each local diagnoser in four offline steps: (1) the plant element (PE), every
evolution of one device; (2) its normal behaviour model (NBM): the PE restricted to what the
control law and the filter make it do, enriched with the times observed when its events are
excited in simulation; (3) the faults that can occur from each normal state, added as
labelled states; (4) a High Level Diagnoser over several devices (hmi/engine/hld.py). Here:

1. **PE**: the device's ports (its sensors read at t, its orders written at t-1, as every
   diagnoser sees them) and its fault models (hmi/project/device_models.py), simulated by the
   device model itself inside the closed loop.
2. **NBM**: the fault-free closed loop (plant model + control law + filter, explored by
   hmi/studies/explore.py) projected on the device's observation vector. Each vector the
   fault-free cycle holds is a normal state; each change a transition. A change of a sensor
   is the plant's: its window is the dwell times observed in every fault-free run (at the
   device's declared timing), widened by :data:`MARGIN_SCANS` scans each side, and the state
   times out at the window's end. A change of an order only is the control law's: no
   window, no timeout (the diagnoser does not depend on when the program decides). An
   order withdrawn that the NBM does not expect (a latch, a stop) sends the diagnoser back
   to synchronising, as the hand-written one does.
3. **Faults**: every fault of the device injected at every instant of the cycle (every
   scan, plus just before and after each NBM event), under the configurations where the diagnoser
   runs (observing only; FTC). Where a run first leaves the NBM (an unexpected vector, an
   expected one outside its window, a timeout), it enters a faulty state holding the
   labels of every run that leaves the NBM there. From a faulty state the runs it holds go
   on: grouped by the next vector they show and by when (runs whose times lie apart go to
   different states, the window boundary halfway between them), and a timeout for those
   that never change again. A state stops refining when it holds one label (isolated with
   certainty) or when its runs never change again (a final ambiguity).

Under FTC the diagnoser acts on the loop it observes (a decision holding an actuator label
masks the orders), so the runs depend on the diagnoser being built. The construction is
iterated (hmi/studies/synth_build.py): explore the loop with the last diagnoser, build
again, until the diagnoser built is the one explored with (a fixpoint: every run it was
built from is a run of the loop it closes). Level by level this is reached: until a run's
first deviation the diagnoser is normal and acts on nothing, so the first faulty states do
not depend on it; their labels fix what the loop does next, and so on.

The result is written in the project's diagnoser format (hmi/studies/synth_yaml.py), with
comments saying where each state and window comes from, and read back by the loader: what
is compared and checked is the file.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

from hmi.project.device_models import DEVICE_MODELS as MODELS
from hmi.project.device_models import FaultSpec
from hmi.project.model import DiagnoserSpec, Project
from hmi.studies.explore import Explorer, Graph, LoopConfig

MARGIN_SCANS = 2  # a plant window is the observed dwell times widened by this many scans
TIMEOUT_MARGIN_SCANS = 5  # a faulty state times out this long after its last change seen
CLUSTER_GAP_SCANS = 5  # changes further apart than this are told apart by their windows
MAX_DEPTH = 24  # faulty states below a deviation, a guard (never reached on the examples)
MAX_ITERATIONS = 8  # FTC fixpoint iterations
# The injection grid of the construction: every scan. A coarser grid builds faster but places
# the boundaries between the times of its runs halfway between the instants it saw, and runs
# injected between them can cross those boundaries (on the valve a 50 ms grid misdiagnosed
# 3 runs of 10,348 per configuration on the 10 ms sweep).
GRID_US = 0
SYNCH = "N0"
DEBUG_DIR = __import__("os").environ.get("PLCHMI_SYNTH_DEBUG", "")

# The configurations of the construction: observing only (the filter monitors; the
# diagnoser acts on nothing, so it need not run), and FTC (with the diagnoser being built).
OBSERVING = LoopConfig("observing", "observing only", "monitor", "off")


class SynthesisError(Exception):
    """The device cannot be diagnosed this way (no such device, nothing observable...)."""


@dataclass(frozen=True)
class Target:
    """The device a diagnoser is built for, and what it observes of it."""

    device: str  # the plant's device name
    model: str
    name: str  # the diagnoser's name (the hand-written one's, else the device's)
    operator_name: str | None  # `device:` as the operator knows it
    sensors: tuple[str, ...]  # project inputs, in the model's port order
    actuators: tuple[str, ...]  # project outputs
    faults: tuple[FaultSpec, ...]
    ports: dict[str, str]  # model port -> project variable
    params: dict[str, object]  # the device's parameters as simulated (defaults filled)
    existing: DiagnoserSpec | None  # the hand-written diagnoser of the device, if any

    @property
    def names(self) -> tuple[str, ...]:
        return self.sensors + self.actuators

    def vector_text(self, vec: int) -> str:
        """`fsc=1 fso=0 C=0 O=1`."""
        return " ".join(f"{n}={vec >> k & 1}" for k, n in enumerate(self.names))

    def condition(self, vec: int) -> str:
        """The vector as a diagnoser condition (a full product of literals)."""
        return " and ".join(n if vec >> k & 1 else f"not {n}" for k, n in enumerate(self.names))

    def sensor_bits(self, vec: int) -> int:
        return vec & ((1 << len(self.sensors)) - 1)

    def at_rest(self, vec: int) -> bool:
        return vec >> len(self.sensors) == 0


def find_target(project: Project, name: str) -> Target:
    """The device `name` names: a plant device, or the device a diagnoser observes."""
    devices = project.plant.devices
    chosen = next((d for d in devices if d.name == name), None)
    existing = next((s for s in project.diagnosers if s.name == name), None)
    if chosen is None and existing is not None:
        watched = {p.sensor for p in existing.partitions if p.sensor} | \
            {a for p in existing.partitions for a in p.actuators}
        chosen = next((d for d in devices if watched & set(d.ports.values())), None)
    if chosen is None:
        known = [d.name for d in devices] + [s.name for s in project.diagnosers]
        raise SynthesisError(f"no device or diagnoser {name!r} in project {project.name} "
                             f"(expected one of {', '.join(known) or 'none'})")
    model = MODELS[chosen.model]
    ports = dict(chosen.ports)
    for port in (*model.sensors, *model.actuators):
        ports.setdefault(port, port)
    if existing is None:
        mine = set(ports.values())
        existing = next((s for s in project.diagnosers if any(
            p.sensor in mine or set(p.actuators) & mine for p in s.partitions)), None)
    sensors = tuple(ports[p] for p in model.sensors)
    actuators = tuple(ports[p] for p in model.actuators)
    if not model.faults:
        raise SynthesisError(f"the {model.name} model declares no fault: nothing to diagnose")
    operator = existing.device if existing is not None else None
    if operator is None:
        var = project.variable(sensors[0]) if sensors else None
        operator = getattr(var, "device", None) or None
    params = {k: p.default for k, p in model.params.items()}
    params.update(chosen.params)
    return Target(chosen.name, model.name, existing.name if existing else chosen.name,
                  operator, sensors, actuators, tuple(model.faults.values()), ports, params,
                  existing)


# --------------------------------------------------------------------------------------------
# Observations of the explored loop, as the diagnoser sees them
# --------------------------------------------------------------------------------------------


class View:
    """The device's observation vector at each node of an explored graph: its sensors as
    read at the node's scan, its orders as written at the scan before (the predecessor)."""

    def __init__(self, g: Graph, target: Target):
        self.g = g
        index = {n: k for k, n in enumerate(g.obs_names)}
        self.sensor_bits = [index[n] for n in target.sensors]
        self.actuator_bits = [index[n] for n in target.actuators]
        self.width = len(target.sensors)

    def sensors(self, node: int) -> int:
        obs = self.g.obs[node]
        return sum(1 << k for k, b in enumerate(self.sensor_bits) if obs >> b & 1)

    def orders(self, node: int) -> int:
        obs = self.g.obs[node]
        return sum(1 << (self.width + k) for k, b in enumerate(self.actuator_bits)
                   if obs >> b & 1)

    def vector(self, node: int, previous: int) -> int:
        return self.sensors(node) | self.orders(previous)


@dataclass(frozen=True, order=True)
class Cursor:
    """One run at one scan: its configuration, its node, the vector seen there."""

    config: int
    node: int
    vec: int
    fault: str = field(compare=False)


QUIET = None  # a cursor whose vector never changes again


def next_change(view: View, c: Cursor, limit: int = 100_000) -> tuple[int, Cursor] | None:
    """Scans to the next change of the vector and the cursor there; None if it never changes
    (the run ends in a cycle, or is settled, with this vector)."""
    g = view.g
    node, steps, seen = c.node, 0, set()
    while steps < limit:
        nxt = g.nxt[node]
        if nxt < 0:
            return QUIET
        steps += 1
        vec = view.vector(nxt, node)
        if vec != c.vec:
            return steps, Cursor(c.config, nxt, vec, c.fault)
        if nxt in seen:
            return QUIET
        seen.add(nxt)
        node = nxt
    return QUIET


# --------------------------------------------------------------------------------------------
# Step 2: the normal behaviour model
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Expected:
    vec: int  # the vector the state goes to
    tmin: int  # window [tmin, tmax) in us; plant events only (None: the control law's)
    tmax: int | None
    dwell: tuple[int, ...]  # the dwell times observed (us), for the comments


@dataclass
class Nbm:
    """Normal states (index 1.. in order of the fault-free run; 0 is synchronising)."""

    vectors: list[int]  # index k -> vector of normal state N<k> (k >= 1; [0] unused)
    expected: dict[int, dict[int, Expected]]  # state -> vector -> expected transition
    first_seen: dict[int, int]  # state -> time (us) it is first entered in the fault-free run
    period: int
    # A switch that changed may read its old value for `settle` us (its bounce): per state,
    # the sensor bits that changed on entering it (or just before, across the control law's
    # event that followed at once), whose old value is its bounce there.
    settle: int = 0
    settling: dict[int, int] = field(default_factory=dict)
    band: tuple[str, ...] = ()  # the band's plants the windows were measured on (their texts)
    margin: int = 0  # us each window was widened by (scans and scan jitter)

    def state_of(self, vec: int) -> int:
        return self.vectors.index(vec)

    def timeout(self, state: int) -> int | None:
        ends = [e.tmax for e in self.expected.get(state, {}).values() if e.tmax is not None]
        return max(ends) if ends else None

    def rest_states(self, target: Target) -> list[int]:
        return [k for k in range(1, len(self.vectors)) if target.at_rest(self.vectors[k])]

    def settle_target(self, state: int, vec: int) -> int | None:
        """What `vec` stands for in `state` while its switches settle, if it differs from a
        normal reading only by the old value of a switch that just changed: the state itself
        (the bounce is no event) or the next normal state (the control law's event, seen
        with the bounce); None if it is not a bounce."""
        bits = self.settling.get(state, 0)
        if not bits or not self.settle:
            return None
        own = self.vectors[state]
        masked = (vec & ~bits) | (own & bits)
        if masked == vec or vec in self.expected.get(state, {}):
            return None  # no switch's old value, or a change the state expects
        if masked == own:
            return state
        e = self.expected.get(state, {}).get(masked)
        if e is not None and e.tmin == 0 and (e.tmax is None or e.tmax >= self.settle):
            return self.state_of(masked)
        return None


def cycle_path(g: Graph) -> list[int]:
    """The fault-free run: its prefix, then its cycle once more (so the cycle's closing
    change is seen too)."""
    return list(g.prefix) + list(g.prefix[g.cycle_start:])


def build_nbm(g: Graph, view: View, target: Target,
              band: Sequence[tuple[str, Graph, View]] = (), jitter_us: int = 0,
              settle_us: int = 0) -> Nbm:
    """The NBM from the fault-free run of the nominal plant (its states and transitions),
    with the plant's windows measured over it and over the fault-free runs of the band's
    plants (`band`: (label, graph, view) per plant), widened by MARGIN_SCANS scans and the
    scan jitter each side. A switch's old value read within `settle_us` of its change is its
    bounce, not an event. A band plant showing a change the nominal run does not is an error
    (the nominal run must hold the behaviour's structure)."""
    period = g.period_us
    path = cycle_path(g)
    vectors = [-1]
    first_seen: dict[int, int] = {}
    dwell: dict[tuple[int, int], list[int]] = {}
    current, since = 0, 0
    for i, node in enumerate(path):
        vec = view.vector(node, path[i - 1]) if i else view.sensors(node)
        if vec not in vectors:
            vectors.append(vec)
            first_seen[len(vectors) - 1] = i * period
        state = vectors.index(vec)
        if i and state != current:
            dwell.setdefault((current, state), []).append((i - since) * period)
        if state != current:
            current, since = state, i
    expected: dict[int, dict[int, Expected]] = {}
    mids: set[tuple[int, int]] = set()  # (order seen, the plant's answer): the mid states'
    width = len(target.sensors)
    for (a, b), times in sorted(dwell.items()):
        va, vb = vectors[a], vectors[b]
        seen = tuple(sorted(set(times)))
        if va >> width == vb >> width:  # the plant's event: its window (set below)
            expected.setdefault(a, {})[vb] = Expected(vb, 0, 0, seen)
            continue
        # The control law's event: no window.
        expected.setdefault(a, {})[vb] = Expected(vb, 0, None, seen)
        if target.sensor_bits(va) != target.sensor_bits(vb):
            # The order and the plant's answer seen at one scan (the diagnoser sees the
            # orders one scan late): a plant answering later shows the order first. That
            # vector is a normal state too, left by the plant's event within the margin.
            mid = target.sensor_bits(va) | (vb >> width << width)
            if mid not in vectors:
                vectors.append(mid)
            m = vectors.index(mid)
            expected[a][mid] = Expected(mid, 0, None, ())
            mids.add((m, vb))
    for m, vb in sorted(mids):
        expected.setdefault(m, {}).setdefault(vb, Expected(vb, 0, 0, ()))
    settling = _settling(vectors, expected, dwell, mids, target, settle_us)
    nbm = Nbm(vectors, expected, first_seen, period, settle_us, settling,
              tuple(label for label, _, _ in band), MARGIN_SCANS * period + jitter_us)
    # The band's plants: every change they show, walked through the NBM (windows open, the
    # bounce settling), adds its dwell to the plant's windows.
    for label, bg, bview in band:
        for (a, b), times in _walk(nbm, target, bg, bview, label, relaxed=True).items():
            dwell.setdefault((a, b), []).extend(times)
    margin = nbm.margin
    for a, exp in expected.items():
        for vb, e in list(exp.items()):
            if e.tmax is None:
                continue  # the control law's event
            seen = tuple(sorted(set(dwell.get((a, vectors.index(vb)), []))))
            if (a, vb) in mids:  # the plant's answer to an order: from the order on
                last = seen[-1] if seen else 0
                exp[vb] = Expected(vb, 0, last + margin, seen or (0,))
            else:
                lo = seen[0] - margin
                exp[vb] = Expected(vb, lo if lo > period else 0, seen[-1] + margin, seen)
    # Every fault-free run, nominal and across the band, stays in the NBM built.
    _walk(nbm, target, g, view, "nominal", relaxed=False)
    for label, bg, bview in band:
        _walk(nbm, target, bg, bview, label, relaxed=False)
    return nbm


def _settling(vectors: list[int], expected: dict[int, dict[int, Expected]],
              dwell: dict[tuple[int, int], list[int]], mids: set[tuple[int, int]],
              target: Target, settle_us: int) -> dict[int, int]:
    """Per normal state, the switches still settling when it is entered: those that changed
    on entering it, and those settling in the state before when the control law's event that
    left it came within the settling time."""
    if not settle_us:
        return {}
    out: dict[int, int] = {}
    edges = [(a, vectors.index(vb)) for a, exp in expected.items() for vb in exp]
    edges += [(m, vectors.index(vb)) for m, vb in mids]
    for a, b in edges:
        changed = target.sensor_bits(vectors[a] ^ vectors[b])
        if changed:
            out[b] = out.get(b, 0) | changed
    while True:
        grown = False
        for a, b in edges:
            if target.sensor_bits(vectors[a] ^ vectors[b]) or not out.get(a):
                continue
            if max(dwell.get((a, b), [settle_us])) >= settle_us:
                continue
            bits = out.get(b, 0) | out[a]
            if bits != out.get(b, 0):
                out[b], grown = bits, True
        if not grown:
            return out


def _walk(nbm: Nbm, target: Target, g: Graph, view: View, label: str, relaxed: bool
          ) -> dict[tuple[int, int], list[int]]:
    """The dwell before each change of one plant's fault-free run, walked through the NBM
    (`relaxed`: its windows open, any expected change at any time), its switches settling.
    A deviation is an error: a fault-free run must stay in the normal behaviour."""
    if relaxed:
        nbm = replace(nbm, expected={a: {v: Expected(v, 0, None, e.dwell)
                                         for v, e in exp.items()}
                                     for a, exp in nbm.expected.items()})
    period = g.period_us
    path = cycle_path(g)
    out: dict[tuple[int, int], list[int]] = {}
    state, since = 0, 0
    for i, node in enumerate(path):
        vec = view.vector(node, path[i - 1]) if i else view.sensors(node)
        result = deviation_of(nbm, target, state, (i - since) * period, vec)
        if isinstance(result, Deviation) or (result == 0 and state):
            why = ("which the nominal plant's fault-free run never does: the normal behaviour "
                   "cannot be built from it") if relaxed else "outside the windows built"
            raise SynthesisError(
                f"the fault-free run of the plant {label} shows {target.vector_text(vec)} "
                f"at {i * period} us in N{state} ({target.vector_text(nbm.vectors[state])}) "
                f"after {(i - since) * period} us, {why}")
        if result is not None and result != state:
            if state:
                out.setdefault((state, result), []).append((i - since) * period)
            state, since = result, i
    return out


def band_plants(project: Project, target: Target, counter: str
                ) -> list[tuple[str, Graph, View]]:
    """The fault-free closed loop at each corner of the device's declared tolerances (those
    a fault-free run depends on: not the block point, F13's alone), every switch change of a
    kind bouncing alike (the exploration needs a loop that repeats): (the corner's text, its
    graph, the device's view of it). The scan jitter is not explored (scans off their grid
    never repeat): the windows are widened by it instead."""
    from hmi.studies.band import band_of
    band = band_of(project).restricted(
        lambda d: d.device == target.device and not d.faults_only)
    out = []
    for corner in band.corners():
        cell = band.apply(project, corner, "same")
        g = Explorer(cell, OBSERVING, counter, settle=False).graph
        out.append((corner.text(band).rsplit(",seed=", 1)[0], g, View(g, target)))
    return out


def settle_of(project: Project, target: Target) -> int:
    """How long a switch of the device may read its old value after a change: its bounce
    (the most its declared tolerances allow) and a scan, as the scan reading the first new
    value may come anywhere in the bounce's first period; 0 for switches that do not
    bounce."""
    bounce = int(str(target.params.get("bounce", 0) or 0))
    device = next(d for d in project.plant.devices if d.name == target.device)
    for t in device.tolerances:
        if t.param == "bounce":
            bounce = max(bounce, int(t.high))
    return bounce + project.scan_period_us if bounce else 0


# --------------------------------------------------------------------------------------------
# Step 3: where each run leaves the NBM
# --------------------------------------------------------------------------------------------

TIMEOUT = -1  # a deviation key's vector for "the state timed out"


@dataclass(frozen=True, order=True)
class Deviation:
    """Where a run leaves the NBM: from normal state `state`, on vector `vec` (TIMEOUT: by
    the state's timeout) within [tmin, tmax)."""

    state: int
    vec: int
    tmin: int
    tmax: int | None


def deviation_of(nbm: Nbm, target: Target, state: int, t: int, vec: int
                 ) -> Deviation | int | None:
    """What the NBM does on `vec` at time-in-state `t`: the next normal state (an int), a
    deviation, or None (nothing: the vector is the state's own and no timeout is due)."""
    if state == 0:
        return nbm.state_of(vec) if vec in nbm.vectors[1:] and target.at_rest(vec) else None
    settled = nbm.settle_target(state, vec)
    if settled is not None and t < nbm.settle:
        return None if settled == state else settled
    result = _deviation_of(nbm, target, state, t, vec)
    if settled is not None and isinstance(result, Deviation) and result.vec != TIMEOUT:
        # A switch's old value past its settling time: the deviation it was, from then on.
        return replace(result, tmin=max(result.tmin, nbm.settle))
    return result


def _deviation_of(nbm: Nbm, target: Target, state: int, t: int, vec: int
                  ) -> Deviation | int | None:
    own = nbm.vectors[state]
    timeout = nbm.timeout(state)
    exp = nbm.expected.get(state, {})
    if vec != own:
        e = exp.get(vec)
        if e is not None:
            if t >= e.tmin and (e.tmax is None or t < e.tmax):
                return nbm.state_of(vec)
            if t < e.tmin:
                return Deviation(state, vec, 0, e.tmin)
            if timeout is not None and t < timeout:
                return Deviation(state, vec, e.tmax or 0, timeout)
            return Deviation(state, TIMEOUT, timeout or 0, None)
        if target.sensor_bits(vec) == target.sensor_bits(own):
            return 0  # an order the NBM does not expect changed: re-synchronise
        return Deviation(state, vec, 0, None)
    if timeout is not None and t >= timeout:
        return Deviation(state, TIMEOUT, timeout, None)
    return None


@dataclass
class Runs:
    """The explored runs of one construction round: per configuration a graph and a view."""

    graphs: list[Graph]
    views: list[View]
    starts: list[list[tuple[str, int, int]]]  # per config: (fault, k, node)
    ftc: list[bool]  # per config: the diagnoser's decisions mask the orders there


def first_deviations(nbm: Nbm, target: Target, runs: Runs
                     ) -> dict[Deviation, list[tuple[int, Cursor]]]:
    """Per deviation, the runs leaving the NBM there: (time in the normal state, the cursor
    at that scan)."""
    out: dict[Deviation, list[tuple[int, Cursor]]] = {}
    period = nbm.period
    for c, (g, view) in enumerate(zip(runs.graphs, runs.views, strict=True)):
        prefix = g.prefix
        # The NBM along the fault-free prefix: (state, entered at scan) after each scan.
        states: list[tuple[int, int]] = []
        state, since = 0, 0
        for i, node in enumerate(prefix):
            vec = view.vector(node, prefix[i - 1]) if i else view.sensors(node)
            result = deviation_of(nbm, target, state, (i - since) * period, vec)
            if isinstance(result, Deviation):
                raise SynthesisError("the fault-free run leaves its own normal behaviour "
                                     f"model at {i * period} us: {result}")
            if result is not None and result != state:
                state, since = result, i
            states.append((state, since))
        for fault, k, start in runs.starts[c]:
            state, since = states[k]
            node, i = start, k
            seen: set[tuple[int, int, int]] = set()
            while True:
                nxt = g.nxt[node]
                if nxt < 0:
                    break
                i += 1
                vec = view.vector(nxt, node)
                result = deviation_of(nbm, target, state, (i - since) * period, vec)
                if isinstance(result, Deviation):
                    out.setdefault(result, []).append(((i - since) * period,
                                                       Cursor(c, nxt, vec, fault)))
                    break
                if result is not None and result != state:
                    state, since = result, i
                key = (nxt, state, min((i - since) * period, _cap(nbm, state)))
                if key in seen:
                    break  # the run cycles without ever leaving the NBM: undetected
                seen.add(key)
                node = nxt
    return out


def _cap(nbm: Nbm, state: int) -> int:
    timeout = nbm.timeout(state)
    ends = [e.tmin for e in nbm.expected.get(state, {}).values()]
    return max([timeout or 0, nbm.settle, *ends]) + 1


# --------------------------------------------------------------------------------------------
# Step 3, continued: the faulty states, refined by what the runs show next
# --------------------------------------------------------------------------------------------


@dataclass
class FaultyState:
    name: str
    labels: tuple[str, ...]
    vec: int | None  # the vector it is entered on (None: by a timeout, same vector)
    origin: str  # where it comes from, for the comments
    runs: dict[str, int]  # fault -> cursors (runs) entering it
    events: list[tuple[int, int, int | None, str, str]] = field(default_factory=list)
    # (vector, tmin, tmax, target, why)
    timeout: tuple[int, str, str] | None = None  # (after, target, why)


@dataclass
class Diagnoser:
    """What the construction built: the NBM, the deviations and the faulty states."""

    target: Target
    nbm: Nbm
    deviations: list[tuple[Deviation, str]]  # deviation -> the faulty state it enters
    faulty: list[FaultyState]
    iterations: int = 0
    converged: bool = False
    runs_used: int = 0
    grid_us: int = GRID_US


class _Builder:
    def __init__(self, target: Target, runs: Runs, order: dict[str, int]):
        self.masking = masking_labels(target)
        self.target = target
        self.runs = runs
        self.order = order  # fault -> its rank in the model (labels sorted by it)
        self.states: list[FaultyState] = []
        self.by_belief: dict[tuple[Cursor, ...], str] = {}
        self.period = runs.graphs[0].period_us

    def labels(self, cursors: Sequence[Cursor]) -> tuple[str, ...]:
        return tuple(sorted({c.fault for c in cursors}, key=self.order.__getitem__))

    def state_for(self, cursors: list[Cursor], vec: int | None, origin: str,
                  depth: int) -> str:
        belief = tuple(sorted(set(cursors)))
        found = self.by_belief.get(belief)
        if found is not None:
            return found
        name = f"D{len(self.states) + 1}"
        runs: dict[str, int] = {}
        for c in belief:
            runs[c.fault] = runs.get(c.fault, 0) + 1
        state = FaultyState(name, self.labels(belief), vec, origin,
                            dict(sorted(runs.items(), key=lambda kv: self.order[kv[0]])))
        self.states.append(state)
        self.by_belief[belief] = name
        if len(state.labels) > 1 and depth < MAX_DEPTH:
            self._refine(state, belief, depth)
        return name

    def _order_rise(self, before: int, after: int) -> bool:
        t = self.target
        return t.sensor_bits(before) == t.sensor_bits(after) and \
            bool(after >> len(t.sensors) & ~(before >> len(t.sensors)))

    def _refine(self, state: FaultyState, belief: tuple[Cursor, ...], depth: int) -> None:
        period = self.period
        changes: dict[int, list[tuple[int, Cursor]]] = {}
        quiet: list[Cursor] = []
        masks = bool(self.masking & set(state.labels))
        for c in belief:
            found = next_change(self.runs.views[c.config], c)
            if found is QUIET or (masks and self.runs.ftc[c.config]
                                  and self._order_rise(c.vec, found[1].vec)):
                # Under FTC this state masks the orders: an order cannot rise while the
                # loop is in it. One that did rose after the diagnoser the loop was explored
                # with had left it (a shorter stay): for this state, the run is quiet.
                quiet.append(c)
            else:
                steps, nxt = found
                changes.setdefault(nxt.vec, []).append((steps * period, nxt))
        if not changes:
            return  # its runs never change again: a final decision
        latest = max(t for items in changes.values() for t, _ in items)
        after = latest + TIMEOUT_MARGIN_SCANS * period if quiet else None
        for vec in sorted(changes):
            clusters = _groups(changes[vec], period)
            for n, cluster in enumerate(clusters):
                lo = 0 if n == 0 else _ms_round((clusters[n - 1][-1][0] + cluster[0][0]) // 2)
                hi = after if n == len(clusters) - 1 else \
                    _ms_round((cluster[-1][0] + clusters[n + 1][0][0]) // 2)
                times = sorted({t for t, _ in cluster})
                why = (f"seen {_span(times)} after entering {state.name} in "
                       + _runs_text(cluster, self.order))
                target = self.state_for([c for _, c in cluster], vec,
                                        f"from {state.name}: {self.target.vector_text(vec)}",
                                        depth + 1)
                state.events.append((vec, lo, hi, target, why))
        if quiet and after is not None:
            why = (f"no change seen after {_span([latest])} in "
                   + _runs_text([(0, c) for c in quiet], self.order) + ", while the others "
                   f"changed by {_span([latest])}")
            # The quiet runs never change again: the state they reach is final.
            name = f"D{len(self.states) + 1}"
            runs: dict[str, int] = {}
            for c in quiet:
                runs[c.fault] = runs.get(c.fault, 0) + 1
            self.states.append(FaultyState(
                name, self.labels(quiet), None, f"from {state.name}: no change for "
                f"{_span([after])}", dict(sorted(runs.items(),
                                                key=lambda kv: self.order[kv[0]]))))
            state.timeout = (after, name, why)


def minimise(deviations: list[tuple[Deviation, str]], states: list[FaultyState]
             ) -> tuple[list[tuple[Deviation, str]], list[FaultyState]]:
    """Faulty states with the same labels and the same transitions (to equivalent states)
    merged (Moore's partition refinement), adjacent windows of one vector to one state
    joined, and the states renamed D1, D2... in their order."""
    by_name = {s.name: s for s in states}
    cls: dict[str, object] = {s.name: s.labels for s in states}
    while True:
        sig = {s.name: (cls[s.name], tuple((v, lo, hi, cls[t]) for v, lo, hi, t, _ in
                                            _joined(s.events, cls)),
                        None if s.timeout is None else (s.timeout[0], cls[s.timeout[1]]))
               for s in states}
        new: dict[str, object] = {name: sig[name] for name in sig}
        if len(set(new.values())) == len(set(cls.values())):
            break
        cls = new
    rep: dict[object, FaultyState] = {}
    for s in states:
        rep.setdefault(cls[s.name], s)
    order: list[FaultyState] = []
    seen: set[str] = set()

    def visit(name: str) -> None:
        r = rep[cls[name]]
        if r.name in seen:
            return
        seen.add(r.name)
        order.append(r)
        for _, _, _, t, _ in r.events:
            visit(t)
        if r.timeout is not None:
            visit(r.timeout[1])

    for _, name in deviations:
        visit(name)
    rename = {r.name: f"D{k}" for k, r in enumerate(order, start=1)}

    def new_name(name: str) -> str:
        return rename[rep[cls[name]].name]

    runs: dict[str, dict[str, int]] = {}
    for s in states:
        total = runs.setdefault(new_name(s.name), {})
        for f, n in s.runs.items():
            total[f] = total.get(f, 0) + n
    out = []
    for r in order:
        name = rename[r.name]
        # Each window's comment says when its runs changed after entering this state.
        events = [(v, lo, hi, new_name(t),
                   why.replace(f"after entering {r.name} in", f"after entering {name} in"))
                  for v, lo, hi, t, why in _joined(r.events, {n: new_name(n) for n in by_name})]
        timeout = None if r.timeout is None else (r.timeout[0], new_name(r.timeout[1]),
                                                  r.timeout[2])
        origin = r.origin
        for old in by_name:
            origin = origin.replace(f"from {old}:", f"from {new_name(old)}:")
        order_of = {f: k for k, f in enumerate(r.labels)}
        merged = dict(sorted(runs[name].items(), key=lambda kv: order_of.get(kv[0], 99)))
        out.append(FaultyState(name, r.labels, r.vec, origin, merged, events, timeout))
    return [(d, new_name(n)) for d, n in deviations], out


def _joined(events: list[tuple[int, int, int | None, str, str]], cls: Mapping[str, object]
            ) -> list[tuple[int, int, int | None, str, str]]:
    """Adjacent windows of one vector leading to equivalent states, as one window."""
    out: list[tuple[int, int, int | None, str, str]] = []
    for v, lo, hi, t, why in events:
        if out and out[-1][0] == v and out[-1][2] == lo and cls[out[-1][3]] == cls[t]:
            prev = out[-1]
            out[-1] = (v, prev[1], hi, prev[3], prev[4] + "; " + why)
        else:
            out.append((v, lo, hi, t, why))
    return out


def masking_labels(target: Target) -> set[str]:
    """The labels whose decision masks the device's orders (an actuator partition's)."""
    if target.existing is not None:
        return {lab for p in target.existing.partitions if p.actuators for lab in p.labels}
    return {f.code for f in target.faults if f.component == "actuator"}


def _groups(items: list[tuple[int, Cursor]], period: int) -> list[list[tuple[int, Cursor]]]:
    """The runs showing one vector, grouped so that time tells the groups apart only where
    it separates faults: each fault spans the times its runs show the vector at; faults whose
    spans overlap (or come within CLUSTER_GAP_SCANS scans) cannot be told apart by the time
    and share a group. In time order."""
    spans: dict[str, list[int]] = {}
    for t, c in items:
        span = spans.setdefault(c.fault, [t, t])
        span[0], span[1] = min(span[0], t), max(span[1], t)
    period_gap = CLUSTER_GAP_SCANS * period
    merged: list[tuple[int, int, set[str]]] = []
    for fault, (lo, hi) in sorted(spans.items(), key=lambda kv: (kv[1][0], kv[0])):
        if merged and lo <= merged[-1][1] + period_gap:
            a, b, faults = merged[-1]
            merged[-1] = (a, max(b, hi), faults | {fault})
        else:
            merged.append((lo, hi, {fault}))
    groups: list[list[tuple[int, Cursor]]] = [[] for _ in merged]
    for t, c in sorted(items, key=lambda x: (x[0], x[1])):
        k = next(i for i, (_, _, faults) in enumerate(merged) if c.fault in faults)
        groups[k].append((t, c))
    return [g for g in groups if g]


def _ms_round(us: int) -> int:
    return max(1000, (us + 500) // 1000 * 1000)


def _span(times: Sequence[int]) -> str:
    from hmi.timefmt import format_duration
    if len(times) == 1 or times[0] == times[-1]:
        return format_duration(times[0])
    return f"{format_duration(times[0])} to {format_duration(times[-1])}"


def _runs_text(items: Sequence[tuple[int, Cursor]], order: dict[str, int]) -> str:
    counts: dict[str, int] = {}
    for _, c in items:
        counts[c.fault] = counts.get(c.fault, 0) + 1
    return "runs of " + ", ".join(f"{f} ({n})" for f, n in
                                  sorted(counts.items(), key=lambda kv: order[kv[0]]))


def build_faulty(target: Target, nbm: Nbm, runs: Runs
                 ) -> tuple[list[tuple[Deviation, str]], list[FaultyState]]:
    order = {f.code: k for k, f in enumerate(target.faults)}
    builder = _Builder(target, runs, order)
    deviations = []
    found = first_deviations(nbm, target, runs)
    pieces = [piece for dev in sorted(found) for piece in split_by_time(dev, found[dev],
                                                                         nbm.margin)]
    for dev, cursors in pieces:
        what = ("no change" if dev.vec == TIMEOUT else target.vector_text(dev.vec))
        origin = f"from N{dev.state}: {what}"
        name = builder.state_for(cursors, None if dev.vec == TIMEOUT else dev.vec, origin, 0)
        deviations.append((dev, name))
    return deviations, builder.states


def split_by_time(dev: Deviation, items: Sequence[tuple[int, Cursor]], margin: int
                  ) -> list[tuple[Deviation, list[Cursor]]]:
    """The runs leaving the NBM at one deviation, told apart by when they left: each fault
    covers the times its runs left at, widened by `margin` each side (the band's plants
    leave a little earlier or later than the nominal one the runs were explored on); the
    deviation's window is cut where the set of faults covering it changes, and each piece
    enters its own faulty state. A fault seen at a time no other fault comes near is told
    apart from the first scan (a switch broken long after the dwell a glitch explains)."""
    if dev.vec == TIMEOUT or not margin:
        return [(dev, [c for _, c in items])]
    extents: dict[str, list[tuple[int, int]]] = {}
    for t, c in sorted(items, key=lambda x: (x[1].fault, x[0])):
        spans = extents.setdefault(c.fault, [])
        lo, hi = t - margin, t + margin
        if spans and lo <= spans[-1][1]:
            spans[-1] = (spans[-1][0], max(spans[-1][1], hi))
        else:
            spans.append((lo, hi))
    cuts = sorted({x for spans in extents.values() for span in spans for x in span
                   if dev.tmin < x and (dev.tmax is None or x < dev.tmax)})
    bounds: list[tuple[int, int | None]] = list(zip([dev.tmin, *cuts],
                                                    [*cuts, dev.tmax], strict=True))

    def covering(lo: int) -> frozenset[str]:
        return frozenset(f for f, spans in extents.items()
                         if any(a <= lo < b for a, b in spans))

    pieces: list[tuple[int, int | None, frozenset[str]]] = []
    for start, end in bounds:
        faults = covering(start)
        if pieces and pieces[-1][2] == faults:
            pieces[-1] = (pieces[-1][0], end, faults)
        else:
            pieces.append((start, end, faults))
    out: list[tuple[Deviation, list[Cursor]]] = []
    for start, end, _ in pieces:
        mine = [c for t, c in items if start <= t and (end is None or t < end)]
        if not mine and out:  # a time no run left at: the piece before takes it
            prev, cursors = out[-1]
            out[-1] = (replace(prev, tmax=end), cursors)
        elif not mine:  # before the first run: the piece after takes it
            out.append((Deviation(dev.state, dev.vec, start, end), []))
        elif out and not out[-1][1]:
            out[-1] = (replace(out[-1][0], tmax=end), mine)
        else:
            out.append((Deviation(dev.state, dev.vec, start, end), mine))
    return out


# --------------------------------------------------------------------------------------------
# The construction, iterated to its fixpoint under FTC
# --------------------------------------------------------------------------------------------


def instants(g: Graph, view: View, every: int) -> list[tuple[int, int, str]]:
    """(prefix index k, instant, why): every `every` scans of the fault-free cycle, and 1 us
    before and after each scan where the device's observation vector changes."""
    period = g.period_us
    first, last = g.cycle_start, len(g.prefix)
    out = [(j - 1, j * period, "") for j in range(first, last, every)]
    for j in range(first, last):
        prefix = g.prefix
        if view.vector(prefix[j], prefix[j - 1]) != view.vector(prefix[j - 1], prefix[j - 2]):
            out.append((j - 1, j * period - 1, "1 us before a change"))
            out.append((j, j * period + 1, "1 us after a change"))
    return out


def explore_runs(project: Project, configs: Sequence[LoopConfig], target: Target,
                 every: int, counter: str) -> Runs:
    faults = [f.code for f in target.faults]
    scoped = [_scoped(project, target, code) for code in faults]
    graphs, views, starts = [], [], []
    for config in configs:
        ex = Explorer(project, config, counter, settle=False)
        view = View(ex.graph, target)
        chosen = instants(ex.graph, view, every)
        mine = []
        for code, fault in zip(faults, scoped, strict=True):
            for k, at, why in chosen:
                s = ex.run(fault, k, at, why)
                mine.append((code, s.k, s.node))
        graphs.append(ex.graph)
        views.append(view)
        starts.append(mine)
    return Runs(graphs, views, starts, [c.diagnosis == "ftc" or c.key == "ftc"
                                        for c in configs])


def _scoped(project: Project, target: Target, code: str) -> str:
    return code if len(project.plant.devices) == 1 else f"{target.device}.{code}"

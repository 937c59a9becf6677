"""What the explanations of every kind share: the project's names and texts, the onsets
and the cache of the situations, the words for a variable, and the policies several kinds
offer. ExplanationBuilder (builder.py) is one; the modules that explain one stage's
situations (diagnoses, monitors, recovery, sequence) are given it as this."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

from hmi.engine import commands as cmd
from hmi.engine.snapshot import Snapshot
from hmi.explain.model import Explanation, Policy
from hmi.explain.plain import PlainNames
from hmi.project.diagnosers import diagnosers_of
from hmi.project.model import Project
from hmi.project.texts import ProjectTexts, TextSpec, fill


@dataclass
class Onset:
    """When a situation began: it keeps this while it lasts."""

    scan: int
    time_us: int


@dataclass(frozen=True)
class Levels:
    """An explanation's words before it is made: the generated ones, which the project's
    texts (explanations.yaml) may replace level by level."""

    what: str
    why: str
    consequences: str
    policies: tuple[Policy, ...]
    severity: str
    alarm: bool
    detail: str


class ExplanationContext:
    """What every kind of explanation reads besides the snapshot: the project's names and
    texts, each situation's onset (scan, time) while it lasts, and the explanations already
    made for a situation with their signature (rebuilt only when it changes)."""

    def __init__(self, project: Project, texts: ProjectTexts | None = None):
        self.project = project
        self.texts = texts or project.explanations or ProjectTexts()
        self.onsets: dict[str, Onset] = {}
        self.cache: dict[str, tuple[tuple[object, ...], Explanation]] = {}
        self.devices = {v.name: (v.device or project.name)
                        for v in (*project.inputs, *project.outputs)}
        self.describe = project.describe
        # Devices the operator can stop (those with outputs), and the diagnosers' models.
        self.stoppable = {v.device for v in project.outputs if v.device}
        self.diagnosers = {spec.name: spec for spec in diagnosers_of(project)}
        self.plain = PlainNames(project)
        # Inputs that are a device's own fault signal (hmi.explain.device_faults).
        self.fault_inputs = tuple(v.name for v in project.inputs if v.fault)

    def onset(self, key: str, snap: Snapshot) -> Onset:
        onset = self.onsets.get(key)
        if onset is None:
            onset = self.onsets[key] = Onset(snap.scan, snap.time_us)
        return onset

    def cached(self, key: str, signature: tuple[object, ...],
               make: Callable[[], Explanation]) -> Explanation:
        hit = self.cache.get(key)
        if hit is not None and hit[0] == signature:
            return hit[1]
        explanation = make()
        self.cache[key] = (signature, explanation)
        return explanation

    def apply_texts(self, spec: TextSpec, defaults: Levels, values: dict[str, Any]) -> Levels:
        """The four levels, each from the project's text when it has one, else the default."""
        out = replace(
            defaults,
            what=fill(spec.what, values) if spec.what else defaults.what,
            why=fill(spec.why, values) if spec.why else defaults.why,
            consequences=(fill(spec.consequences, values) if spec.consequences
                          else defaults.consequences),
            detail=fill(spec.detail, values) if spec.detail else defaults.detail)
        if spec.severity:
            out = replace(out, severity=spec.severity)
        if spec.alarm is not None:
            out = replace(out, alarm=spec.alarm)
        if spec.policies or spec.recommend:
            policies = []
            for policy in out.policies:
                effect = spec.policies.get(policy.id)
                recommended = (policy.id == spec.recommend) if spec.recommend else \
                    policy.recommended
                policies.append(Policy(policy.id, policy.label,
                                       fill(effect, values) if effect else policy.effect,
                                       policy.command, recommended))
            out = replace(out, policies=tuple(policies))
        return out

    def device_of(self, names: Iterable[str]) -> str:
        for name in names:
            if name in self.devices:
                return self.devices[name]
        return self.project.name

    def devices_of(self, names: Iterable[str]) -> set[str]:
        """The devices these variables belong to."""
        return {self.devices[n] for n in names if n in self.devices}

    def short(self, name: str) -> str:
        """A variable's description without its device's name ("open order", not "Valve V1
        open order"), for sentences that already name the device."""
        desc = self.describe(name)
        device = self.devices.get(name)
        if device and desc.lower().startswith(device.lower()):
            desc = desc[len(device):].strip(" :-—")
        return desc or name

    def literal_values(self, literals: Iterable[tuple[str, object]]) -> str:
        """`C=1 (close order); prev(C)=0; fso=0 (open end switch)` from a violation."""
        parts = []
        seen: set[str] = set()
        for literal, value in literals:
            core = literal[4:] if literal.startswith("not ") else literal
            name = core[5:].split(",")[0].rstrip(")") if core.startswith("prev(") else core
            text = f"{core}={int(value) if isinstance(value, bool) else value}"
            if name not in seen and self.describe(name) != name:
                text += f" ({self.short(name)})"
                seen.add(name)
            parts.append(text)
        return "; ".join(parts)

    def var_text(self, name: str, value: object) -> str:
        desc = self.describe(name)
        shown = int(value) if isinstance(value, bool) else value
        return f"{name}={shown}" + (f" ({desc})" if desc != name else "")

    # -- policies shared by several kinds ---------------------------------------------------
    @staticmethod
    def policy_continue(effect: str, recommended: bool = False) -> Policy:
        return Policy("continue", "Continue", effect, None, recommended)

    @staticmethod
    def policy_manual(recommended: bool = False) -> Policy:
        return Policy("manual", "Switch to manual",
                      "the control program stops driving the outputs; your requests still go "
                      "through the safety filter", cmd.SetMode(True), recommended)

    @staticmethod
    def policy_stop(device: str, recommended: bool = False) -> Policy:
        return Policy("stop_device", f"Stop {device}",
                      f"hold every output of {device} at its safe value until you release it",
                      cmd.StopDevice(device), recommended)

    @staticmethod
    def policy_reset(effect: str, recommended: bool = False) -> Policy:
        return Policy("reset", "Fault reset", effect, cmd.FaultReset(), recommended)

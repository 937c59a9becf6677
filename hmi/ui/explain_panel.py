"""The explanation panel: the selected alarm's graduated explanation, level by level.

000 asks for "a graduated explanation with potential consequences" so that the operator can
choose the best policy. The levels of :class:`~hmi.explain.model.Explanation` are shown one
under the other, the first always, the others on demand; the fifth, the engineering detail
(diagnoser states, constraints, flags, stopwatch values), comes after the policies::

    P2 medium · Conveyor C1 · since 3.000 s (scan 301) · LATCHED
    Conveyor C1 carrying a pallet …: cannot end within its acceptable time (conveyor_fault)
    ▾ Why
      Stopwatch monitor conveyor: at scan 301 (3.000 s), x = 3.000 s …
    ▸ Consequences
    ▸ Policies · 3, recommended: Continue

``e`` opens the next level (and, once all five are open, folds them back to the first); a click
on a level's heading opens it (with the levels before it) or folds it (with those after).
The level just opened is scrolled to the top of the panel; when the text is taller than the
panel the subtitle says ``↑↓ scroll`` and the panel has the focus (tab moves on), so the
arrows scroll it. Opening the policies focuses the recommended one: enter chooses it. Each
policy is a button with its effect beside it; choosing one asks the app
(:class:`PolicyRequested`), which
confirms the choices that change what the plant does and sends ``ChoosePolicy``; the
result is shown here at once, under the buttons, as well as on the message line — while the
explanation it answered is the one shown, and until a fault reset or a repair changes the
situation it spoke of (the app then forgets it).

An ambiguous diagnosis says so in its heading (``? AMBIGUOUS``): the labels it cannot tell
apart are in its first line, and the recommended check in its policies.

The panel rebuilds its widgets only when the explanation, the open levels or a result
change (an explanation object is kept by the engine while its situation lasts), so a
frame where nothing changed costs a comparison.
"""

from __future__ import annotations

from typing import Any

from rich.style import Style
from rich.text import Text
from textual import events, on
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.message import Message
from textual.widgets import Button, Static

from hmi.explain.alarms import CLEARED_UNACK, PRIORITY, Alarm
from hmi.explain.model import Explanation, Policy
from hmi.timefmt import seconds
from hmi.ui.containment import ContainedPump
from hmi.ui.panel import set_title
from hmi.ui.style import MUTED, OK_SYMBOL, STYLE, Level, tag
from hmi.ui.textual_adapter import VirtualSizeHook

LEVELS = ("What", "Why", "Consequences", "Policies", "Engineering detail")
TOP = len(LEVELS)
RECOMMENDED = "★"
SEVERITY_LEVEL = {"high": Level.ALARM, "medium": Level.ATTENTION, "low": Level.ATTENTION}


class PolicyRequested(Message):
    """The operator pressed a policy's button: the app confirms if needed, then sends it."""

    def __init__(self, key: str, policy: Policy) -> None:
        super().__init__()
        self.key = key
        self.policy = policy


class ExplanationShown(Message):
    """The panel appeared or went away (on a narrow screen it takes the chronogram's place)."""

    def __init__(self, visible: bool) -> None:
        super().__init__()
        self.visible = visible


class LevelView(ContainedPump, Static):
    """One level: its heading, and its text when open. A click opens or folds it."""

    def __init__(self, level: int, *, id: str | None = None):
        super().__init__(id=id, markup=False, classes="explain-level")
        self.level = level

    def on_click(self, event: events.Click) -> None:
        event.stop()
        panel = next(a for a in self.ancestors if isinstance(a, ExplanationPanel))
        panel.toggle(self.level)


def heading_text(explanation: Explanation, alarm: Alarm | None) -> Text:
    """Priority, severity, device, since when, and the marks that change how to read it.

    An alarm's priority is the one its row in the list shows: the highest it had while
    listed (hmi.explain.alarms), not the situation's severity now, which may have come down
    (a diagnosis first ambiguous, P1, then certain and degraded, medium): that one follows
    as ``now medium``."""
    severity = alarm.severity if alarm is not None else explanation.severity
    priority = PRIORITY.get(severity, 3)
    level = SEVERITY_LEVEL.get(severity, Level.ATTENTION)
    text = Text(no_wrap=True, overflow="ellipsis")
    if explanation.alarm:
        text.append_text(tag(f"P{priority} {severity}", level))
        if severity != explanation.severity:
            text.append(f" · now {explanation.severity}", style=MUTED)
    else:
        text.append(f"{explanation.severity} (no alarm)", style=MUTED)
    # the marks that change how to read it first: the end of the line may be cut
    if explanation.ambiguous:
        text.append(" · ")
        text.append("? AMBIGUOUS", style=STYLE[Level.ATTENTION])
    if explanation.latched:
        text.append(" · LATCHED", style=Style(bold=True))
    if alarm is not None and alarm.state == CLEARED_UNACK:
        text.append(f" · ○ cleared at {seconds(alarm.changed_us)} s", style=MUTED)
    text.append(f" · {explanation.device} · since {seconds(explanation.since_us)} s "
                f"(scan {explanation.since_scan})", style=MUTED)
    return text


def level_text(explanation: Explanation, level: int, open_: bool) -> Text:
    """A level's heading (▸ closed, ▾ open) and, when open, its text, indented."""
    title = LEVELS[level - 1]
    text = Text()
    if level == 4:
        rec = explanation.recommended
        count = len(explanation.policies)
        head = f"{'▾' if open_ else '▸'} {title} · {count}"
        if rec is not None:
            head += f", recommended: {rec.label}"
        text.append(head, style=Style(bold=open_))
        return text
    text.append(f"{'▾' if open_ else '▸'} {title}", style=Style(bold=open_))
    if open_:
        body = explanation.levels[level - 1]
        for line in body.splitlines():
            text.append("\n  " + line)
    return text


def policy_label(policy: Policy) -> str:
    return f"{RECOMMENDED} {policy.label}" if policy.recommended else policy.label


def policy_effect(policy: Policy) -> Text:
    text = Text()
    if policy.recommended:
        text.append("recommended · ", style=Style(bold=True))
    text.append(policy.effect)
    if policy.command is None:
        text.append(" (nothing is sent)", style=MUTED)
    return text


class ExplanationPanel(VirtualSizeHook, ContainedPump, VerticalScroll):
    """The graduated explanation of one situation (the app says which: `key`)."""

    can_focus = True  # ↑↓ scroll it (its bindings); tab goes on to the policy buttons

    def __init__(self, *, id: str | None = None):
        super().__init__(id=id)
        self.key: str | None = None
        self.explanation: Explanation | None = None
        self.alarm: Alarm | None = None
        self.levels: dict[str, int] = {}  # open levels per situation (1: the first only)
        # the last policy choice's answer, per situation, with the explanation it answered
        self.results: dict[str, tuple[Text, int]] = {}
        self.wide = True
        self._drawn: tuple[Any, ...] | None = None
        self._policies: tuple[Policy, ...] | None = None
        self._focus_recommended = False
        self._answered: Text | None = None
        self._pending_end = False
        # The level just opened, kept at the top of the panel while the panel is laid out
        # again (it appears, widens, its text reflows), until the operator scrolls.
        self._anchor: int | None = None
        self._contents: dict[str | None, Text | str] = {}  # each part's text as shown
        self.visible = True

    def compose(self) -> ComposeResult:
        yield Static(id="explain-head", markup=False)
        yield Static(id="explain-what", markup=False)
        yield LevelView(2, id="explain-why")
        yield LevelView(3, id="explain-consequences")
        yield LevelView(4, id="explain-policies-head")
        yield Vertical(id="explain-policies")
        yield LevelView(5, id="explain-detail")
        yield Static(id="explain-result", markup=False)

    def on_mount(self) -> None:
        self.border_title = "Explanation"

    # -- what the app sets -------------------------------------------------------------------
    @property
    def level(self) -> int:
        return self.levels.get(self.key, 1) if self.key else 1

    def show(self, key: str | None, explanation: Explanation | None, alarm: Alarm | None,
             wide: bool) -> None:
        """Explain `key` (None: nothing selected); `alarm` when it is an alarm's."""
        if key != self.key:
            self._anchor = None
        self.key, self.explanation, self.alarm, self.wide = key, explanation, alarm, wide
        self._draw()

    def open_next_level(self) -> None:
        """``e``: open the next level; after the last, fold back to the first."""
        if self.key is None or self.explanation is None:
            return
        level = self.level
        self._set_level(1 if level >= TOP else level + 1)

    def toggle(self, level: int) -> None:
        """A heading clicked: open up to it, or fold it and those after it."""
        if self.key is None:
            return
        self._set_level(level - 1 if self.level >= level else level)

    def open_to(self, level: int) -> None:
        if self.key is not None:
            self._set_level(level)

    def say_result(self, key: str, text: Text) -> None:
        shown = self.explanation if key == self.key else None
        self.results[key] = (text, id(shown))
        self._draw()

    def forget_results(self) -> None:
        """The situations the answers spoke of changed (a fault reset, a repair): the
        answers are history now, the message line and the journal keep them."""
        if self.results:
            self.results.clear()
            self._draw()

    def _answer(self) -> Text | None:
        """The answer to the last policy chosen here, if it answered this explanation."""
        found = self.results.get(self.key or "")
        if found is None or found[1] != id(self.explanation):
            return None
        return found[0]

    def _set_level(self, level: int) -> None:
        assert self.key is not None
        opened = level > self.level
        self.levels[self.key] = level
        self._focus_recommended = level == 4
        self._anchor = level if opened and level > 1 else None
        self._draw()
        if opened and 1 < level != 4 and self.visible and not self.has_focus:
            self.focus(scroll_visible=False)  # ↑↓ scroll it

    # -- drawing -----------------------------------------------------------------------------
    def _draw(self) -> None:
        exp = self.explanation
        level = self.level
        # wide: always there; narrow: only once opened past the first level (the alarm
        # list already shows that line), in the chronogram's place
        visible = self.wide or (exp is not None and level >= 2)
        if visible != self.visible or self._drawn is None:
            self.visible = visible
            self.display = visible
            self.post_message(ExplanationShown(visible))
        answer = self._answer()
        alarm = self.alarm
        state = (self.key, id(exp), (alarm.state, alarm.severity) if alarm else None, level,
                 answer, self.wide)
        if state == self._drawn:
            return
        self._drawn = state
        head = self.query_one("#explain-head", Static)
        what = self.query_one("#explain-what", Static)
        views = [self.query_one(f"#explain-{n}", LevelView)
                 for n in ("why", "consequences", "policies-head", "detail")]
        result = self.query_one("#explain-result", Static)
        if exp is None:
            set_title(self, "Explanation")
            self._set_subtitle("")
            self._put(head, Text(f"{OK_SYMBOL} no alarm to explain", style=MUTED))
            self._put(what, "")
            for view in views:
                view.display = False
            self._set_policies(())
            self._put(result, "")
            result.display = False
            return
        set_title(self, f"Explanation · {exp.kind}")
        self._set_subtitle()
        self._put(head, heading_text(exp, self.alarm))
        self._put(what, Text(exp.what, style=Style(bold=True)))
        for view in views:
            view.display = view.level < 5 or bool(exp.detail)
            self._put(view, level_text(exp, view.level, level >= view.level))
        self._set_policies(exp.policies if level >= 4 else ())
        self._put(result, answer or "")
        result.display = answer is not None  # empty, its margin would make the text scroll
        if answer is not None and answer is not self._answered:
            self._answered = answer  # a new answer: make sure it is seen
            self._pending_end = True  # the answer is the last line: scroll to it once laid out
        if self._focus_recommended:
            self._focus_recommended = False
            self.call_after_refresh(self._focus_policy)

    def _set_subtitle(self, subtitle: str | None = None) -> None:
        """`level 2/5 · e: more`, and `↑↓ scroll` while the text is taller than the panel."""
        if subtitle is None:
            level = self.level
            subtitle = f"level {level}/{TOP} · e: {'more' if level < TOP else 'fold'}"
            if self.max_scroll_y > 0:
                subtitle += " · ↑↓ scroll"
        if self.border_subtitle != subtitle:
            self.border_subtitle = subtitle

    def virtual_size_placed(self) -> None:
        # A new virtual size has its place (hmi.ui.textual_adapter.VirtualSizeHook): the
        # first moment the new lines can be scrolled to.
        if self.explanation is not None:
            self._set_subtitle()
        if self._pending_end:  # the answer's lines are laid out now
            self._pending_end = False
            self._anchor = None
            self.scroll_end(animate=False, immediate=True)
        elif self._anchor is not None:
            self.call_after_refresh(self._scroll_to_anchor)

    def on_resize(self) -> None:
        if self._anchor is not None:
            self.call_after_refresh(self._scroll_to_anchor)

    def _scroll_to_anchor(self) -> None:
        if self._anchor is None or self.explanation is None:
            return
        view = self.query_one(("#explain-why", "#explain-consequences",
                               "#explain-policies-head", "#explain-detail")[self._anchor - 2])
        if self.scroll_y != view.virtual_region.y:
            self.scroll_to(y=view.virtual_region.y, animate=False, immediate=True)

    # The operator scrolls: the level opened no longer holds the top.
    def action_scroll_up(self) -> None:
        self._anchor = None
        super().action_scroll_up()

    def action_scroll_down(self) -> None:
        self._anchor = None
        super().action_scroll_down()

    def action_page_up(self) -> None:
        self._anchor = None
        super().action_page_up()

    def action_page_down(self) -> None:
        self._anchor = None
        super().action_page_down()

    def action_scroll_home(self) -> None:
        self._anchor = None
        super().action_scroll_home()

    def action_scroll_end(self) -> None:
        self._anchor = None
        super().action_scroll_end()

    def on_mouse_scroll_up(self) -> None:
        self._anchor = None

    def on_mouse_scroll_down(self) -> None:
        self._anchor = None

    def _put(self, widget: Static, content: Text | str) -> None:
        """Update a part only when its text changed: an update re-lays the screen out."""
        if self._contents.get(widget.id) != content:
            self._contents[widget.id] = content
            widget.update(content)

    def _set_policies(self, policies: tuple[Policy, ...]) -> None:
        if policies == self._policies:
            return
        self._policies = policies
        box = self.query_one("#explain-policies", Vertical)
        box.remove_children()
        rows = []
        for index, policy in enumerate(policies):
            button = Button(policy_label(policy), id=f"policy-{index}", compact=True,
                            classes="policy-button")
            button.policy = policy  # type: ignore[attr-defined]
            rows.append(Horizontal(button, Static(policy_effect(policy), markup=False,
                                                  classes="policy-effect"),
                                   classes="policy-row"))
        if rows:
            box.mount(*rows)

    def _focus_policy(self) -> None:
        buttons = list(self.query(".policy-button").results(Button))
        chosen = next((b for b in buttons if (policy := getattr(b, "policy", None)) is not None
                       and policy.recommended), buttons[0] if buttons else None)
        if chosen is not None:
            chosen.focus(scroll_visible=False)  # the policies' heading is scrolled to

    @on(Button.Pressed, ".policy-button")
    def _pressed(self, event: Button.Pressed) -> None:
        event.stop()
        policy = getattr(event.button, "policy", None)
        if policy is not None and self.key is not None:
            self.post_message(PolicyRequested(self.key, policy))


def result_line(key: str, policy: Policy, accepted: bool, message: str) -> Text:
    """The answer to a policy choice, for the panel: the message line's (`message`: "policy
    'Fault reset' chosen: released: …", or the engine's, "… chosen for KEY: …") without the
    part that repeats the policy and the situation."""
    _, found, rest = message.partition(f" for {key}: ")
    if not found and message.startswith(f"policy '{policy.label}' "):
        _, found, rest = message.partition(": ")
    answer = rest if found else message
    if accepted:
        return Text(f"{OK_SYMBOL} {policy.label} chosen: {answer}")
    line = tag("REFUSED", Level.ALARM)
    line.append(f" {policy.label}: {answer}")
    return line


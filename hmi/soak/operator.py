"""The soak's operator: random, but reproducible from its seed.

It looks at the app as an operator would (which screen is on top, which palette entries exist
now, whether manual mode is on) and picks its next gesture: run virtual time; press a key of
the footer (or 1 / 0 / x / b, tab, arrows, enter, escape); run a palette entry, any of them,
by its exact title; click a row of the I/O table, a constraint, an alarm, an explanation's
heading or policy; resize the terminal between 60×20 and 200×60. A dialog on top is answered:
yes, no, escape, enter (which must not confirm), g (the fault reset's third answer, Start
recovery, when it offers one), or filled in (a fault and when, a number of scans, a policy,
chronogram signals, a comment on an alarm). Fault injections, repairs, resets, manual mode
with forces and policy changes come from the footer and the palette like any other gesture,
with weights that make them frequent. The choice depends only on the seed and on what the
app shows, so the same seed on the same program gives the same session. Time also runs
while a dialog is open (the operator reads it; the cell goes on), so a confirmation may be
answered after what it said has changed.
"""

from __future__ import annotations

import random
from typing import TYPE_CHECKING, Any

from textual.command import CommandPalette
from textual.screen import ModalScreen, Screen

from hmi.soak.steps import Click, Palette, Press, Resize, Row, Run, Step
from hmi.ui.actions import ACTIONS
from hmi.ui.dialogs import ChoiceDialog, ConfirmDialog, StepDialog, TextDialog
from hmi.ui.fault_dialog import FaultDialog
from hmi.ui.signal_dialog import SignalDialog
from hmi.ui.trend_screen import TrendScreen

if TYPE_CHECKING:
    from hmi.ui.app import PlcHmiApp

MAIN_KEYS = (*(a.key for a in ACTIONS), "1", "0", "x", "b", "tab", "shift+tab", "up", "down",
             "enter", "home", "end", "escape")
# the keys that change the cell most, drawn more often than the others
HEAVY_KEYS = ("r", "m", "p", "f", "a", "A", "e", "space")
CLICK_TARGETS = ("#constraints", "#alarms", "#explain", "#io", "#chronogram", "#status",
                 "#banners", "#sim")
MIN_SIZE, MAX_SIZE = (60, 20), (200, 60)
REPAIR = "SIMULATION: repair the faulty devices"
RECLAIM = "Control: request it"
READING = 0.15  # how often virtual time runs while a dialog is open, before its answer
# what an operator writes on an alarm: plain words, and text that looks like markup, quotes,
# a backslash, non-ASCII letters, one long line
COMMENTS = ("checked on site", "[b]sticky[/b] valve", 'called "maintenance" 50%', "a\\b {x}",
            "Kühlung prüfen", "ok " * 60)


class RandomOperator:
    def __init__(self, seed: int):
        self.seed = seed
        self.rng = random.Random(seed)

    def next(self, app: PlcHmiApp) -> Step:
        screen = app.screen
        if isinstance(screen, CommandPalette):
            return Press(("escape",))
        if isinstance(screen, ModalScreen):
            if self.rng.random() < READING:
                # the operator reads the dialog while the cell runs on (live, the scans never
                # wait for a dialog): what it previewed may no longer hold when answered
                return Run(int(10_000 * 500 ** self.rng.random()))  # 10 ms to 5 s
            return self._answer(screen)
        return self._main(app)

    # -- the main screen ----------------------------------------------------------------------
    def _main(self, app: PlcHmiApp) -> Step:
        rng = self.rng
        paused = not app.running
        weights = {
            "run": 6 if paused else 36,
            "resume": 20 if paused else 0,
            "key": 26,
            "heavy": 10,
            "palette": 14,
            "row": 6,
            "click": 6,
            "resize": 3,
            # the technician's repair, while the SIMULATION strip shows faults: a palette
            # entry among 15 to 40 of its group, drawn by its group alone it came once in
            # ~30 injections, and the way back (repair, fault reset, automatic operation)
            # was seldom walked. Last, with no weight otherwise: the other draws unchanged.
            "repair": 3 if app.frame is not None and app.frame.injected else 0,
            # an operator who released control (or had it taken) asks for it back: drawn by
            # its group alone, "Control: request it" came seldom, and seeds spent most of
            # their session with every command refused ("nobody is in control"). Last, with
            # no weight while in control: the other draws unchanged.
            "reclaim": 8 if not app.in_control and any(
                e.title == RECLAIM for e in app.palette_entries()) else 0,
        }
        kind = rng.choices(list(weights), list(weights.values()))[0]
        match kind:
            case "run":
                return Run(self._duration())
            case "resume":
                return Press(("space",))
            case "key":
                return Press((rng.choice(MAIN_KEYS),))
            case "heavy":
                return Press((rng.choice(HEAVY_KEYS),))
            case "palette":
                return self._palette(app)
            case "row":
                outputs = app.facts.layout.outputs
                names = outputs if rng.random() < 0.8 else app.facts.layout.names
                row = Row(rng.choice(names))
                return row
            case "repair":
                return Palette(REPAIR)
            case "reclaim":
                return Palette(RECLAIM)
            case "click":
                target = rng.choice(CLICK_TARGETS)
                return Click(target, rng.randrange(0, 60), rng.randrange(0, 8))
        return Resize(rng.randint(MIN_SIZE[0], MAX_SIZE[0]), rng.randint(MIN_SIZE[1],
                                                                         MAX_SIZE[1]))

    def _duration(self) -> int:
        """10 ms to 60 s of virtual time, log-uniform: short steps and long waits alike (an
        operator watches the cell for a minute as often as for a scan)."""
        return int(10_000 * 6000 ** self.rng.random())

    def _palette(self, app: PlcHmiApp) -> Step:
        """Any palette entry, by group first (the text before ':' — manual, alarms, policy,
        simulation, chronogram...) so that the long groups do not drown the others."""
        entries = app.palette_entries()
        groups: dict[str, list[str]] = {}
        for entry in entries:
            groups.setdefault(entry.title.split(":")[0].split()[0], []).append(entry.title)
        group = self.rng.choice(sorted(groups))
        return Palette(self.rng.choice(groups[group]))

    # -- a dialog on top ----------------------------------------------------------------------
    def _answer(self, screen: Screen[Any]) -> Step:
        rng = self.rng
        if isinstance(screen, ConfirmDialog):
            answers = {"y": 40, "n": 20, "escape": 15, "enter": 12, "tab": 5, "stray": 8}
            if screen.id == "quit-dialog":
                answers["y"] = 0  # the soak goes on
            if screen.alternative:  # the reset dialog's third answer: g, Start recovery
                answers["g"] = 25
            answer = rng.choices(list(answers), list(answers.values()))[0]
            if answer == "stray":  # a main-screen key: the dialog must not let it through
                return Press((rng.choice(("r", "m", "space", "1", "s", "a")),))
            return Press((answer,))
        if isinstance(screen, ChoiceDialog):
            if rng.random() < 0.25:
                return Press(("escape",))
            moves = ("down",) * rng.randrange(0, 4)
            return Press((*moves, "enter"))
        if isinstance(screen, StepDialog):
            roll = rng.random()
            if roll < 0.2:
                return Press(("escape",))
            if roll < 0.3:  # not a valid count: the dialog says so and stays
                return Press((*rng.choice(("0", "abc", "99999")), "enter"))
            count = str(rng.choice((1, 2, 5, 10, 50, 100, 500, 1000)))
            return Press(("end", "backspace", "backspace", "backspace", *count, "enter"))
        if isinstance(screen, FaultDialog):
            if rng.random() < 0.2:
                return Press(("escape",))
            moves = ("down",) * rng.randrange(0, len(screen.faults) or 1)
            delay = str(rng.choice((0, 0, 0, 1, 2, 5, 10, 30)))
            return Press((*moves, "enter", "backspace", *delay, "enter"))
        if isinstance(screen, TextDialog):  # a comment on an alarm
            roll = rng.random()
            if roll < 0.2:
                return Press(("escape",))
            if roll < 0.3:  # nothing written: the dialog says so and stays
                return Press(("enter",))
            text = rng.choice(COMMENTS)
            return Press((*("space" if c == " " else c for c in text), "enter"))
        if isinstance(screen, TrendScreen):  # the trends: look around, then back
            keys = {"escape": 15, "left": 10, "right": 10, "shift+left": 8, "shift+right": 8,
                    "plus": 8, "minus": 8, "end": 6, "home": 6, "g": 5, "left_square_bracket": 3}
            return Press((rng.choices(list(keys), list(keys.values()))[0],))
        if isinstance(screen, SignalDialog):
            if rng.random() < 0.2:
                return Press(("escape",))
            presses: list[str] = []
            for _ in range(rng.randrange(1, 5)):
                presses += ["down"] * rng.randrange(0, 4) + ["space"]
            return Press((*presses, "enter"))
        return Press(("escape",))  # a screen of Textual's own (help...): back

"""What a screen makes of the runtime's messages: the cell's facts, the latest view, the
history mirror, the answers awaited. Shared by the socket link and the in-process one, so
both show exactly what the runtime sent.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from hmi.engine.commands import CommandResult
from hmi.link.base import Answer, View
from hmi.project.model import Project
from hmi.session.recorder import Changes, Cursor, ScanRecorder
from hmi.wire import messages as m
from hmi.wire.codec import Codec


class Receiver:
    """The screen's side of the protocol's state (messages in, a consistent view out)."""

    def __init__(self, project: Project):
        self.project = project
        self.facts: m.CellFacts | None = None
        self.client: str | None = None
        self.runtime: m.RuntimeInfo | None = None
        self.history: ScanRecorder | None = None
        self._view: View | None = None
        self.control: m.ControlInfo | None = None
        self.frames = 0
        self.lost: str | None = None
        # told of each frame once applied, in order (the OPC UA gateway: every scan's alarm
        # transitions); in the thread that took it, so a listener must not wait
        self.listeners: list[Callable[[m.Frame], None]] = []
        self.listener_errors = 0
        # answers awaited, by id: (event, the answer once it came)
        self._pending: dict[int, list[Any]] = {}
        self._lock = threading.Lock()
        self._next_id = 0
        # Decoding: a snapshot's layout is the Welcome's; a layout's GRAFCET comes from the
        # project loaded here (set once the Welcome says which control variant runs).
        self.codec: Codec = m.codec(layout=self._layout, grafcet=lambda: None)

    def _layout(self) -> Any:
        assert self.facts is not None, "a frame before the Welcome"
        return self.facts.layout

    # -- messages in ---------------------------------------------------------------------
    def decode(self, data: bytes) -> m.RuntimeMessage:
        message: m.RuntimeMessage = self.codec.loads(data, m.RuntimeMessage)
        return message

    def welcome(self, welcome: m.Welcome) -> None:
        facts = welcome.facts
        law = self.project.controls.get(facts.control)
        if law is None:
            raise ValueError(f"the runtime runs control variant {facts.control!r}, which the "
                             "project loaded here does not have")
        self.facts = replace(facts, layout=replace(facts.layout, grafcet=law.grafcet))
        self.client = welcome.client
        self.runtime = welcome.runtime
        self.history = ScanRecorder(self.facts.layout)

    def take(self, message: m.RuntimeMessage) -> None:
        """Apply one message (a frame, an answer, the runtime closing)."""
        match message:
            case m.Frame():
                self._frame(message)
            case m.Reply(id=ident) | m.Stats(id=ident):
                with self._lock:
                    slot = self._pending.get(ident)
                if slot is not None:
                    slot[1] = message
                    slot[0].set()
            case m.Closing(why=why):
                self.lose(f"the runtime stopped: {why}")
            case m.Refused(reason=reason):
                self.lose(f"the runtime refused this screen: {reason}")
            case m.Tick() | m.Welcome():
                pass

    def _frame(self, frame: m.Frame) -> None:
        history = self.history
        assert history is not None, "a frame before the Welcome"
        delta = frame.history
        history.apply(Changes(
            frame.cell, delta.full, delta.edges, delta.events, delta.event_count,
            delta.damage_count, dict(delta.constraints),
            tuple((b.events, b.alarms) for b in delta.alarm_batches), delta.batches_lost,
            Cursor(frame.cell.snapshot.time_us, delta.event_count, 0)))
        self.control = frame.control
        self._view = View(frame.cell, delta.constraints, delta.damage_count, frame.run,
                          frame.overruns, frame.control, frame.services)
        self.frames += 1
        for listener in list(self.listeners):
            try:
                listener(frame)
            except Exception:  # a listener's failure is its own, never the link's
                self.listener_errors += 1

    def view(self) -> View | None:
        return self._view

    def lose(self, why: str) -> None:
        """The runtime is gone: every answer awaited is refused with why (and when)."""
        if self.lost is None:
            self.lost = f"{why} (at {time.strftime('%H:%M:%S')})"
        with self._lock:
            pending = list(self._pending.values())
        for slot in pending:
            slot[0].set()

    # -- answers awaited -----------------------------------------------------------------
    def expect(self) -> tuple[int, list[Any]]:
        with self._lock:
            self._next_id += 1
            slot: list[Any] = [threading.Event(), None]
            self._pending[self._next_id] = slot
            return self._next_id, slot

    def answer(self, ident: int, slot: list[Any], timeout: float) -> m.RuntimeMessage | None:
        slot[0].wait(timeout)
        with self._lock:
            self._pending.pop(ident, None)
        answer: m.RuntimeMessage | None = slot[1]
        return answer

    def result(self, answer: m.RuntimeMessage | None, what: str) -> Answer:
        if isinstance(answer, m.Reply):
            return Answer(answer.result, answer.declined)
        why = self.lost or f"no answer from the runtime to {what}"
        return Answer(CommandResult.refused(f"not done: {why}"))

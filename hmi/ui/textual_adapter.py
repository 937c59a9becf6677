"""Textual's private members that plchmi relies on: every one of them is used here, and only
here, behind a name that says what plchmi needs of it.

Textual has no public interface for these. tests/test_textual_adapter.py checks each one
against the installed Textual (it exists, and does what the code below counts on), so a
release that renames or changes one fails there, naming the member, rather than in an
operator's HMI or as a test that hangs; it also checks that no other module
touches a private member of Textual. The Textual versions they were checked with are
pyproject.toml's range.

1. Containing errors: ``MessagePump._dispatch_message``, where every event and message of a
   node is handled (:class:`GuardedDispatch`), and ``App._handle_exception``, Textual's
   last resort before it ends the app (:class:`LastResort`).
2. Scrolling to new lines: ``Widget._scroll_update``, the first moment a new virtual size
   has its place (:class:`VirtualSizeHook`).
3. The CSS parse: ``Stylesheet._parse_rules`` with the stylesheet's ``_parse_cache`` and
   ``_variables`` (hmi/ui/csscache.py keeps parsed rules across starts).
4. Screens refreshed in virtual time: the screen's refresh timer (``Screen.__update_timer``,
   created at first use) and what it runs, ``Screen._on_timer_update``, with what that would
   do (``_layout_required``, ``_repaint_required``, ``_recompose_required``,
   ``_dirty_widgets``, ``_callbacks``); and a node's ``_next_callbacks`` (run after its
   current message).
5. Painting headless: ``Screen._compositor_refresh`` and the screen's ``_compositor`` (its
   ``_dirty_regions``, ``render_update``), ``App._update_mouse_over``.
6. The footer: a node's reactive watchers (``__watchers``) and whether a node is closed
   (``_closing``/``_closed``), so that the footer drops the keys it removed; its keys'
   class, ``FooterKey`` (``textual.widgets._footer``), and whether it may build them yet
   (``Footer._bindings_ready``).
7. Widgets' rendered lines freed with their widgets: ``StylesCache.get_inner_outer``
   (``textual._styles_cache``), whose ``lru_cache`` keeps the widget's StylesCache alive
   (:func:`release_styles_caches`); a DataTable's render caches of cells, rows and lines
   (``_row_render_cache``, ``_cell_render_cache``, ``_row_renderable_cache``,
   ``_line_cache``), whose keys all hold the table's ``_update_count``
   (:func:`drop_stale_renders`).
8. The command palette's "no matches" countdown (``CommandPalette._start_no_matches_countdown``,
   the timer it keeps in ``_no_matches_timer`` and that timer's ``_callback``), which could
   run after the palette was dismissed (:func:`guard_palette_countdown`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache, partial
from typing import Any

from rich.console import RenderableType
from textual._styles_cache import StylesCache
from textual.app import App
from textual.command import CommandList, CommandPalette
from textual.css.stylesheet import Stylesheet
from textual.message import Message
from textual.message_pump import MessagePump
from textual.screen import Screen
from textual.widgets import DataTable, Footer
from textual.widgets._footer import FooterKey as FooterKey

# -- 1. containing errors ------------------------------------------------------------------


class GuardedDispatch:
    """Mixin for a Textual node: :meth:`handler_failed` hears every exception one of its
    handlers raises; it returns True if it dealt with it, else the exception goes on to
    Textual (which ends the app)."""

    async def _dispatch_message(self, message: Message) -> None:
        try:
            await super()._dispatch_message(message)  # type: ignore[misc]
        except Exception as exc:
            if not self.handler_failed(message, exc):
                raise

    def handler_failed(self, message: Message, error: Exception) -> bool:
        return False


class LastResort:
    """Mixin for the app: :meth:`last_resort` hears an error that reached Textual's last
    resort (an error in its own widgets, the compositor, a timer's callback), before
    Textual ends the app."""

    def _handle_exception(self, error: Exception) -> None:
        self.last_resort(error)
        super()._handle_exception(error)  # type: ignore[misc]

    def last_resort(self, error: Exception) -> None:
        pass


# -- 2. scrolling to new lines ------------------------------------------------------------


class VirtualSizeHook:
    """Mixin for a scrolling widget: :meth:`virtual_size_placed` is called once a new virtual
    size has its place (scroll bars and scroll limits updated), the first moment scrolling
    to the new lines reaches them."""

    def _scroll_update(self, virtual_size: Any) -> None:
        super()._scroll_update(virtual_size)  # type: ignore[misc]
        self.virtual_size_placed()

    def virtual_size_placed(self) -> None:
        pass


# -- 3. the CSS parse ----------------------------------------------------------------------

ParseRules = Callable[..., list[Any]]


def parse_rules() -> ParseRules:
    """Textual's own method that parses a CSS text into rules."""
    method: ParseRules = Stylesheet.__dict__["_parse_rules"]
    return method


def set_parse_rules(method: ParseRules) -> None:
    """Every stylesheet parses with `method` (``Stylesheet._parse_rules``) from now on."""
    Stylesheet._parse_rules = method  # type: ignore[method-assign]


def parse_cache(stylesheet: Stylesheet) -> Any:
    """The stylesheet's own cache of parsed rules (``get``, ``[key] = rules``), by (css,
    read_from, is_default_rules, tie_breaker, scope)."""
    return stylesheet._parse_cache


def css_variables(stylesheet: Stylesheet) -> dict[str, str]:
    """The variables the stylesheet substitutes into the CSS it parses."""
    variables: dict[str, str] = stylesheet._variables
    return variables


# -- 4. screens refreshed in virtual time --------------------------------------------------


class _HeldTimer:
    """A screen's refresh timer that never fires (see :func:`hold_refresh`)."""

    def pause(self) -> None:
        pass

    def resume(self) -> None:
        pass


HELD = _HeldTimer()


def hold_refresh(screen: Screen[Any]) -> None:
    """The screen lays out, paints and runs its after-refresh callbacks only when
    :func:`refresh` says so, never on its refresh timer (Textual's one thing paced by the
    clock, 1/60 s after a change). Call before the screen first refreshes."""
    screen._Screen__update_timer = HELD  # type: ignore[attr-defined]


def refresh(screen: Screen[Any]) -> None:
    """What the screen's refresh timer would do now: lay out, paint, run the callbacks due
    after a refresh."""
    screen._on_timer_update()


def refresh_due(app: App[Any]) -> list[Screen[Any]]:
    """The screens whose refresh would do something now: the active one with a layout, a
    repaint, a recompose, a widget to repaint or callbacks due; one shown under a dialog with
    a layout, a widget to repaint, a recompose or callbacks due (its own refresh hands the
    repaint to the active screen and leaves itself marked for one more: not counted, or
    this would never end); any other with callbacks due (its timer runs only those)."""
    current = app.screen
    shown = background_screens(app)
    due = []
    for screen in app.screen_stack:
        if screen is current:
            pending = (screen._layout_required or screen._repaint_required
                       or screen._dirty_widgets or screen._callbacks
                       or screen._recompose_required)
        elif screen in shown:
            pending = (screen._layout_required or screen._dirty_widgets
                       or screen._callbacks or screen._recompose_required)
        else:
            pending = screen._callbacks
        if pending:
            due.append(screen)
    return due


def next_callbacks_due(node: MessagePump) -> bool:
    """The node has callbacks to run after its current message (``call_next``)."""
    return bool(node._next_callbacks)


def background_screens(app: App[Any]) -> list[Screen[Any]]:
    """The screens shown under the active one (a dialog's translucent background), lowest
    first: those below it up to the first with an opaque background."""
    screens: list[Screen[Any]] = []
    for screen in reversed(app.screen_stack[:-1]):
        screens.append(screen)
        if screen.styles.background.a == 1:
            break
    return screens[::-1]


# -- 5. painting headless ------------------------------------------------------------------

MOST_DIRTY = 64  # regions kept to repaint; beyond, the whole screen's region instead


def _unseen_refresh(screen: Screen[Any]) -> None:
    """``Screen._compositor_refresh`` without the paint, for a headless screen: what is to be
    repainted is kept for :func:`paint_changes`; the rest is Textual's (the screen under a
    dialog passes its changes up, the mouse-over is updated)."""
    app = screen.app
    if screen is app.screen:
        screen._dirty_widgets.clear()
        dirty = screen._compositor._dirty_regions
        if len(dirty) > MOST_DIRTY:
            dirty.clear()
            dirty.add(screen._compositor.size.region)
        app._update_mouse_over(screen)
    else:
        Screen._compositor_refresh(screen)


def paint_later(screen: Screen[Any]) -> None:
    """The screen's layouts do not paint (a headless terminal throws every paint away):
    what changed is kept, for :func:`paint_changes` or a full render."""
    screen._compositor_refresh = partial(_unseen_refresh, screen)  # type: ignore[method-assign]


def paint_changes(app: App[Any]) -> bool:
    """Paint what changed on the active screen since it was last painted, as its refresh
    would have on a terminal; True if there was anything."""
    screen = app.screen
    compositor = screen._compositor
    if not compositor._dirty_regions:
        return False
    compositor.render_update(screen_stack=background_screens(app))
    return True


def render_screen(app: App[Any]) -> RenderableType | None:
    """The whole active screen as the terminal would show it (with what shows under a
    dialog), rendered now."""
    rendered: RenderableType | None = app.screen._compositor.render_update(
        full=True, screen_stack=background_screens(app))
    return rendered


# -- 6. reactive watchers ------------------------------------------------------------------


def drop_closed_watchers(node: MessagePump) -> None:
    """Forget the watchers of `node`'s reactives that belong to closed nodes: Textual prunes
    them only when the reactive changes (a footer recomposed at every change of bindings
    kept every key it ever showed alive)."""
    watchers = getattr(node, "__watchers", None)
    if not watchers:
        return
    for entries in watchers.values():
        entries[:] = [(owner, callback) for owner, callback in entries
                      if not (owner._closing or owner._closed)]


def set_bindings_ready(footer: Footer) -> None:
    """The footer may compose its keys (Textual's own ``bindings_changed`` says so; a footer
    that replaces it must too)."""
    footer._bindings_ready = True


def bindings_ready(footer: Footer) -> bool:
    """Whether the footer's compose builds keys yet (it builds none before the first change of
    bindings)."""
    return bool(footer._bindings_ready)


# -- 7. widgets' rendered lines freed with their widgets ------------------------------------

INNER_OUTER_KEPT = 1024  # colour pairs (Textual's own bound)


def release_styles_caches() -> None:
    """Every widget's StylesCache (its rendered lines, and the lines derived from them) is
    freed with the widget.

    Textual caches ``StylesCache.get_inner_outer`` with ``functools.lru_cache`` on the method,
    so its key holds ``self``: the cache keeps the last 1,024 StylesCaches it was called on
    alive, with every line they rendered (Textualize/textual#6665). Each dialog an operator
    opened left its widgets' lines there: the screen grew by about 13 MB a minute with a
    dialog every half second, until 1,024 widgets' worth were kept. The same computation
    (Textual's own function), cached by the two colours alone."""
    method = StylesCache.__dict__["get_inner_outer"]
    if getattr(method, "plchmi_released", False):
        return
    compute = method.__wrapped__  # (uses its colours only: `cls` is never read)

    @lru_cache(INNER_OUTER_KEPT)
    def inner_outer(base_background: Any, background: Any) -> Any:
        return compute(None, base_background, background)

    def get_inner_outer(self: StylesCache, base_background: Any, background: Any) -> Any:
        return inner_outer(base_background, background)

    get_inner_outer.plchmi_released = True  # type: ignore[attr-defined]
    get_inner_outer.cache_info = inner_outer.cache_info  # type: ignore[attr-defined]
    StylesCache.get_inner_outer = get_inner_outer  # type: ignore[method-assign,assignment]


release_styles_caches()  # (before any widget renders: hmi/ui imports this module first)


def drop_stale_renders(table: DataTable[Any]) -> None:
    """Forget what `table` rendered before its cells last changed.

    A DataTable caches each cell, row and line it renders under a key that holds its update
    count, which every changed cell moves on: what was cached before can never be asked for
    again, yet stays until the caches are full (10,000 cells, 1,000 rows and lines). The
    I/O table changes a few cells every frame, so its caches grew by a few MB over the
    minutes of any screen, idle or not. Called once its cells changed, this keeps only the
    current generation (the cursor's and the mouse's variants of it come back as drawn)."""
    for cache in (table._row_render_cache, table._cell_render_cache,
                  table._row_renderable_cache, table._line_cache):
        cache.clear()


# -- 8. the palette's countdown -------------------------------------------------------------


def guard_palette_countdown() -> None:
    """The palette shows "No matches found" half a second after a search found nothing, by a
    timer that queues the showing as the palette's next callback; escape does not stop it.
    Typed fast on a loaded machine (a search, then escape), the callback ran once the
    palette's list was gone, and its error ended the whole HMI (seen in ``plchmi bench
    live``, a key every 1/8 s at load 20). The queued showing now runs only while the list is
    there."""
    start = CommandPalette.__dict__["_start_no_matches_countdown"]
    if getattr(start, "plchmi_guarded", False):
        return

    def start_guarded(self: CommandPalette, search_value: str) -> None:
        start(self, search_value)
        timer = self._no_matches_timer
        scheduled = getattr(timer, "_callback", None)
        if not isinstance(scheduled, partial) or not scheduled.args:
            return
        show = scheduled.args[0]

        def show_while_open() -> None:
            if self.query(CommandList):
                show()

        timer._callback = partial(self.call_next, show_while_open)  # type: ignore[union-attr]

    start_guarded.plchmi_guarded = True  # type: ignore[attr-defined]
    CommandPalette._start_no_matches_countdown = start_guarded  # type: ignore[method-assign]


guard_palette_countdown()


# -- public replacements, kept here with the rest of what plchmi assumes of Textual ---------


def event_clock() -> float:
    """Now, on the clock Textual stamps its events with (``Message.time``)."""
    return Message().time


def forward_mouse_event(screen: Screen[Any], event: Any) -> None:
    """Hand a mouse event to the widget under it, as the app does with one from the terminal
    (``Screen._forward_event``), but without the app making a click of a press and a release
    by the wall clock's click-chain timing."""
    screen._forward_event(event)

"""Each private member of Textual that plchmi uses (hmi/ui/textual_adapter.py), checked
against the installed Textual: a release that renames or changes one fails here, naming it.
And no other module of hmi/ touches one (tests/textual_privates.py finds them)."""

from __future__ import annotations

import asyncio
import io
import unicodedata
from pathlib import Path
from typing import ClassVar

import pytest
from rich.console import Console
from textual import events
from textual.app import App, ComposeResult
from textual.containers import VerticalScroll
from textual.css.stylesheet import Stylesheet
from textual.keys import REPLACED_KEYS, _character_to_key, _get_unicode_name_from_key
from textual.message_pump import MessagePump
from textual.reactive import reactive
from textual.screen import ModalScreen, Screen
from textual.widget import Widget
from textual.widgets import Button, Footer, Label, Static
from textual_privates import private_uses

from hmi.ui import textual_adapter as ta
from hmi.ui.headless import key_event

ROOT = Path(__file__).resolve().parent.parent


def test_no_module_but_the_adapter_touches_a_private_member_of_textual():
    found = private_uses(sorted((ROOT / "hmi").rglob("*.py")), ROOT)
    outside = {name: sites for name, sites in found.items()
               if any("textual_adapter.py" not in site for site in sites)}
    assert outside == {}
    assert found  # the finder sees the adapter's own


def test_the_finder_sees_each_kind_of_use(tmp_path):
    """The check above can fail: an import of a private name, an attribute Textual defines
    and we do not, a mangled name, a string naming one."""
    sample = tmp_path / "sample.py"
    sample.write_text("from textual.keys import _character_to_key\n"
                      "def f(app, screen):\n"
                      "    screen._layout_required\n"
                      "    screen._Screen__update_timer = None\n"
                      "    getattr(app, '__watchers')\n")
    found = private_uses([sample], tmp_path)
    assert {"_character_to_key", "_layout_required", "_Screen__update_timer",
            "__watchers"} <= set(found)


# -- 1. containing errors ------------------------------------------------------------------


class Guarded(ta.GuardedDispatch, Static):
    failed: ClassVar[list[str]] = []

    def on_click(self) -> None:
        raise RuntimeError("boom")

    def handler_failed(self, message, error) -> bool:
        self.failed.append(f"{type(message).__name__}: {error}")
        return True


async def test_guarded_dispatch_hears_a_handler_error_and_the_app_goes_on():
    assert "_dispatch_message" in vars(MessagePump)

    class One(App):
        def compose(self) -> ComposeResult:
            yield Guarded("x", id="g")

    app = One()
    async with app.run_test() as pilot:
        await pilot.click("#g")
        await pilot.pause()
        assert Guarded.failed == ["Click: boom"]
        assert app.is_running and app.return_code is None


async def test_last_resort_hears_what_ends_the_app():
    heard: list[str] = []

    class Failing(ta.LastResort, App):
        def on_mount(self) -> None:
            def fail() -> None:
                raise RuntimeError("outside any handler")
            self.set_timer(0.01, fail)

        def last_resort(self, error: Exception) -> None:
            heard.append(str(error))

    app = Failing()
    with pytest.raises(RuntimeError, match="outside any handler"):  # run_test raises it
        async with app.run_test() as pilot:
            await pilot.pause(0.2)
    assert heard == ["outside any handler"] and app.return_code == 1


# -- 2. scrolling to new lines -------------------------------------------------------------


async def test_the_virtual_size_hook_comes_when_new_lines_can_be_scrolled_to():
    seen: list[tuple[int, int]] = []

    class Scroller(ta.VirtualSizeHook, VerticalScroll):
        def virtual_size_placed(self) -> None:
            seen.append((self.virtual_size.height, self.max_scroll_y))

    class One(App):
        def compose(self) -> ComposeResult:
            yield Scroller(id="s")

    app = One()
    async with app.run_test(size=(40, 10)) as pilot:
        scroller = app.query_one(Scroller)
        await scroller.mount(Static("\n".join(f"line {n}" for n in range(30))))
        await pilot.pause()
        assert seen and seen[-1][0] == 30 and seen[-1][1] == 30 - scroller.size.height


# -- 3. the CSS parse ----------------------------------------------------------------------


def test_the_css_parse_is_one_method_with_its_cache_and_variables():
    original = ta.parse_rules()
    stylesheet = Stylesheet(variables={"accent": "red"})
    rules = original(stylesheet, "Label { color: $accent; }", ("test", ""))
    assert rules and all(type(r).__name__ == "RuleSet" for r in rules)
    assert ta.css_variables(stylesheet) == {"accent": "red"}
    # its cache's key, as hmi/ui/csscache.py builds it
    cache = ta.parse_cache(stylesheet)
    assert cache.get(("Label { color: $accent; }", ("test", ""), False, 0, "")) is rules
    calls: list[str] = []

    def counting(self, css, read_from, *args, **kwargs):
        calls.append(css)
        return original(self, css, read_from, *args, **kwargs)

    ta.set_parse_rules(counting)
    try:
        fresh = Stylesheet()
        fresh.add_source("Label { color: red; }", read_from=("test", ""))
        fresh.parse()
    finally:
        ta.set_parse_rules(original)
    assert calls == ["Label { color: red; }"] and ta.parse_rules() is original


# -- 4. screens refreshed in virtual time --------------------------------------------------


class Held(App):
    def get_default_screen(self) -> Screen:
        screen = super().get_default_screen()
        ta.hold_refresh(screen)
        return screen

    def compose(self) -> ComposeResult:
        yield Label("before", id="l")


async def test_a_held_screen_refreshes_only_when_told():
    """(Pilot.pause refreshes the screen itself: not used here.)"""
    app = Held()
    async with app.run_test():
        screen = app.screen
        for _ in range(10):
            await asyncio.sleep(0.02)
            for due in ta.refresh_due(app):
                ta.refresh(due)
        assert ta.refresh_due(app) == []
        app.query_one("#l", Label).update("after, and longer")
        await asyncio.sleep(0.1)  # the wall clock's refresh would have come by now
        assert ta.refresh_due(app) == [screen]  # nothing ran it
        ta.refresh(screen)
        await asyncio.sleep(0.02)
        for due in ta.refresh_due(app):
            ta.refresh(due)
        assert ta.refresh_due(app) == []
        screen.call_next(lambda: None)
        assert ta.next_callbacks_due(screen)


async def test_background_screens_are_textuals():
    class Dialog(ModalScreen):
        def compose(self) -> ComposeResult:
            yield Label("dialog")

    app = Held()
    async with app.run_test() as pilot:
        assert ta.background_screens(app) == app._background_screens == []
        await app.push_screen(Dialog())
        await pilot.pause()
        assert ta.background_screens(app) == app._background_screens == [app.screen_stack[0]]


# -- 5. painting headless ------------------------------------------------------------------


async def test_a_headless_screen_paints_what_changed_when_asked():
    app = Held()
    async with app.run_test(size=(30, 5)) as pilot:
        ta.paint_later(app.screen)
        app.query_one("#l", Label).update("changed")
        await pilot.pause()
        for due in ta.refresh_due(app):
            ta.refresh(due)
        assert ta.paint_changes(app) and not ta.paint_changes(app)
        console = Console(width=30, height=5, file=io.StringIO(), record=True,
                          color_system=None)
        console.print(ta.render_screen(app))
        assert "changed" in console.export_text()


# -- 6. reactive watchers ------------------------------------------------------------------


class Child(Widget):
    value = reactive(0)


class Owner(Widget):
    value = reactive(0)

    def compose(self) -> ComposeResult:
        yield Child().data_bind(Owner.value)


def _watching(owner: Widget) -> list[object]:
    return [node for entries in getattr(owner, "__watchers", {}).values()
            for node, _ in entries]


async def test_closed_watchers_are_dropped_and_the_footer_keys_are_footerkeys():
    class One(App):
        BINDINGS: ClassVar = [("x", "bell", "Ring")]

        def compose(self) -> ComposeResult:
            yield Owner()
            yield Footer()

    app = One()
    async with app.run_test() as pilot:
        owner = app.query_one(Owner)
        child = owner.query_one(Child)
        assert child in _watching(owner)
        await child.remove()
        await pilot.pause()
        assert child in _watching(owner)  # Textual keeps it (the leak the footer works around)
        ta.drop_closed_watchers(owner)
        assert child not in _watching(owner)
        assert "x" in [key.key for key in app.query(ta.FooterKey)]


def test_a_footer_builds_its_keys_once_its_bindings_are_ready():
    footer = Footer()
    assert not ta.bindings_ready(footer)
    assert list(footer.compose()) == []  # Footer.compose reads it
    ta.set_bindings_ready(footer)
    assert ta.bindings_ready(footer)


# -- rendered lines freed -------------------------------------------------------------------


def test_a_styles_cache_is_freed_once_asked_for_its_colours():
    import gc
    import weakref

    from textual._styles_cache import StylesCache
    from textual.color import Color
    from textual.style import Style

    method = ta.StylesCache.__dict__["get_inner_outer"]
    assert getattr(method, "plchmi_released", False)  # (done at the adapter's import)
    cache = StylesCache()
    base, background = Color.parse("#202020"), Color.parse("red").with_alpha(0.5)
    inner, outer = cache.get_inner_outer(base, background)
    assert (inner, outer) == (Style(background=base + background),
                              Style(background=base))  # Textual's own computation
    kept = weakref.ref(cache)
    del cache
    gc.collect()
    assert kept() is None  # Textual's lru_cache on the method would hold it


async def test_a_data_tables_render_caches_are_keyed_by_its_update_count():
    from textual.widgets import DataTable

    class Table(App):
        def compose(self) -> ComposeResult:
            yield DataTable()

    app = Table()
    async with app.run_test(size=(40, 8)) as pilot:
        table = app.query_one(DataTable)
        table.add_columns("a", "b")
        table.add_rows([("1", "2"), ("3", "4")])
        await pilot.pause()
        caches = (table._row_render_cache, table._cell_render_cache,
                  table._row_renderable_cache, table._line_cache)
        ta.drop_stale_renders(table)
        lines = [table.render_line(y).text for y in range(3)]  # drawn at one update count
        count = table._update_count
        assert all(len(cache) for cache in caches)
        assert all(count in key for cache in caches for key in cache.keys())  # noqa: SIM118 (no __iter__)
        table.update_cell_at((0, 0), "5")
        assert table._update_count > count  # every older key is dead
        ta.drop_stale_renders(table)
        assert not any(len(cache) for cache in caches)
        assert "5" in table.render_line(1).text and "5" not in lines[1]


async def test_the_palettes_no_matches_countdown_after_its_list_is_gone_does_nothing():
    from functools import partial

    from textual.command import CommandInput, CommandList, CommandPalette

    app = App()
    async with app.run_test() as pilot:
        app.action_command_palette()
        await pilot.pause()
        palette = app.screen
        assert isinstance(palette, CommandPalette)
        palette._start_no_matches_countdown("zzz")
        timer = palette._no_matches_timer
        assert timer is not None and isinstance(timer._callback, partial)
        timer.stop()
        await palette.query_one(CommandList).remove()  # (as a dismissed palette's)
        timer._callback()  # what the timer does when it fires: queue the showing
        await pilot.pause()
        assert not app._exit  # Textual's own showing would fail on the list and end the app
        assert palette.query_one(CommandInput)


# -- input ---------------------------------------------------------------------------------


async def test_a_forwarded_click_presses_a_button():
    pressed: list[str] = []

    class One(App):
        def compose(self) -> ComposeResult:
            yield Button("go", id="b")

        def on_button_pressed(self, event: Button.Pressed) -> None:
            pressed.append(event.button.id or "")

    app = One()
    async with app.run_test() as pilot:
        button = app.query_one(Button)
        point = button.region.offset
        arguments = dict(widget=button, x=point.x, y=point.y, delta_x=0, delta_y=0, button=1,
                         shift=False, meta=False, ctrl=False, screen_x=point.x,
                         screen_y=point.y)
        for cls in (events.MouseDown, events.MouseUp):
            ta.forward_mouse_event(app.screen, cls(**arguments))
        ta.forward_mouse_event(app.screen, events.Click(**arguments, chain=1))
        await pilot.pause()
        assert pressed == ["b"]


def test_the_event_clock_is_the_one_events_are_stamped_with():
    before = ta.event_clock()
    stamped = events.Key("x", "x").time
    assert before <= stamped <= ta.event_clock()


def test_keys_are_the_events_textuals_pilot_sends():
    def pilots(key: str) -> tuple[str, str | None]:
        if len(key) == 1 and not key.isalnum():
            key = _character_to_key(key)
        try:
            char = unicodedata.lookup(_get_unicode_name_from_key(REPLACED_KEYS.get(key, key)))
        except KeyError:
            char = key if len(key) == 1 else None
        return key, char

    keys = [chr(c) for c in range(33, 127)] + ["space", "enter", "escape", "tab", "shift+tab",
                                                "ctrl+p", "up", "down", "home", "pageup"]
    assert [(e.key, e.character) for e in map(key_event, keys)] == list(map(pilots, keys))

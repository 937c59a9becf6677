"""The command palette (ctrl+p): every operator control, plus the per-item variants that have
no single key (a manual request for a named output, a named policy, a chronogram signal).

The entries come from the app (:meth:`PlcHmiApp.palette_entries`), which builds them from the
same table as the footer bindings and hides those that do not apply now (manual requests
outside manual mode, fault injection on a real plant).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from textual.command import DiscoveryHit, Hit, Hits, Provider
from textual.content import Content
from textual.fuzzy import Matcher


@dataclass(frozen=True)
class PaletteEntry:
    title: str
    help: str
    run: Callable[[], object]
    action: str | None = None  # the binding's action, when the entry mirrors a key


class HmiCommands(Provider):
    """Offers the app's palette entries; fuzzy search on their titles."""

    def _entries(self) -> list[PaletteEntry]:
        """The entries of the screen the palette was opened on (the trends have their own),
        else the app's."""
        entries = getattr(self.screen, "palette_entries", None) or \
            getattr(self.app, "palette_entries", None)
        return list(entries()) if entries else []

    def _run(self, entry: PaletteEntry) -> Callable[[], object]:
        """The entry's command, its errors contained by the app (hmi.ui.containment)."""
        guarded = getattr(self.app, "guarded", None)
        return guarded(f"palette entry {entry.title!r}", entry.run) if guarded else entry.run

    async def discover(self) -> Hits:
        for entry in self._entries():
            yield DiscoveryHit(Content(entry.title), self._run(entry), text=entry.title,
                               help=entry.help)

    async def search(self, query: str) -> Hits:
        matcher = self.matcher(query)
        for entry in self._entries():
            score = matcher.match(entry.title)
            if score > 0:
                yield Hit(score, highlighted(matcher, entry.title), self._run(entry),
                          text=entry.title, help=entry.help)


def highlighted(matcher: Matcher, title: str) -> Content:
    """The title with the characters the query matched marked, read as plain text: titles
    end in their key, ``[r]``, which ``Matcher.highlight`` would take for markup and drop."""
    content = Content(title)
    score, offsets = matcher.fuzzy_search.match(matcher.query, title)
    for offset in offsets if score else ():
        if not title[offset].isspace():
            content = content.stylize(matcher.match_style, offset, offset + 1)
    return content

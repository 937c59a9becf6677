"""``plchmi web``: the sign-in page, then the HMI in each browser tab.

An aiohttp server (textual-serve's, with a door in front):

* ``/signin`` — the form; a name and password checked against the users file by
  :class:`~hmi.access.signin.Authenticator` in its own threads (never on this loop), the
  lockout shared with every other door. Accepted: a browser session (a random cookie,
  HttpOnly, SameSite=Strict, Secure over TLS), counted in the users file's session table
  (``sessions-per-user``), ended at sign-out, or when idle for ``idle-lock`` with no tab
  open (an open tab's screen locks itself instead: hmi.ui.app's idle lock). Refused: the
  name tried, the browser's address and why go to the cell's journal (hmi.access.audit).
* ``/`` — textual-serve's terminal page, signed-in sessions only.
* ``/ws`` — each tab's websocket, signed-in sessions only and from this server's own pages
  (the Origin checked): it starts one screen process (``plchmi attach``), handing it the
  sign-in as a one-time ticket (:mod:`hmi.access.tickets`) in its environment; the runtime
  redeems the ticket and takes the role from the users file. At most MAX_TABS tabs.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import shlex
import ssl
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import textual_serve
from aiohttp import WSMsgType, web
from textual_serve.app_service import AppService
from textual_serve.download_manager import DownloadManager

from hmi.access import audit, tickets
from hmi.access.audit import SignInRefusal, refusal
from hmi.access.sessions import SessionTable
from hmi.access.signin import Authenticator
from hmi.access.users import Settings
from hmi.errors import OutputError

from . import pages

COOKIE = "plchmi_session"
REAPER = web.AppKey("reaper", asyncio.Task)
MAX_TABS = 16  # browser tabs (screen processes) at once, every session together
MAX_TABS_PER_SESSION = 4
MAX_FORM = 4096  # bytes of a sign-in form
STATIC = Path(textual_serve.__file__).parent / "static"  # its page's terminal (xterm.js)


@dataclass(eq=False)
class WebSession:
    """One browser's sign-in (its tabs share it)."""

    id: str
    user: str
    role: str
    table_id: str  # its entry in the session table (sessions per user)
    last: float  # monotonic time of the last thing its person did
    tabs: set[web.WebSocketResponse] = field(default_factory=set)


class _TabProcess(AppService):
    """textual-serve's app process, with the ticket in its environment."""

    def __init__(self, command: str, env: dict[str, str], **kwargs: Any):
        super().__init__(command, **kwargs)
        self._env = env

    def _build_environment(self, width: int = 80, height: int = 24) -> dict[str, str]:
        environment = super()._build_environment(width, height)
        environment.update(self._env)
        return environment


class WebDoor:
    def __init__(self, project_arg: str, project_name: str, users_path: Path,
                 socket: Path | None, banner: str = "", tls: bool = False,
                 clock: Any = time.monotonic, journal: Path | None = None):
        self.project_arg = project_arg
        self.journal = journal  # the cell's: each refused sign-in is appended to it
        self.project_name = project_name
        self.users_path = users_path
        self.socket = socket
        self.banner = banner
        self.tls = tls
        self.clock = clock
        self.auth = Authenticator(users_path)
        self.table = SessionTable(users_path)
        self.sessions: dict[str, WebSession] = {}
        self.tabs = 0
        self.downloads = DownloadManager()

    # -- the application --------------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_FORM, middlewares=[self._headers])
        app.add_routes([
            web.get("/signin", self.sign_in_page), web.post("/signin", self.sign_in),
            web.post("/signout", self.sign_out), web.get("/", self.index),
            web.get("/ws", self.websocket),
            web.static("/static", STATIC)])
        app.on_startup.append(self._start_reaper)
        app.on_shutdown.append(self._shutdown)
        return app

    @web.middleware
    async def _headers(self, request: web.Request, handler: Any) -> web.StreamResponse:
        response: web.StreamResponse = await handler(request)
        response.headers.setdefault("X-Frame-Options", "DENY")
        response.headers.setdefault("X-Content-Type-Options", "nosniff")
        response.headers.setdefault("Referrer-Policy", "no-referrer")
        if not request.path.startswith("/static"):
            response.headers.setdefault("Cache-Control", "no-store")
        return response

    def _settings(self) -> Settings | None:  # the users file's, read again when it changes
        users = self.auth.users()
        return users.settings if users is not None else None

    def _banner(self) -> str:
        settings = self._settings()
        return "\n".join(t for t in (settings.banner if settings else "", self.banner) if t)

    def session_of(self, request: web.Request) -> WebSession | None:
        token = request.cookies.get(COOKIE, "")
        session = self.sessions.get(token) if token else None
        if session is None:
            return None
        if self._expired(session, self.clock()):
            return None  # the reaper ends it
        return session

    def _expired(self, session: WebSession, now: float) -> bool:
        """A sign-in with no tab open ends after idle-lock untouched (sign in again); one
        whose tabs are open lasts: each tab's screen warns, then locks itself and asks the
        password again (the HMI's idle lock), the cell shown running meanwhile."""
        settings = self._settings()
        return settings is None or (not session.tabs and
                                    now - session.last > settings.idle_lock_us / 1e6)

    # -- signing in and out ----------------------------------------------------------------
    async def sign_in_page(self, request: web.Request) -> web.Response:
        if self.session_of(request) is not None:
            raise web.HTTPSeeOther("/")
        return web.Response(text=pages.sign_in(self.project_name, self._banner()),
                            content_type="text/html")

    async def sign_in(self, request: web.Request) -> web.Response:
        form = await request.post()
        name = str(form.get("name", ""))[:64]
        password = str(form.get("password", ""))
        result = await self.auth.check_async(name, password)
        problem = result.reason
        if result.accepted and result.user is not None:
            settings = self._settings()
            limit = settings.sessions_per_user if settings else 1
            opened, why = await asyncio.to_thread(self.table.open, result.user.name,
                                                  "browser", limit)
            if opened is not None:
                token = secrets.token_hex(32)
                self.sessions[token] = WebSession(token, result.user.name, result.user.role,
                                                  opened.id, self.clock())
                response = web.HTTPSeeOther("/")
                response.set_cookie(COOKIE, token, httponly=True, samesite="Strict",
                                    secure=self.tls, path="/")
                raise response
            problem = why
        await self._journal(refusal(name, "browser", request.remote or "", problem,
                                    result.locked_now))
        return web.Response(text=pages.sign_in(self.project_name, self._banner(), problem,
                                               name), content_type="text/html", status=401)

    async def _journal(self, refused: SignInRefusal) -> None:
        """A refused sign-in into the cell's journal (off this loop: it waits for the disk);
        a journal that cannot be written is said on stderr, the refusal stands."""
        if self.journal is None:
            return
        try:
            await asyncio.to_thread(audit.append, self.journal, refused)
        except OutputError as exc:
            print(f"plchmi web: a refused sign-in could not be journalled: {exc}",
                  file=sys.stderr, flush=True)

    async def sign_out(self, request: web.Request) -> web.Response:
        session = self.session_of(request)
        if session is not None:
            await self._end(session)
        response = web.HTTPSeeOther("/signin")
        response.del_cookie(COOKIE, path="/")
        raise response

    async def _end(self, session: WebSession) -> None:
        """The session is over: its tabs closed (their screens leave the runtime)."""
        self.sessions.pop(session.id, None)
        for tab in list(session.tabs):
            with contextlib.suppress(Exception):
                await tab.close(message=b"signed out")
        await asyncio.to_thread(self.table.close, session.table_id)

    # -- the HMI --------------------------------------------------------------------------
    async def index(self, request: web.Request) -> web.Response:
        session = self.session_of(request)
        if session is None:
            raise web.HTTPSeeOther("/signin")
        scheme = "wss" if self.tls else "ws"
        return web.Response(text=pages.hmi(
            self.project_name, f"{session.user} ({session.role})", "/static/",
            f"{scheme}://{request.host}/ws"), content_type="text/html")

    def command(self) -> str:
        parts = [sys.executable, "-m", "hmi.cli", "attach", self.project_arg]
        if self.socket is not None:
            parts += ["--socket", str(self.socket)]
        return " ".join(shlex.quote(p) for p in parts)

    async def websocket(self, request: web.Request) -> web.StreamResponse:
        session = self.session_of(request)
        if session is None:
            raise web.HTTPForbidden(text="sign in first")
        origin = request.headers.get("Origin")
        if origin is not None and origin.split("://", 1)[-1] != request.host:
            raise web.HTTPForbidden(text="not from this server's page")
        if self.tabs >= MAX_TABS or len(session.tabs) >= MAX_TABS_PER_SESSION:
            raise web.HTTPServiceUnavailable(text="too many screens open at once")
        width = _int(request.query.get("width", "80"), 80, 20, 500)
        height = _int(request.query.get("height", "24"), 24, 5, 200)
        socket = web.WebSocketResponse(heartbeat=15, max_msg_size=64 * 1024)
        await socket.prepare(request)
        ticket = await asyncio.to_thread(tickets.issue, self.users_path, session.user,
                                         "browser", session.id[:8])
        process = _TabProcess(
            self.command(), {"PLCHMI_TICKET": ticket},
            write_bytes=socket.send_bytes, write_str=socket.send_str, close=socket.close,
            download_manager=self.downloads)
        self.tabs += 1
        session.tabs.add(socket)
        try:
            await process.start(width, height)
            try:
                await self._relay(socket, process, session)
            finally:
                await process.stop()
        except asyncio.CancelledError:
            await socket.close()
        finally:
            self.tabs -= 1
            session.tabs.discard(socket)
        return socket

    async def _relay(self, socket: web.WebSocketResponse, process: AppService,
                     session: WebSession) -> None:
        """What the browser sends, to the tab's process (textual-serve's envelope); a key
        or a click keeps the session alive."""
        async for message in socket:
            if message.type != WSMsgType.TEXT:
                continue
            try:
                envelope = message.json()
            except ValueError:
                break  # not textual-serve's page: the tab is closed
            if not isinstance(envelope, list) or not envelope:
                break
            kind, data = envelope[0], (envelope[1] if len(envelope) > 1 else None)
            if kind == "stdin" and isinstance(data, str):
                session.last = self.clock()
                await process.send_bytes(data.encode("utf-8"))
            elif kind == "resize" and isinstance(data, dict):
                await process.set_terminal_size(_int(data.get("width"), 80, 20, 500),
                                                _int(data.get("height"), 24, 5, 200))
            elif kind == "ping":
                await socket.send_json(["pong", data])
            elif kind == "blur":
                await process.blur()
            elif kind == "focus":
                session.last = self.clock()
                await process.focus()

    # -- the sessions' clock -------------------------------------------------------------
    async def _start_reaper(self, app: web.Application) -> None:
        app[REAPER] = asyncio.create_task(self._reap())

    async def _reap(self) -> None:
        """Idle sessions without a tab end (sign in again); stale tickets go."""
        while True:
            await asyncio.sleep(1.0)
            now = self.clock()
            for session in list(self.sessions.values()):
                if self._expired(session, now):
                    await self._end(session)
            await asyncio.to_thread(tickets.sweep, self.users_path)

    async def _shutdown(self, app: web.Application) -> None:
        reaper = app.get(REAPER)
        if reaper is not None:
            reaper.cancel()
        for session in list(self.sessions.values()):
            await self._end(session)
        self.auth.close()


def _int(value: object, default: int, least: int, most: int) -> int:
    try:
        number = int(str(value))
    except ValueError:
        return default
    return min(most, max(least, number))


def tls_context(cert: Path, key: Path) -> ssl.SSLContext:
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cert, key)
    return context


async def serve(door: WebDoor, host: str, port: int, context: ssl.SSLContext | None,
                ready: Any = None) -> None:
    """Serve until SIGINT or SIGTERM; `ready(url)` once listening."""
    import signal
    runner = web.AppRunner(door.app(), access_log=None, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, host, port, ssl_context=context, reuse_address=True)
    await site.start()
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    bound = runner.addresses[0]
    shown = f"[{bound[0]}]" if ":" in bound[0] else bound[0]
    url = f"{'https' if context else 'http'}://{shown}:{bound[1]}/"
    if ready is not None:
        ready(url)
    try:
        await stop.wait()
    finally:
        await runner.cleanup()

"""The browser door's two pages: the sign-in form and the HMI's page (textual-serve's
terminal with a bar that says who is signed in). Plain HTML: nothing is loaded from
outside this server (a cell's network often reaches nothing else)."""

from __future__ import annotations

from html import escape

_STYLE = """
body { background: #0c181f; color: #e8eef2; font-family: "DejaVu Sans Mono", Menlo,
       monospace; margin: 0; }
main { max-width: 34em; margin: 8vh auto; padding: 1.5em 2em; background: #12232d; }
h1 { font-size: 1.3em; margin: 0 0 .3em 0; }
.cell { color: #9fb3c0; margin: 0 0 1.2em 0; }
.banner { white-space: pre-wrap; border-left: 4px solid #f0b400; padding: .4em .8em;
          margin: 0 0 1.2em 0; }
label { display: block; margin: .8em 0 .2em 0; }
input { width: 100%; box-sizing: border-box; padding: .5em; font: inherit;
        background: #0c181f; color: #e8eef2; border: 1px solid #4b6272; }
button { margin-top: 1.2em; padding: .6em 1.6em; font: inherit; background: #1d6fa5;
         color: #fff; border: none; cursor: pointer; }
.problem { color: #ffb4a8; border-left: 4px solid #e0463a; padding: .4em .8em; }
.note { color: #9fb3c0; font-size: .9em; margin-top: 1.5em; }
"""


def sign_in(project: str, banner: str, problem: str = "", name: str = "") -> str:
    said = (f'<p class="problem" id="problem" role="alert">{escape(problem)}</p>'
            if problem else "")
    shown = f'<p class="banner" id="banner">{escape(banner)}</p>' if banner else ""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>Sign in: {escape(project)}</title><style>{_STYLE}</style></head>
<body><main>
<h1>Sign in</h1>
<p class="cell">to the operator screen of <strong>{escape(project)}</strong></p>
{shown}{said}
<form method="post" action="/signin" autocomplete="off">
<label for="name">User name</label>
<input id="name" name="name" value="{escape(name)}" required maxlength="64" autofocus
       autocapitalize="none" spellcheck="false">
<label for="password">Password</label>
<input id="password" name="password" type="password" required maxlength="1024">
<button id="sign-in" type="submit">Sign in</button>
</form>
<p class="note">Everything you do here is journalled with your name.</p>
</main></body></html>
"""


def hmi(project: str, who: str, static_url: str, websocket_url: str,
        font_size: int = 16) -> str:
    """textual-serve's page for one app, with the bar on top (who, sign out)."""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>{escape(project)}: operator screen</title>
<link rel="stylesheet" href="{escape(static_url)}css/xterm.css">
<script src="{escape(static_url)}js/textual.js"></script>
<style>
body {{ background: #0c181f; margin: 0; overflow: hidden; }}
#bar {{ height: 28px; box-sizing: border-box; padding: 4px 10px; display: flex; gap: 1em;
        align-items: center; font: 14px "DejaVu Sans Mono", Menlo, monospace;
        color: #e8eef2; background: #12232d; }}
#bar form {{ margin: 0 0 0 auto; }}
#bar button {{ font: inherit; background: none; color: #9fd0ff; border: 1px solid #4b6272;
               cursor: pointer; }}
#terminal.textual-terminal {{ width: 100vw; height: calc(100vh - 28px); opacity: 1; }}
#ended {{ display: none; color: #ffb4a8; font: 16px monospace; padding: 2em; }}
body.-closed #ended {{ display: block; }}
body.-closed #terminal {{ display: none; }}
</style></head>
<body>
<div id="bar"><span id="who">{escape(project)} · signed in as {escape(who)}</span>
<form method="post" action="/signout"><button id="sign-out" type="submit">Sign out</button>
</form></div>
<div id="ended">This screen ended (the runtime stopped, the session expired or the screen
was closed). <a href="/" style="color:#9fd0ff">Open it again</a>.</div>
<div id="terminal" class="textual-terminal" data-session-websocket-url="{escape(websocket_url)}"
     data-font-size="{font_size}"></div>
</body></html>
"""

"""Serving an export over HTTP on this machine: ``neuras-distill serve DIR [--port N] [--no-open]``.

Owns: :func:`page_of` (which folders are served and which page opens), :func:`make_server` and :func:`serve`.
Browsers load the three.js page's ES modules only over HTTP, and the web player fetches its files over HTTP
(from ``file://`` it reads ``data.js``); this is the server for both, so no ``python -m http.server`` is needed.

What DIR may be, known by the marker file its writer always writes (an arbitrary folder with an index.html is not
served)::

    web export       .neuras-distill-web (``export/web.py``) + index.html        serves DIR, opens index.html
    three.js export  .neuras-distill-threejs (``export/threejs.py``) + index.html  serves DIR, opens index.html
    3dtiles page     .neuras-distill-3dtiles (``export/tiles_page.py``) + index.html  serves DIR, opens index.html
    run folder       .neuras-distill-run (``pipeline/rundir.py``) + report.html   serves DIR, opens report.html
                                                                                  (its player is DIR/web)

Decisions: the server listens on 127.0.0.1 only (nothing of the machine is offered to the network); ``.js`` /
``.mjs`` go out as ``text/javascript`` and ``.wasm`` as ``application/wasm`` whatever the system's MIME table says
(browsers refuse a module of another type); every response says ``Cache-Control: no-cache`` so a page reloaded
after a new export revalidates its files; no request is logged. The browser is opened in the background: a
console browser (lynx, w3m: what Python's ``webbrowser`` falls back to without a display) is never started, as it
would take over the terminal the server runs in.
"""

from __future__ import annotations

import errno
import functools
import os
import socketserver
import sys
import threading
import webbrowser
from collections.abc import Callable
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote

from ..errors import BadInputError
from .threejs import MARKER as THREEJS_MARKER
from .tiles_page import MARKER as TILES_PAGE_MARKER
from .web import MARKER as WEB_MARKER

#: ``pipeline/rundir.py``'s MARKER (this room may not import the pipeline, which imports it).
RUN_MARKER = ".neuras-distill-run"
HOST = "127.0.0.1"
#: Types sent whatever the system's MIME table says (``mimetypes`` reads /etc/mime.types, which may lack them).
CONTENT_TYPES = {".js": "text/javascript", ".mjs": "text/javascript", ".wasm": "application/wasm",
                 ".json": "application/json", ".glb": "model/gltf-binary"}
_CONSOLE_BROWSERS = frozenset({"www-browser", "links", "links2", "elinks", "lynx", "w3m"})


def page_of(folder: Path) -> tuple[Path, str]:
    """(the folder to serve, resolved; the page to open, relative to it, posix) for ``folder``: a web or three.js
    export or a run folder (module docstring); BadInputError saying what to pass otherwise."""
    folder = Path(folder)
    if not folder.exists():
        raise BadInputError(f"{folder} does not exist: pass the folder `neuras-distill export --format "
                            "web|threejs|3dtiles --out` wrote, or a run folder")
    for marker in (WEB_MARKER, THREEJS_MARKER, TILES_PAGE_MARKER):
        if (folder / marker).is_file() and (folder / "index.html").is_file():
            return folder.resolve(), "index.html"
    if (folder / RUN_MARKER).is_file():
        if (folder / "report.html").is_file():
            return folder.resolve(), "report.html"
        raise BadInputError(f"run folder {folder} has no report.html: serve its web/ folder instead, or run the "
                            "distillation again to write it")
    raise BadInputError(f"{folder} is not a web, threejs or 3dtiles export or a run folder: pass the folder "
                        "`neuras-distill export --format web|threejs|3dtiles --out` wrote, or a run folder")


def check_port(port) -> int:
    """``port`` when it is an int in 0..65535 (0: any free port), else BadInputError naming --port."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise BadInputError(f"--port must be 0..65535 (0 picks a free port), got {port!r}")
    return port


class _Handler(SimpleHTTPRequestHandler):
    """Files under ``directory`` with :data:`CONTENT_TYPES`, revalidated on every load, nothing logged."""

    extensions_map = {**SimpleHTTPRequestHandler.extensions_map, **CONTENT_TYPES}

    def end_headers(self) -> None:
        self.send_header("Cache-Control", "no-cache")
        super().end_headers()

    def log_message(self, format, *args) -> None:  # noqa: A002 (the base class's name)
        pass


class _Server(ThreadingHTTPServer):
    """ThreadingHTTPServer without the reverse DNS lookup of its address (slow on some machines) and quiet about
    clients that hang up mid-response (a reloaded page)."""

    allow_reuse_address = os.name != "nt"      # on Windows SO_REUSEADDR would let a second server share the port
    allow_reuse_port = False

    def server_bind(self) -> None:
        socketserver.TCPServer.server_bind(self)
        self.server_name, self.server_port = self.server_address[:2]

    def handle_error(self, request, client_address) -> None:
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


def make_server(folder, port: int = 0) -> tuple[ThreadingHTTPServer, str]:
    """A server of ``folder`` (:func:`page_of`) bound to 127.0.0.1:``port`` (0: a free port), not yet serving,
    and the URL of its page. The caller runs ``serve_forever()`` and ends it with ``shutdown()`` (from another
    thread) and ``server_close()``. BadInputError for a folder it does not serve or a port it cannot bind."""
    root, page = page_of(Path(folder))
    check_port(port)
    handler = functools.partial(_Handler, directory=str(root))
    try:
        server = _Server((HOST, port), handler)
    except OSError as exc:
        why = "is already in use" if exc.errno == errno.EADDRINUSE else f"cannot be bound ({exc.strerror or exc})"
        raise BadInputError(f"--port {port} {why} on {HOST}: pass another --port, or --port 0 for a free one"
                            ) from None
    return server, f"http://{HOST}:{server.server_port}/{quote(page)}"


def open_page(url: str) -> threading.Thread:
    """Open ``url`` in the user's browser from a background thread (returned, started); nothing when there is
    none, or only a console browser (module docstring)."""
    def run() -> None:
        try:
            browser = webbrowser.get()
            if getattr(browser, "name", None) not in _CONSOLE_BROWSERS:
                browser.open(url)
        except (webbrowser.Error, OSError):
            pass

    thread = threading.Thread(target=run, name="neuras-distill-browser", daemon=True)
    thread.start()
    return thread


def serve(folder, port: int = 0, open_browser: bool = True, ready: Callable[[str], None] | None = None) -> None:
    """Serve ``folder`` (a web or three.js export or a run folder, :func:`page_of`) on 127.0.0.1:``port`` (0: a
    free port) until interrupted (KeyboardInterrupt propagates, the socket closed). Once the socket is bound
    ``ready(url)`` is called with the page's URL, then the page is opened in the browser unless ``open_browser``
    is false. BadInputError, before anything is bound, for a folder it does not serve or a bad or taken port."""
    server, url = make_server(folder, port)
    with server:
        if ready is not None:
            ready(url)
        if open_browser:
            open_page(url)
        server.serve_forever()


__all__ = ["CONTENT_TYPES", "RUN_MARKER", "check_port", "make_server", "open_page", "page_of", "serve"]

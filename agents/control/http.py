"""The control center's HTTP server: one page (``static/``: vanilla HTML/JS/CSS, no build step) and
the JSON API of :mod:`agents.control.api` (``docs/control.md``), on ``127.0.0.1`` only.

Every request is answered, never a traceback: a refused one with its HTTP status and
``{"error": "<one line>"}``. A request whose ``Host`` is not a loopback name is refused (a page of
another site reaching this port through a rebound DNS name), and a body must come as
``Content-Type: application/json`` (so a browser asks first before a cross-site request, which this
server never grants) of at most :data:`MAX_BODY` bytes.
"""

from __future__ import annotations

import json
import logging
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, urlsplit

from .api import NAME, ApiError, _one_line

if TYPE_CHECKING:
    from . import Control

__all__ = ["MAX_BODY", "STATIC", "Handler", "make_server"]

log = logging.getLogger("agents.control")

STATIC = Path(__file__).resolve().parent / "static"
STATIC_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css"}
MAX_BODY = 64 * 1024


class Handler(BaseHTTPRequestHandler):
    server_version = "rsal-control/1"
    control: Control  # set on the subclass made by make_server()

    def log_message(self, fmt: str, *args) -> None:  # quiet: the page polls twice a second
        log.debug("%s %s", self.address_string(), fmt % args)

    def _send(self, status: int, body: bytes, ctype: str, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, obj: Any, status: int = 200) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json")

    def _error(self, message: str, status: int = 400) -> None:
        self._json({"error": message}, status)

    def _body(self) -> dict:
        ctype = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if ctype != "application/json":
            # a JSON content type makes a browser ask before a cross-site request (CORS preflight,
            # which this server never grants): another web site cannot start processes here
            raise ApiError(f"send the body as Content-Type application/json, not {ctype or 'none'!r}", 415)
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise ApiError("Content-Length must be a number") from None
        if n > MAX_BODY:
            raise ApiError(f"the body is {n} bytes; at most {MAX_BODY} are accepted", 413)
        raw = self.rfile.read(n) if n else b"{}"
        try:
            body = json.loads(raw or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            why = e.msg if isinstance(e, json.JSONDecodeError) else "not UTF-8"
            raise ApiError(f"the body is not valid JSON ({why}); send a JSON object") from None
        if not isinstance(body, dict):
            raise ApiError('the body must be a JSON object, e.g. {"scenario": "wander", "app": "wallfollow"}')
        return body

    def _dispatch(self, method: str) -> None:
        url = urlsplit(self.path)
        parts = [p for p in url.path.split("/") if p]
        query = parse_qs(url.query)
        c = self.control
        try:
            host = (self.headers.get("Host") or "").rsplit(":", 1)[0]
            if host not in ("127.0.0.1", "localhost", "[::1]"):
                # a page of another site reaching this port through a rebound DNS name
                raise ApiError(f"Host {host!r} refused; open the page as http://127.0.0.1:PORT/", 403)
            if method == "GET":
                if not parts or parts == ["index.html"]:
                    return self._static("index.html")
                if parts[0] == "static" and len(parts) == 2:
                    return self._static(parts[1])
                if parts == ["api", "state"]:
                    return self._json(c.state())
                if parts == ["api", "tasks"]:
                    return self._json(c.tasks())
                if parts == ["api", "scenarios"]:
                    return self._json(c.scenarios())
                if parts == ["api", "map"]:
                    m = c.map_info(_query_one(query, "device"))
                    info = {k: v for k, v in m.items() if k != "png"}
                    return self._json(info | {"png": f"/api/map.png?device={m['device']}"})
                if parts == ["api", "map.png"]:
                    m = c.map_info(_query_one(query, "device"))
                    return self._send(200, m["png"], "image/png")
            elif method == "POST":
                if parts == ["api", "runs"]:
                    return self._json(c.start_run(self._body()))
                if len(parts) == 4 and parts[:2] == ["api", "runs"] and parts[3] == "stop":
                    self._body()
                    try:
                        rid = int(parts[2])
                    except ValueError:
                        raise ApiError(f"run id {parts[2]!r} must be a number", 404) from None
                    return self._json(c.stop_run(rid))
                if parts == ["api", "tasks"]:
                    return self._json(c.submit_task(self._body()))
                if len(parts) == 4 and parts[:2] == ["api", "tasks"] and parts[3] == "cancel":
                    self._body()
                    return self._json(c.cancel_task(parts[2]))
                if parts == ["api", "estop"]:
                    return self._json(c.estop(self._body()))
                if len(parts) == 4 and parts[:2] == ["api", "robots"]:
                    return self._json(c.robot_action(parts[2], parts[3], self._body()))
            raise ApiError(f"no such API: {method} {url.path}; see docs/control.md", 404)
        except ApiError as e:
            return self._error(str(e), e.status)
        except Exception as e:  # never a traceback to the page: one line, logged here
            log.exception("%s %s", method, self.path)
            return self._error(f"internal error: {_one_line(e)}", 500)

    def _static(self, name: str) -> None:
        path = STATIC / name
        if not NAME.match(name) or path.suffix not in STATIC_TYPES or not path.is_file():
            raise ApiError(f"no such file: {name}", 404)
        self._send(200, path.read_bytes(), STATIC_TYPES[path.suffix])

    def do_GET(self) -> None:  # noqa: N802 (http.server's naming)
        self._dispatch("GET")

    def do_HEAD(self) -> None:  # noqa: N802
        self._dispatch("GET")

    def do_POST(self) -> None:  # noqa: N802
        self._dispatch("POST")


def _query_one(query: dict, key: str) -> str | None:
    v = query.get(key)
    return v[-1] if v else None


def make_server(port: int, control: Control) -> ThreadingHTTPServer:
    """A threading HTTP server on ``127.0.0.1:port`` (0: a free port) answering for ``control``;
    raises :class:`OSError` when the port cannot be had."""
    httpd = ThreadingHTTPServer(("127.0.0.1", port), type("H", (Handler,), {"control": control}))
    httpd.daemon_threads = True
    return httpd

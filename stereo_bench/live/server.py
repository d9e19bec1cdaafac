"""The live page's HTTP server: Starlette on uvicorn, in the campaign's process, on a thread with its own loop.

Routes (everything the page needs ships in the package: no CDN, works offline):

========================  ===================================================================
``GET /``                 the page (``static/index.html``)
``GET /static/NAME``      its script and style (a fixed list, read from the package at start)
``GET /api/state``        the state as JSON (:meth:`LiveState.snapshot`)
``GET /api/events``       Server-Sent Events: ``state`` (the state, each time it changes, at most 5 a
                          second) and ``preview`` (the newest preview's meta, each time there is one)
``GET /preview/SIDE.jpg`` the newest preview of ``left`` or ``right``; ``rectified``: both, rectified, with
                          epipolar lines (after the first calibration)
``GET /session/PATH``     a file of the session directory (refused outside it, symlinks included)
``POST /api/control/ACT`` continue, capture_now, discard_last_view, set_threshold, exclude_view, recalibrate,
                          pause, resume, stop: needs the token; a prompt's answer may name the prompt
                          (``?prompt=ID``, the state's ``prompt.id``): refused (409) if another is waiting now
========================  ===================================================================

Every control needs the run's random token (``X-Token`` header, or ``?token=``), which is part of
the URL printed at start; without it the answer is 403 and nothing happens. Reading needs no token.
A browser that connects makes previews start; one that leaves changes nothing else.
"""

from __future__ import annotations

import asyncio
import errno
import json
import secrets
import socket
import threading
import time
from importlib import resources
from pathlib import Path

STATIC_FILES = {"index.html": "text/html; charset=utf-8", "live.js": "text/javascript; charset=utf-8",
                "live.css": "text/css; charset=utf-8"}
CONTROL_ACTIONS = ("continue", "capture_now", "discard_last_view", "set_threshold", "exclude_view", "recalibrate",
                   "pause", "resume", "stop")
VALUED_ACTIONS = ("set_threshold", "exclude_view")  # ?value=: a threshold (px), a view's index
MAX_UPDATES_PER_S = 5.0
KEEPALIVE_S = 15.0


class LiveServerError(RuntimeError):
    """The server could not start (the port is taken, the host is not this machine's); one line naming host:port."""


def _bind_reason(error: OSError) -> str:
    if error.errno == errno.EADDRINUSE:
        return "the port is in use (another program, or another live page, listens on it): choose another --ui-port, " \
               "or 0 for a free one"
    if error.errno == errno.EADDRNOTAVAIL:
        return "no network interface of this machine has that address: give --ui-host one of its own addresses, " \
               "or 0.0.0.0 for all of them"
    if error.errno in (errno.EACCES, errno.EPERM):
        return "not allowed (ports below 1024 need privileges): choose a port from 1024 to 65535, or 0 for a free one"
    return error.strerror or str(error)


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (0: any free port), or :class:`LiveServerError` saying why not.

    Bound here rather than by uvicorn, which logs a bind failure over several lines and exits.
    """
    where = f"{host}:{port}"
    if not 0 <= port <= 65535:
        raise LiveServerError(f"live page: cannot serve on {where}: a port is a number from 0 to 65535")
    try:
        addresses = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as error:
        reason = getattr(error, "strerror", None) or str(error)
        raise LiveServerError(f"live page: cannot serve on {where}: {host!r} is not an address or a host name this "
                              f"machine can resolve ({reason})") from None
    failure: OSError | None = None
    for family, kind, protocol, _, address in addresses:
        sock = socket.socket(family, kind, protocol)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does: a restart reuses the port
            sock.bind(address)
            sock.listen(128)
        except OSError as error:
            sock.close()
            failure = failure or error
            continue
        return sock
    raise LiveServerError(f"live page: cannot serve on {where}: {_bind_reason(failure)}")


def static_files() -> dict[str, bytes]:
    """The page's files, read from the installed package (package-data)."""
    root = resources.files("stereo_bench.live") / "static"
    return {name: (root / name).read_bytes() for name in STATIC_FILES}


#: The longest request path served: Linux's PATH_MAX. The page's own URLs are under 300 characters (a session
#: file: ``/session/frames/<config id, at most 100>/<name>``); a longer one is answered 414, never looked up.
MAX_PATH_CHARS = 4096


class BoundedPaths:
    """ASGI middleware: a request whose path is over :data:`MAX_PATH_CHARS` gets 414 (URI Too Long) before any
    route sees it (a route would stat a 100,000-character file name and fail with ENAMETOOLONG: a 500)."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and len(scope.get("raw_path") or scope.get("path", "")) > MAX_PATH_CHARS:
            from starlette.responses import PlainTextResponse

            response = PlainTextResponse(f"URI too long (over {MAX_PATH_CHARS} characters)", status_code=414)
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)


class LiveApp:
    """The Starlette application around a page (a :class:`~stereo_bench.live.page.LivePage`-like object).

    ``page`` gives ``state`` (snapshot(), version), ``previews`` (encoded, watchers()), ``control(action)``
    -> (status code, message) and ``token``; ``session_dir`` the directory files may be served from.
    """

    def __init__(self, page, *, session_dir: Path | None):
        from starlette.applications import Starlette
        from starlette.middleware import Middleware
        from starlette.routing import Route

        self.page = page
        self.session_dir = session_dir
        self.files = static_files()
        self.loop: asyncio.AbstractEventLoop | None = None
        self._changed: asyncio.Event | None = None
        self.closing = False
        self.app = Starlette(routes=[
            Route("/", self.index), Route("/static/{name}", self.static), Route("/api/state", self.state),
            Route("/api/events", self.events), Route("/preview/{side}.jpg", self.preview),
            Route("/session/{path:path}", self.session_file), Route("/api/control/{action}", self.control,
                                                                   methods=["POST"]),
        ], middleware=[Middleware(BoundedPaths)])

    # -- change notification (from any thread) ------------------------------------------------------------------

    def notify(self) -> None:
        loop = self.loop
        if loop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(self._wake)
            except RuntimeError:  # the loop closed meanwhile
                pass

    def _wake(self) -> None:
        if self._changed is not None:
            self._changed.set()
            self._changed = asyncio.Event()

    def _bind_loop(self) -> None:
        if self.loop is None:
            self.loop = asyncio.get_running_loop()
            self._changed = asyncio.Event()

    # -- routes -------------------------------------------------------------------------------------------------

    async def index(self, request):
        from starlette.responses import Response

        self._bind_loop()
        return Response(self.files["index.html"], media_type=STATIC_FILES["index.html"],
                        headers={"Cache-Control": "no-store"})

    async def static(self, request):
        from starlette.responses import Response

        name = request.path_params["name"]
        if name not in STATIC_FILES or name == "index.html":
            return Response("not found", status_code=404)
        return Response(self.files[name], media_type=STATIC_FILES[name], headers={"Cache-Control": "no-cache"})

    async def state(self, request):
        from starlette.responses import JSONResponse

        self._bind_loop()
        return JSONResponse(self.page.state.snapshot(), headers={"Cache-Control": "no-store"})

    async def events(self, request):
        from starlette.responses import StreamingResponse

        self._bind_loop()
        return StreamingResponse(self._stream(request), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def _stream(self, request):
        """The state as an SSE stream: a ``state`` event per change (coalesced, at most MAX_UPDATES_PER_S) and a
        ``preview`` event per new preview (its meta only: the live previews come faster than that and are small)."""
        self.page.previews.watchers(+1)
        try:
            sent, sent_preview, next_state = -1, None, 0.0
            last_write = last_check = time.monotonic()
            while not self.closing:
                changed = self._changed
                state = self.page.state
                now = time.monotonic()
                if state.version != sent and now >= next_state:
                    snapshot = await asyncio.to_thread(state.snapshot)
                    sent, sent_preview = snapshot["version"], _version_of(snapshot["preview"])
                    yield f"event: state\ndata: {json.dumps(snapshot, separators=(',', ':'))}\n\n"
                    last_write, next_state = now, now + 1.0 / MAX_UPDATES_PER_S
                    continue
                preview = state.preview
                if _version_of(preview) != sent_preview:
                    sent_preview = _version_of(preview)
                    yield f"event: preview\ndata: {json.dumps(preview, separators=(',', ':'))}\n\n"
                    last_write = now
                    continue
                if now - last_check > 0.5:  # previews may flow without pause: look for a closed tab anyway
                    last_check = now
                    if await request.is_disconnected():
                        return
                timeout = 0.5 if state.version == sent else max(0.0, next_state - now)
                try:
                    await asyncio.wait_for(changed.wait(), timeout=timeout)
                except TimeoutError:
                    if time.monotonic() - last_write > KEEPALIVE_S:
                        yield ": keepalive\n\n"
                        last_write = time.monotonic()
        finally:
            self.page.previews.watchers(-1)

    async def preview(self, request):
        from starlette.responses import Response

        side = request.path_params["side"]
        encoded = self.page.previews.encoded
        if side not in ("left", "right", "rectified") or encoded is None or not encoded.jpeg.get(side):
            return Response("no preview yet", status_code=404, headers={"Cache-Control": "no-store"})
        return Response(encoded.jpeg[side], media_type="image/jpeg",
                        headers={"Cache-Control": "no-store", "X-Preview-Version": str(encoded.version)})

    async def session_file(self, request):
        from starlette.responses import FileResponse, Response

        from stereo_bench.campaign.session import SessionError, SessionReader

        if self.session_dir is None:
            return Response("no session: this page is a preview without a campaign", status_code=404)
        relative = request.path_params["path"]
        try:
            path = SessionReader(self.session_dir).path(relative)
            found = path.is_file()
        except SessionError as error:
            return Response(str(error).split(": ", 1)[-1], status_code=403)
        except (OSError, RuntimeError):  # a name too long for the file system, a symlink loop: not there
            found = False
        if not found:
            return Response("not found in the session", status_code=404)
        return FileResponse(path, headers={"Cache-Control": "no-store"})

    async def control(self, request):
        from starlette.responses import JSONResponse

        given = request.headers.get("x-token") or request.query_params.get("token") or ""
        if not secrets.compare_digest(given.encode(), self.page.token.encode()):
            return JSONResponse({"ok": False, "message": "refused: this action needs the token of the URL the "
                                                         "campaign printed"}, status_code=403)
        action = request.path_params["action"]
        if action not in CONTROL_ACTIONS:
            return JSONResponse({"ok": False, "message": f"unknown action {action!r}; known: "
                                                         f"{', '.join(CONTROL_ACTIONS)}"}, status_code=404)
        value = None
        if action in VALUED_ACTIONS:
            try:
                value = float(request.query_params.get("value", ""))
            except ValueError:
                return JSONResponse({"ok": False, "message": f"{action.replace('_', ' ')} needs ?value= (a number: "
                                                             "a threshold in px, a view's index)"}, status_code=400)
        prompt_id = None
        if "prompt" in request.query_params:
            try:
                prompt_id = int(request.query_params["prompt"])
            except ValueError:
                return JSONResponse({"ok": False, "message": "?prompt= must be the id of the prompt answered (an "
                                                             "integer: the state's prompt.id)"}, status_code=400)
        status, message = await asyncio.to_thread(self.page.control, action, value, prompt_id)
        return JSONResponse({"ok": status == 200, "message": message}, status_code=status)


class LiveServer:
    """uvicorn serving ``app`` on ``host:port`` (0: any free port) from a daemon thread; :meth:`stop` ends it."""

    def __init__(self, live_app: LiveApp, host: str = "127.0.0.1", port: int = 0):
        self.live_app = live_app
        self.host = host
        self.requested_port = port
        self.port: int | None = None
        self._server = None
        self._socket: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def start(self, timeout_s: float = 10.0) -> LiveServer:
        import uvicorn

        sock = self._socket = bind(self.host, self.requested_port)
        config = uvicorn.Config(self.live_app.app, host=self.host, port=self.requested_port, log_level="warning",
                                access_log=False, lifespan="off", timeout_graceful_shutdown=2)
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._serve, args=(sock,), name="live-server", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                sock.close()
                why = self._error or "it did not start in time"
                raise LiveServerError(f"live page: cannot serve on {self.host}:{self.requested_port} ({why})")
            time.sleep(0.01)
        self.port = sock.getsockname()[1]
        return self

    def _serve(self, sock: socket.socket) -> None:
        try:
            self._server.run(sockets=[sock])
        except BaseException as error:  # noqa: BLE001 - reported by start()
            self._error = error

    def stop(self) -> None:
        self.live_app.closing = True
        self.live_app.notify()
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=10)
        if self._socket is not None:
            self._socket.close()  # uvicorn closed it when it served; not when it failed to start


def _version_of(preview: dict | None) -> int | None:
    return None if preview is None else preview.get("version")


def url_for(host: str, port: int, token: str) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/?token={token}"


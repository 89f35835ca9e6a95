"""The web layer of ``shoha serve``: Starlette on uvicorn.

Why Starlette on uvicorn: ``benchmarks/serve_stacks.py`` put the same
service behind Starlette, FastAPI (on uvicorn) and aiohttp and measured the
latency a keep-alive client sees (docs/serve.md, "Choice of stack"). The
service checks its bodies itself, so FastAPI's pydantic layer would only
check them twice; the OpenAPI schema is written out in
:mod:`optimizer.serve.openapi` instead.

This module only moves bytes: it reads bodies (at most
:data:`optimizer.serve.bodies.MAX_BODY_BYTES`, read in chunks so a larger one
is refused before it is held), hands them to :class:`Service`, and writes
its answers. Every refusal is ``{"error": "one line"}`` with a 4xx status;
anything unexpected is logged and answered 500, and the service goes on.

The guard in front of every request and socket:

* with ``--token``, ``Authorization: Bearer TOKEN`` (constant-time compare);
  a browser cannot set that header on a page load or a WebSocket, so ``GET``
  requests and sockets may carry ``?token=TOKEN`` instead;
* bound to 127.0.0.1, only ``Host: 127.0.0.1`` or ``localhost`` (a web page
  that rebinds a name of its own to 127.0.0.1 is refused);
* a WebSocket opened by a page must come from this service's own origin or
  a ``--cors`` origin;
* bodies must be ``Content-Type: application/json``, which a page of another
  origin cannot send without the CORS preflight that ``--cors`` governs.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import time
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.middleware.cors import CORSMiddleware
from starlette.requests import ClientDisconnect, Request
from starlette.responses import HTMLResponse, RedirectResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from geometry.errors import one_line
from geometry.fileio import ascii_digits

from .bodies import MAX_BODY_BYTES, BodyError, parse_json
from .openapi import schema
from .service import Service
from .view import page, plotly_js

log = logging.getLogger("shoha.serve")

#: Hosts a client may name in ``Host`` when the service is bound to 127.0.0.1.
LOCAL_NAMES = ("127.0.0.1", "localhost")

#: Most sockets watching one session at once.
MAX_WATCHERS = 16

#: ``GET /view`` while no session is open: looks again every second.
WAITING = ("<!doctype html><html lang=\"en\"><head><meta charset=\"utf-8\"><meta http-equiv=\"refresh\" "
           "content=\"1\"><title>shoha live</title></head><body style=\"font-family: sans-serif\">"
           "<p>shoha serve: waiting for a session to start (POST /sessions)...</p></body></html>")


def _json(payload: Any, status: int = 200) -> Response:
    return Response(json.dumps(payload, allow_nan=False), status, media_type="application/json")


def _error(status: int, message: str) -> Response:
    return _json({"error": message.splitlines()[0] if message else "error"}, status)


class Guard:
    """Token, Host and Origin checks in front of the app (pure ASGI, so sockets pass through it too)."""

    def __init__(self, app: ASGIApp, token: str | None, local: bool, port: int, cors: tuple[str, ...]):
        self.app = app
        self.token = token.encode() if token else None
        self.hosts = {f"{h}:{port}" for h in LOCAL_NAMES} | set(LOCAL_NAMES) if local else None
        self.cors = cors

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        refusal = self._refusal(scope, headers)
        if refusal is None:
            await self.app(scope, receive, send)
        elif scope["type"] == "http":
            await _error(*refusal)(scope, receive, send)
        else:
            await receive()  # websocket.connect
            await send({"type": "websocket.close", "code": 1008, "reason": refusal[1][:120]})

    def _refusal(self, scope: Scope, headers: dict[str, str]) -> tuple[int, str] | None:
        if self.hosts is not None and headers.get("host", "") not in self.hosts:
            return 421, "this service answers only requests to 127.0.0.1 or localhost"
        if scope["type"] == "websocket":
            origin = headers.get("origin")
            same = origin is not None and urlsplit(origin).netloc == headers.get("host")
            if origin is not None and origin not in self.cors and not same:
                return 403, f"origin {origin[:80]} may not open this service's sockets (see --cors)"
        if self.token is None:
            return None
        given = headers.get("authorization", "")
        if given.startswith("Bearer "):
            if hmac.compare_digest(given[7:].strip().encode(), self.token):
                return None
        elif scope["type"] == "websocket" or scope.get("method") == "GET":
            token = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
            if hmac.compare_digest(token.encode(), self.token):
                return None
        elif scope.get("method") == "OPTIONS":
            return None  # a CORS preflight carries no credentials; CORSMiddleware answers it
        return 401, "missing or wrong token: send Authorization: Bearer TOKEN"


async def read_json(request: Request) -> Any:
    """The request's JSON body, at most MAX_BODY_BYTES, read in chunks."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind != "application/json":
        raise BodyError(415, "send the body as JSON with Content-Type: application/json")
    length = request.headers.get("content-length", "")
    if ascii_digits(length) and int(length) > MAX_BODY_BYTES:
        raise BodyError(413, f"body is {length} bytes, more than {MAX_BODY_BYTES}")
    chunks, size = [], 0
    try:
        async for chunk in request.stream():
            size += len(chunk)
            if size > MAX_BODY_BYTES:
                raise BodyError(413, f"body is more than {MAX_BODY_BYTES} bytes")
            chunks.append(chunk)
    except ClientDisconnect:
        # The client went before its body came: no one to answer, and no fault of the service
        # (it was logged as an internal error, with two tracebacks).
        raise BodyError(400, "the client closed the connection before the body was sent") from None
    return parse_json(b"".join(chunks))


Handler = Callable[[Request], Awaitable[Response]]


def answers(fn: Callable[[Request], Awaitable[Any]], status: int = 200) -> Handler:
    """A route that answers ``fn``'s dict as JSON, and a BodyError as ``{"error"}`` with its status."""

    async def handle(request: Request) -> Response:
        try:
            payload = await fn(request)
        except BodyError as exc:
            return _error(exc.status, str(exc))
        return Response(status_code=204) if payload is None else _json(payload, status)

    return handle


def build_app(service: Service, *, token: str | None = None, local: bool = True, port: int = 8750,
              cors: tuple[str, ...] = ()) -> Starlette:
    """The ASGI app of ``service``.

    Parameters
    ----------
    token : str, optional
        Required of every request when given.
    local : bool
        Bound to 127.0.0.1: only local ``Host`` names are answered.
    port : int
        The port, for the ``Host`` check.
    cors : tuple of str
        Origins allowed to call from a browser (a WebGL build of the simulator).
    """

    def sid(request: Request | WebSocket) -> str:
        return request.path_params["sid"]

    async def healthz(request: Request) -> Any:
        return service.healthz()

    async def scenes(request: Request) -> Any:
        return service.list_scenes()

    async def create(request: Request) -> Any:
        return service.create_session(await read_json(request))

    async def get_session(request: Request) -> Any:
        return service.get_session(sid(request))

    async def end_session(request: Request) -> Any:
        # After a hint or a whole save of the session being worked out in a thread.
        async with change_lock(request):
            service.end_session(sid(request))
        return None

    # A session's changes in the order they came: a whole save is measured in a worker thread
    # (it can take seconds; the loop answers reads and other sessions meanwhile), and a block
    # laid during it waits, then goes on top (applied first, it was wiped by the save).
    changing: weakref.WeakValueDictionary[str, asyncio.Lock] = weakref.WeakValueDictionary()

    def change_lock(request: Request) -> asyncio.Lock:
        key = sid(request)
        lock = changing.get(key)
        if lock is None:
            lock = changing[key] = asyncio.Lock()
        return lock

    async def put_block(request: Request) -> Any:
        body = await read_json(request)
        async with change_lock(request):
            return service.put_block(sid(request), request.path_params["block"], body)

    async def delete_block(request: Request) -> Any:
        async with change_lock(request):
            return service.delete_block(sid(request), request.path_params["block"])

    async def put_layout(request: Request) -> Any:
        body = await read_json(request)
        async with change_lock(request):
            measure = service.prepare_layout(sid(request), body)
            prepared = await run_in_threadpool(measure)
            return service.apply_layout(sid(request), prepared)

    async def get_layout(request: Request) -> Any:
        return service.get_layout(sid(request))

    async def score(request: Request) -> Any:
        return await service.score(sid(request))

    async def hint(request: Request) -> Any:
        # Off the loop (its block is let go in a short settle), while the session's changes wait.
        async with change_lock(request):
            return await run_in_threadpool(service.prepare_hint(sid(request)))

    async def openapi(request: Request) -> Any:
        return schema()

    async def view(request: Request) -> Response:
        try:
            session = service.store.get(sid(request))
        except BodyError as exc:
            return _error(exc.status, str(exc))
        token_q = request.query_params.get("token")
        query = f"?token={quote(token_q, safe='')}" if token_q else ""
        return HTMLResponse(page(session.scene, service.catalogue, session.id, query))

    async def latest_view(request: Request) -> Response:
        """The view of the session started last; a page that waits for one while there is none."""
        session = service.latest_session()
        query = f"?{request.url.query}" if request.url.query else ""
        if session is None:
            return HTMLResponse(WAITING, headers={"Cache-Control": "no-store"})
        return RedirectResponse(f"/sessions/{session.id}/view{query}", status_code=307)

    async def static_plotly(request: Request) -> Response:
        return Response(plotly_js(), media_type="text/javascript",
                        headers={"Cache-Control": "max-age=86400"})

    async def events(ws: WebSocket) -> None:
        await ws.accept()
        try:
            session = service.store.get(sid(ws))
            if len(session.watchers) >= MAX_WATCHERS:
                raise BodyError(429, f"{MAX_WATCHERS} sockets already watch this session")
            session, queue = service.watch(session.id)
        except BodyError as exc:
            await ws.send_text(json.dumps({"error": str(exc)}))
            await ws.close(code=4000 + exc.status)
            return

        async def send() -> None:
            while True:
                text = await queue.get()
                if not text:
                    await ws.close(code=1000, reason="session ended")
                    return
                await ws.send_text(text)

        async def listen() -> None:
            # Nothing is read from a watcher, but its going away must end this socket at once,
            # not at the session's next change.
            while (await ws.receive())["type"] != "websocket.disconnect":
                pass

        tasks = {asyncio.create_task(send()), asyncio.create_task(listen())}
        try:
            done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in pending:
                task.cancel()
            for task in done:
                if task.exception() is not None and not isinstance(
                        task.exception(), (WebSocketDisconnect, RuntimeError)):
                    raise task.exception()
        finally:
            for task in tasks:
                task.cancel()
            session.watchers.discard(queue)

    routes = [
        Route("/healthz", answers(healthz), methods=["GET"]),
        Route("/scenes", answers(scenes), methods=["GET"]),
        Route("/sessions", answers(create, 201), methods=["POST"]),
        Route("/sessions/{sid}", answers(get_session), methods=["GET"]),
        Route("/sessions/{sid}", answers(end_session), methods=["DELETE"]),
        Route("/sessions/{sid}/blocks/{block}", answers(put_block), methods=["PUT"]),
        Route("/sessions/{sid}/blocks/{block}", answers(delete_block), methods=["DELETE"]),
        Route("/sessions/{sid}/layout", answers(put_layout), methods=["PUT"]),
        Route("/sessions/{sid}/layout", answers(get_layout), methods=["GET"]),
        Route("/sessions/{sid}/score", answers(score), methods=["POST"]),
        Route("/sessions/{sid}/hint", answers(hint), methods=["GET"]),
        Route("/sessions/{sid}/view", view, methods=["GET"]),
        Route("/view", latest_view, methods=["GET"]),
        Route("/static/plotly.js", static_plotly, methods=["GET"]),
        Route("/openapi.json", answers(openapi), methods=["GET"]),
        WebSocketRoute("/sessions/{sid}/events", events),
    ]

    async def not_found(request: Request, exc: Exception) -> Response:
        return _error(404, f"no such endpoint: {request.method} {request.url.path[:80]}")

    async def not_allowed(request: Request, exc: Exception) -> Response:
        return _error(405, f"{request.method} is not allowed on {request.url.path[:80]}")

    async def failure(request: Request, exc: Exception) -> Response:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return _error(500, f"internal error ({type(exc).__name__}); the service goes on")

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        await service.start()
        try:
            yield
        finally:
            await service.stop()

    middleware = [Middleware(Guard, token=token, local=local, port=port, cors=tuple(cors))]
    if cors:
        # Outermost, so a browser's preflight is answered before the token is asked for.
        middleware.insert(0, Middleware(CORSMiddleware, allow_origins=list(cors),
                                        allow_methods=["GET", "PUT", "POST", "DELETE"],
                                        allow_headers=["Authorization", "Content-Type"]))
    return Starlette(routes=routes, middleware=middleware, lifespan=lifespan,
                     exception_handlers={404: not_found, 405: not_allowed, Exception: failure})


def run(service: Service, host: str, port: int, token: str | None, cors: tuple[str, ...],
        listening: Callable[[int], None] | None = None) -> None:
    """Serve until interrupted (uvicorn with uvloop and httptools where installed).

    ``listening(port)`` is called once the sockets are bound and the service answers. If it
    fails (its stdout closed, say), the service shuts down as on a signal and exits with 1:
    the launcher waiting for it was not told where it listens.
    """
    import uvicorn

    class Server(uvicorn.Server):
        unsaid = False  # listening() failed: where it listens was not said

        async def startup(self, sockets: list | None = None) -> None:
            await super().startup(sockets)
            if self.started and listening is not None:
                try:
                    listening(int(self.servers[0].sockets[0].getsockname()[1]))
                except Exception as exc:  # stdout closed (``| true``), say: shut down as on a signal
                    why = one_line(str(exc) or repr(exc))
                    log.warning("stopping: could not say where it listens (%s)", why)
                    self.unsaid = True
                    self.should_exit = True

    app = build_app(service, token=token, local=host == "127.0.0.1", port=port, cors=cors)
    config = uvicorn.Config(app, host=host, port=port, log_level="warning", access_log=False,
                            ws_max_size=64 * 1024, lifespan="on", timeout_graceful_shutdown=2)
    server = Server(config)
    started = time.perf_counter()
    server.run()
    log.info("served for %.0f s", time.perf_counter() - started)
    if server.unsaid:
        raise SystemExit(1)

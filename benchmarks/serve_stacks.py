"""Which web stack gives ``shoha serve`` the better tail latency (issue 25 asks us to measure it).

The same :class:`optimizer.serve.service.Service` is put behind each stack,
in its own process, and driven by the same client over HTTP keep-alive on
127.0.0.1 (httpx), with a WebSocket watcher (websockets) timing the event
each change sends:

``starlette-uvicorn``
    the app ``shoha serve`` runs (optimizer/serve/app.py): Starlette on
    uvicorn with uvloop and httptools;
``starlette-uvicorn-asyncio``
    the same app on uvicorn's pure-Python defaults (asyncio loop, h11), to
    show what uvloop and httptools bring;
``fastapi-uvicorn``
    FastAPI on the same uvicorn, bodies declared the FastAPI way
    (``body: dict = Body(...)``), answers returned as dicts;
``aiohttp``
    aiohttp's own server on uvloop.

The work per request is the service's own, identical in all: a 75-block
session on ``mini`` (the reference after a physics settle, blocks in
contact), laid block by block, then blocks moved by up to 5 cm and back.
Rounds alternate the order of the stacks, so a change in the machine's load
falls on all of them.

Run::

    .venv/bin/python benchmarks/serve_stacks.py [--rounds 2] [--moves 450]

Writes ``benchmarks/results/serve_stacks.csv`` and ``.json``.
"""


import argparse
import json
import sys
import threading
import time
from typing import Any

import numpy as np
from common import MINI_75, ROOT, Run, ServiceProcess, free_port, percentiles, settled

STACKS = ("starlette-uvicorn", "starlette-uvicorn-asyncio", "fastapi-uvicorn", "aiohttp")


# --- the child: one stack serving the service ------------------------------------------------


def _service() -> Any:
    from geometry.scene import load_scene
    from optimizer.serve.service import Service

    return Service([load_scene("mini")], [str(MINI_75)], reference_seconds=0)


def serve(stack: str, port: int) -> None:
    """Serve the service on ``port`` with ``stack`` until terminated."""
    if stack.startswith("starlette"):
        import uvicorn

        from optimizer.serve.app import build_app

        fast = stack == "starlette-uvicorn"
        uvicorn.run(build_app(_service(), port=port), host="127.0.0.1", port=port, log_level="warning",
                    access_log=False, loop="uvloop" if fast else "asyncio",
                    http="httptools" if fast else "h11", ws="websockets-sansio")
    elif stack == "fastapi-uvicorn":
        import uvicorn

        uvicorn.run(_fastapi(_service()), host="127.0.0.1", port=port, log_level="warning", access_log=False,
                    loop="uvloop", http="httptools", ws="websockets-sansio")
    elif stack == "aiohttp":
        import uvloop
        from aiohttp import web

        uvloop.install()
        web.run_app(_aiohttp(_service()), host="127.0.0.1", port=port, print=None, access_log=None)
    else:
        raise SystemExit(f"unknown stack {stack}")


def _fastapi(service: Any) -> Any:
    import contextlib

    from fastapi import Body, FastAPI, WebSocket
    from fastapi.responses import JSONResponse

    from optimizer.serve.bodies import BodyError

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        await service.start()
        yield
        await service.stop()

    app = FastAPI(lifespan=lifespan)

    def answer(fn: Any, status: int = 200) -> Any:
        try:
            return JSONResponse(fn(), status)
        except BodyError as exc:
            return JSONResponse({"error": str(exc)}, exc.status)

    @app.get("/healthz")
    async def healthz() -> Any:
        return service.healthz()

    @app.post("/sessions")
    async def create(body: dict[str, Any] = Body(...)) -> Any:  # noqa: B008 - FastAPI's idiom
        return answer(lambda: service.create_session(body), 201)

    @app.put("/sessions/{sid}/blocks/{block}")
    async def put_block(sid: str, block: str, body: dict[str, Any] = Body(...)) -> Any:  # noqa: B008
        return answer(lambda: service.put_block(sid, block, body))

    @app.websocket("/sessions/{sid}/events")
    async def events(ws: WebSocket, sid: str) -> None:
        await ws.accept()
        session, queue = service.watch(sid)
        try:
            while True:
                await ws.send_text(await queue.get())
        finally:
            session.watchers.discard(queue)

    return app


def _aiohttp(service: Any) -> Any:
    from aiohttp import web

    from optimizer.serve.bodies import BodyError, parse_json

    def answer(fn: Any, status: int = 200) -> Any:
        try:
            return web.Response(text=json.dumps(fn()), status=status, content_type="application/json")
        except BodyError as exc:
            return web.json_response({"error": str(exc)}, status=exc.status)

    async def healthz(request: web.Request) -> web.Response:
        return web.json_response(service.healthz())

    async def create(request: web.Request) -> web.Response:
        body = parse_json(await request.read())
        return answer(lambda: service.create_session(body), 201)

    async def put_block(request: web.Request) -> web.Response:
        body = parse_json(await request.read())
        return answer(lambda: service.put_block(request.match_info["sid"], request.match_info["block"], body))

    async def events(request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse()
        await ws.prepare(request)
        session, queue = service.watch(request.match_info["sid"])
        try:
            while True:
                await ws.send_str(await queue.get())
        finally:
            session.watchers.discard(queue)
        return ws

    async def start(app: web.Application) -> None:
        await service.start()

    async def stop(app: web.Application) -> None:
        await service.stop()

    app = web.Application(client_max_size=4 * 1024 * 1024)
    app.on_startup.append(start)
    app.on_cleanup.append(stop)
    app.add_routes([web.get("/healthz", healthz), web.post("/sessions", create),
                    web.put("/sessions/{sid}/blocks/{block}", put_block),
                    web.get("/sessions/{sid}/events", events)])
    return app


# --- the client -------------------------------------------------------------------------------


def world_body(block: Any, pose: Any) -> dict[str, Any]:
    return {"position": [float(v) for v in pose.position], "quaternion": [float(v) for v in pose.quaternion],
            "type": block.name}


class Watcher:
    """A WebSocket client on its own thread, noting when each event (by version) arrives."""

    def __init__(self, url: str):
        self.url = url
        self.arrived: dict[int, float] = {}
        self._ready = threading.Event()
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        if not self._ready.wait(10):
            raise RuntimeError(f"no WebSocket at {url}")

    def _run(self) -> None:
        from websockets.sync.client import connect

        with connect(self.url, max_size=None) as ws:
            self._ready.set()
            while not self._stop:
                try:
                    text = ws.recv(timeout=0.5)
                except TimeoutError:
                    continue
                except Exception:
                    return
                t = time.perf_counter()
                self.arrived[json.loads(text)["version"]] = t

    def close(self) -> None:
        self._stop = True
        self.thread.join(5)


def drive(url: str, placed: list, moves: int, seed: int = 0, watch: bool = True) -> dict[str, Any]:
    """Lay ``placed`` block by block, then make ``moves`` moves; request and event times, seconds."""
    import httpx

    from geometry.pose import Pose

    rng = np.random.default_rng(seed)
    with httpx.Client(base_url=url, timeout=30.0) as client:
        sid = client.post("/sessions", json={"scene": "mini", "frame": "world"}).json()["session"]
        watcher = Watcher(url.replace("http://", "ws://") + f"/sessions/{sid}/events") if watch else None
        sent: dict[int, float] = {}
        lay, move = [], []

        def put(key: int, block: Any, pose: Any, into: list) -> None:
            t = time.perf_counter()
            r = client.put(f"/sessions/{sid}/blocks/{key}", json=world_body(block, pose))
            into.append(time.perf_counter() - t)
            r.raise_for_status()
            sent[r.json()["version"]] = t

        for key, block, pose in placed:
            put(key, block, pose, lay)
        for i in range(moves):
            key, block, pose = placed[int(rng.integers(len(placed)))]
            target = pose if i % 2 else Pose(pose.position + rng.uniform(-0.05, 0.05, 3), pose.quaternion)
            put(key, block, target, move)
        time.sleep(0.3)
        events = []
        if watcher is not None:
            watcher.close()
            events = [watcher.arrived[v] - t for v, t in sent.items() if v in watcher.arrived]
        client.delete(f"/sessions/{sid}")
    return {"lay": lay, "move": move, "events": events, "missed_events": len(sent) - len(events)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--moves", type=int, default=450)
    args = parser.parse_args()
    if args.child:
        serve(args.child, args.port)
        return 0
    run = Run("serve_stacks", {"rounds": args.rounds, "moves": args.moves, "layout": MINI_75.name,
                               "stacks": list(STACKS)})
    _, placed = settled(MINI_75)
    results: dict[str, dict[str, list[float]]] = {s: {"lay": [], "move": [], "events": []} for s in STACKS}
    for r in range(args.rounds):
        order = STACKS if r % 2 == 0 else STACKS[::-1]
        for stack in order:
            port = free_port()
            argv = [sys.executable, str(ROOT / "benchmarks" / "serve_stacks.py"), "--child", stack,
                    "--port", str(port)]
            with ServiceProcess(argv, port) as svc:
                time.sleep(3.0)  # let the scoring process finish its warm-up on the other core
                out = drive(svc.url, placed, args.moves, seed=r)
            for k in ("lay", "move", "events"):
                results[stack][k] += out[k]
            print(f"round {r + 1} {stack:26s} move p50 {1e3 * np.median(out['move']):.2f} ms "
                  f"p99 {1e3 * np.percentile(out['move'], 99):.2f} ms; event p99 "
                  f"{1e3 * np.percentile(out['events'], 99):.2f} ms", flush=True)
    rows = []
    for stack in STACKS:
        for kind in ("lay", "move", "events"):
            rows.append({"stack": stack, "what": kind, **percentiles(results[stack][kind]),
                         "load_start": run.start["load_average"][0]})
    run.csv("serve_stacks", rows)
    print()
    for row in rows:
        print(f"{row['stack']:26s} {row['what']:6s} n={row['n']:5d} p50 {row['p50_ms']:6.2f} ms  "
              f"p90 {row['p90_ms']:6.2f}  p99 {row['p99_ms']:6.2f}  max {row['max_ms']:7.2f}")
    run.done()
    return 0


if __name__ == "__main__":
    sys.exit(main())

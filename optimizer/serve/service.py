"""What ``shoha serve`` does, apart from HTTP: scenes, references, sessions, hints and scores.

:class:`Service` answers each endpoint of docs/serve.md with a JSON-ready
dict, or raises :class:`optimizer.serve.bodies.BodyError` with the status
and the one-line reason. The web layer (:mod:`optimizer.serve.app`) only
moves bytes; every check of a body happens here, whole, before a session
changes, so a refused request leaves the session as it was.

Requests are answered on the event loop's one thread, one at a time, which
is what keeps a session's changes in order; each costs milliseconds
(:mod:`optimizer.serve.live`). Whatever takes longer (a reference, a score, a
re-plan) runs in :class:`optimizer.serve.workers.Workers`; a whole save
(:meth:`Service.prepare_layout`) and a hint (:meth:`Service.prepare_hint`), which
take tens to hundreds of milliseconds, run in a worker thread while the
session's changes wait (the app's change lock).
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

from geometry.errors import InputError
from geometry.layout import Layout, layout_from_dict, read_layout
from geometry.porosity import porosity
from geometry.scene import Scene, scene_file

from .bodies import (
    BodyError,
    Catalogue,
    block_body,
    block_id,
    frame_value,
    layout_body,
    origin_value,
)
from .hint import PlanBlock, first_fitting
from .live import LiveLayout
from .session import IDLE_SECONDS, MAX_SESSIONS, QUEUE_EVENTS, Session, SessionStore
from .workers import Workers, reference_cache

log = logging.getLogger("shoha.serve")

#: Seconds a re-plan around a trainee's blocks may take, unless ``--replan-time-limit`` says
#: otherwise (the CLI's help says "a minute": it does not import this module).
REPLAN_SECONDS = 60.0




def scene_info(scene: Scene) -> dict[str, Any]:
    """A scene's measures: the keys of ``shoha scene info --json`` (docs/contract.md)."""
    return {
        "name": scene.name,
        "kind": scene.kind,
        "block": scene.block_type,
        "design_volume_m3": scene.design_volume,
        "tolerance_volume_m3": scene.tolerance.volume,
        "required_blocks": scene.required_blocks,
        "target_porosity_percent": scene.target_porosity,
        "crest_width_m": scene.crest_width,
        "height_m": scene.height,
        "slope_run_per_rise": scene.slope,
        "length_m": scene.length,
        "foundation": scene.foundation.kind,
        "wall": scene.wall,
        "block_height_m": scene.block.height,
    }


@dataclass
class Served:
    """A scene the service serves, and its reference once there is one.

    Attributes
    ----------
    scene : Scene
    reference : Layout or None
    plan : list of PlanBlock
        The reference's blocks in crane order, for hints.
    summary : dict or None
        ``{"porosity_percent", "blocks", "source"}``: the state's ``reference``.
    status : str
        ``ready``, ``computing``, ``queued`` or ``unavailable`` (a section
        scene, or a failed optimize: see ``reason``).
    """

    scene: Scene
    reference: Layout | None = None
    plan: list[PlanBlock] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    status: str = "queued"
    reason: str | None = None

    def set_reference(self, layout: Layout, source: str) -> None:
        """Adopt ``layout`` (already checked to be of this scene) as the reference."""
        placed = layout.placed()
        self.plan = [PlanBlock(p.id, p.type, block, p.pose)
                     for p, (_, block, _) in zip(layout.blocks, placed, strict=True)]
        self.summary = {"porosity_percent": porosity(self.scene, placed, "exact").percent,
                        "blocks": len(placed), "source": source}
        self.reference = layout
        self.status = "ready"

    @property
    def ref_key(self) -> str:
        return f"{self.scene.source}#{id(self.reference)}"


def load_reference(path: str, scenes: dict[str, Served]) -> tuple[Served, Layout]:
    """A ``--reference`` layout and the served scene it names (its ``scene`` key)."""
    layout = read_layout(path)
    scene = layout.load_scene()
    served = scenes.get(scene.name)
    # The whole scene, not its name and section alone: a file named as a built-in scene with its
    # own ground or target had its reference served as the built-in one's.
    if served is None or any(getattr(served.scene, key) != getattr(scene, key) for key in
                             ("design", "block_type", "foundation", "allowance", "target_porosity",
                              "required_blocks")):
        raise InputError(f"{path}: its scene {layout.scene!r} is not one this service serves")
    return served, layout


@dataclass(frozen=True)
class PreparedLayout:
    """A whole save as a live layout, ready to replace a session's (``Service.prepare_layout``)."""

    live: LiveLayout
    elapsed_s: float | None
    started: float


def _which(scene: Scene) -> str:
    """A served scene in words: the built-in one, or its file."""
    return "the built-in one" if scene_file(scene.source) is None else str(scene.source)


class Service:
    """The endpoints of ``shoha serve`` (docs/serve.md), without the web layer.

    Parameters
    ----------
    scenes : list of Scene
        The scenes to serve, by name; two of one name are refused (InputError): sessions
        name their scene, and a second one took the first one's place.
    references : list of str
        ``--reference`` layout files; each names its scene.
    reference_seconds : float or None
        Time limit of the background optimize of a scene without a
        reference: None for optimize's own default, 0 to compute none (the
        state's ``reference`` stays null).
    replan_seconds : float or None
        Time limit of a re-plan around a trainee's blocks (a hint where no
        reference block fits); None for ``REPLAN_SECONDS``.
    max_sessions, idle_s : see :class:`SessionStore`.
    """

    def __init__(self, scenes: list[Scene], references: list[str] = (), *,
                 reference_seconds: float | None = None, replan_seconds: float | None = None,
                 max_sessions: int = MAX_SESSIONS, idle_s: float = IDLE_SECONDS):
        self.scenes: dict[str, Served] = {}
        for s in scenes:
            if (other := self.scenes.get(s.name)) is not None:
                raise InputError(f"{s.source or s.name}: its scene is named {s.name!r}, as "
                                 f"{_which(other.scene)} is; give each served scene its own name")
            self.scenes[s.name] = Served(s)
        for path in references:
            served, layout = load_reference(path, self.scenes)
            served.set_reference(layout, "file")
        self.catalogue = Catalogue.of(s.scene for s in self.scenes.values())
        self.reference_seconds = reference_seconds
        self.replan_seconds = REPLAN_SECONDS if replan_seconds is None else replan_seconds
        self.store = SessionStore(max_sessions, idle_s)
        self.workers: Workers | None = None
        self._replans: dict[str, tuple[int, Future[dict[str, Any]] | None, list[PlanBlock]]] = {}
        self._tasks: set[asyncio.Task[Any]] = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.latest: str | None = None

    # --- life -------------------------------------------------------------------------

    async def start(self) -> None:
        """Start the child processes, warm the scorer and queue the missing references."""
        self._loop = asyncio.get_running_loop()
        self.workers = Workers()
        known = [(s.scene.source, s.ref_key, s.reference.to_dict()) for s in self.scenes.values()
                 if s.reference is not None]
        self.workers.warm(known)
        for served in self.scenes.values():
            if served.reference is not None:
                continue
            if served.scene.kind != "3d":
                served.status, served.reason = "unavailable", "a section scene has no 3D reference"
            elif self.reference_seconds is not None and self.reference_seconds <= 0:
                served.status, served.reason = "unavailable", "background references are off"
            elif reference_cache(served.scene, self.reference_seconds).is_file():
                self._adopt_cached(served)  # before the first request: a restart has it at once
        self._spawn(self._compute_references())
        self._spawn(self._expire_sessions())

    async def stop(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        self.store.end_all()
        if self.workers is not None:
            self.workers.shutdown()

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _expire_sessions(self) -> None:
        while True:
            await asyncio.sleep(min(60.0, max(1.0, self.store.idle_s / 4)))
            self.store.expire()
            for sid in [sid for sid in self._replans if self.store.peek(sid) is None]:
                del self._replans[sid]  # an expired session's re-plan is no one's

    async def _compute_references(self) -> None:
        """One scene at a time, smallest first: the cache, or an optimize in the child process."""
        todo = sorted((s for s in self.scenes.values() if s.status == "queued"),
                      key=lambda s: s.scene.required_blocks)
        for served in todo:
            path = reference_cache(served.scene, self.reference_seconds)
            if not path.is_file():
                served.status = "computing"
                assert self.workers is not None
                try:
                    await asyncio.wrap_future(self.workers.submit_reference(
                        served.scene.source, self.reference_seconds, str(path)))
                except Exception as exc:  # the child's failure is reported, never raised into the loop
                    served.status, served.reason = "unavailable", f"optimize failed: {exc}"
                    log.warning("reference for %s: %s", served.scene.name, exc)
                    continue
            self._adopt_cached(served)

    def _adopt_cached(self, served: Served) -> None:
        path = reference_cache(served.scene, self.reference_seconds)
        try:
            _, layout = load_reference(str(path), self.scenes)
        except InputError as exc:
            served.status, served.reason = "unavailable", str(exc)
            return
        served.set_reference(layout, "computed")
        assert self.workers is not None
        self.workers.warm([(served.scene.source, served.ref_key, layout.to_dict())])

    # --- endpoints --------------------------------------------------------------------

    def healthz(self) -> dict[str, Any]:
        return {"status": "ok"}

    def list_scenes(self) -> dict[str, Any]:
        return {"scenes": [{**scene_info(s.scene), "reference": s.summary, "reference_status": s.status}
                           for s in self.scenes.values()]}

    def _session(self, sid: str) -> Session:
        return self.store.get(sid)

    def _served(self, session: Session) -> Served:
        return self.scenes[session.scene.name]

    def state(self, session: Session, started: float) -> dict[str, Any]:
        return session.state(self._served(session).summary, started)

    def create_session(self, body: Any) -> dict[str, Any]:
        started = time.perf_counter()
        if not isinstance(body, dict):
            raise BodyError(422, "body must be a JSON object with a scene")
        unknown = [k for k in body if k not in ("scene", "frame", "origin")]
        if unknown:
            raise BodyError(422, f"unknown key {unknown[0][:40]!r} (allowed: scene, frame, origin)")
        name = body.get("scene")
        if not isinstance(name, str) or name not in self.scenes:
            raise BodyError(422, f"unknown scene {str(name)[:60]!r} (served: {', '.join(self.scenes)})")
        frame = frame_value(body.get("frame"))
        origin = origin_value(body.get("origin"))
        session = self.store.create(self.scenes[name].scene, frame, origin)
        self.latest = session.id
        return self.state(session, started)

    def latest_session(self) -> Session | None:
        """The session started last, while it lasts (``GET /view`` follows it)."""
        return self.store.peek(self.latest) if self.latest is not None else None

    def get_session(self, sid: str) -> dict[str, Any]:
        started = time.perf_counter()
        return self.state(self._session(sid), started)

    def end_session(self, sid: str) -> None:
        self._session(sid)
        self.store.end(sid)
        self._replans.pop(sid, None)

    def put_block(self, sid: str, key_text: str, body: Any) -> dict[str, Any]:
        started = time.perf_counter()
        session = self._session(sid)
        key = block_id(key_text)
        parsed = block_body(body, session.frame, session.origin, session.scene.block_type, self.catalogue)
        change = session.put(key, parsed)
        return self._changed(session, change, started)

    def delete_block(self, sid: str, key_text: str) -> dict[str, Any]:
        started = time.perf_counter()
        session = self._session(sid)
        change = session.remove(block_id(key_text))
        return self._changed(session, change, started)

    def prepare_layout(self, sid: str, body: Any) -> Callable[[], PreparedLayout]:
        """A whole save's measuring, to run off the event loop: 84 blocks in one place took
        30 s, and held every other request as long. The session is looked up here, on the
        loop; the function returned reads only its scene and origin, and changes nothing."""
        started = time.perf_counter()
        session = self._session(sid)
        scene, origin = session.scene, session.origin

        def measure() -> PreparedLayout:
            parsed = layout_body(body, scene, origin, self.catalogue)
            live = LiveLayout(scene)
            for key, b in parsed.blocks:
                live.put(key, b.type, b.block, b.pose, b.time_s)
            # As a save's time is read for shoha score: its elapsed_s where it has one, else the
            # latest time_s.
            times = [b.time_s for _, b in parsed.blocks if b.time_s is not None]
            elapsed = parsed.elapsed_s if parsed.elapsed_s is not None else max(times, default=None)
            return PreparedLayout(live, elapsed, started)

        return measure

    def apply_layout(self, sid: str, prepared: PreparedLayout) -> dict[str, Any]:
        """The session's layout replaced by a measured save (:meth:`prepare_layout`). The
        app lets no other change of the session in between."""
        session = self._session(sid)
        change = session.replace(prepared.live, prepared.elapsed_s)
        return self._changed(session, change, prepared.started)

    def get_layout(self, sid: str) -> dict[str, Any]:
        return self._session(sid).layout()

    def _changed(self, session: Session, change: dict[str, Any], started: float) -> dict[str, Any]:
        state = self.state(session, started)
        session.publish({**state, **change})
        return state

    async def score(self, sid: str) -> dict[str, Any]:
        """``shoha score --json``'s object for the session's blocks, from the scoring process."""
        session = self._session(sid)
        served = self._served(session)
        if served.reference is None:
            later = "; try again later" if served.status in ("queued", "computing") else ""
            raise BodyError(409, f"scene {served.scene.name!r} has no reference ({served.status}"
                                 f"{': ' + served.reason if served.reason else ''}){later}")
        assert self.workers is not None
        blocks = session.layout()
        version = session.version
        try:
            result = await asyncio.wrap_future(self.workers.submit_score(
                served.scene.source, blocks, served.ref_key, served.reference.to_dict(), session.elapsed_s))
        except InputError as exc:
            raise BodyError(422, f"score: {exc}") from None
        except BrokenProcessPool:
            self.workers.restart_scores()
            raise BodyError(503, "the scoring process stopped and is restarted; try again") from None
        # The verdict is for the blocks as they were sent; those changed since are left out.
        if session.version == version and self.store.peek(sid) is session:
            session.unstable = set(result.get("unstable_blocks", []))
            self._changed(session, {"changed": [], "removed": [], "replaced": False}, time.perf_counter())
        return result

    def hint(self, sid: str) -> dict[str, Any]:
        """The next block to lay (:mod:`optimizer.serve.hint`), in the session's frame."""
        return self.prepare_hint(sid)()

    def prepare_hint(self, sid: str) -> Callable[[], dict[str, Any]]:
        """:meth:`hint`'s work, to run off the event loop: a hint lets its block go in a short
        settle (tens of milliseconds, a few hundred at most), and every session waited for it.
        The session is looked up here, on the loop; the function returned reads the session's
        blocks, which the app changes no one meanwhile (its change lock)."""
        started = time.perf_counter()
        session = self._session(sid)
        return lambda: self._hint_of(session, started)

    def _hint_of(self, session: Session, started: float) -> dict[str, Any]:
        served = self._served(session)
        if served.reference is None:
            return {"block": None, "source": "reference", "status": "pending" if served.status in (
                "queued", "computing") else "unavailable",
                    "message": f"the reference of {served.scene.name!r} is {served.status}"
                               + (f": {served.reason}" if served.reason else ""),
                    "seconds": time.perf_counter() - started}
        found = first_fitting(session.scene, session.live, served.plan)
        if found is not None:
            return self._hint(session, found, "reference", started)
        if len(session.live) >= session.scene.required_blocks:
            return {"block": None, "source": "reference", "status": "complete",
                    "message": "the required blocks are laid and no reference block fits",
                    "seconds": time.perf_counter() - started}
        return self._replan_hint(session, started)

    def _hint(self, session: Session, found: Any, source: str, started: float) -> dict[str, Any]:
        block = {**session.pose_out(found.pose), "type": found.type}
        return {"block": block, "source": source, "status": "ready", "plan_id": found.plan_id,
                "seconds": time.perf_counter() - started}

    def _replan_hint(self, session: Session, started: float) -> dict[str, Any]:
        """No reference block fits: a re-plan around the laid blocks, made in the background."""
        version, future, plan = self._replans.get(session.id, (-1, None, []))
        failed = future is not None and future.done() and future.exception() is not None
        if failed and version == session.version:
            return {"block": None, "source": "replan", "status": "unavailable",
                    "message": f"the re-plan failed: {str(future.exception()).splitlines()[0][:200]}",
                    "seconds": time.perf_counter() - started}
        current = future is not None and future.done() and version == session.version
        if current:
            # The re-plan of the blocks as laid now is done: its plan read here (the pool's
            # callback may not have run yet).
            self._replanned(session.id, future)
            plan = self._replans.get(session.id, (version, future, plan))[2]
        found = first_fitting(session.scene, session.live, plan) if plan else None
        if found is not None:
            return self._hint(session, found, "replan", started)
        if current:  # another re-plan would give the same: say so, not "pending" for good
            return {"block": None, "source": "replan", "status": "unavailable",
                    "message": "no block of the re-plan around the laid blocks fits",
                    "seconds": time.perf_counter() - started}
        if self.store.peek(session.id) is not session:
            # Ended (or expired) while this hint was worked out in its thread: no re-plan for it.
            return {"block": None, "source": "replan", "status": "unavailable",
                    "message": "the session has ended", "seconds": time.perf_counter() - started}
        if future is None or (future.done() and version != session.version):
            assert self.workers is not None
            future = self.workers.submit_replan(session.scene.source, session.layout(), self.replan_seconds)
            self._replans[session.id] = (session.version, future, plan)
            # The pool calls back on its own thread: hand the result to the event loop's (this
            # may run in a worker thread: the loop is the one the service started on).
            loop = self._loop if self._loop is not None else asyncio.get_running_loop()
            future.add_done_callback(
                lambda f, sid=session.id: loop.call_soon_threadsafe(self._replanned, sid, f))
        return {"block": None, "source": "replan", "status": "pending",
                "message": "no reference block fits; a re-plan around the laid blocks is running "
                           f"(at most {self.replan_seconds:g} s)",
                "seconds": time.perf_counter() - started}

    def _replanned(self, sid: str, future: Future[dict[str, Any]]) -> None:
        entry = self._replans.get(sid)
        if entry is None or entry[1] is not future or future.exception() is not None:
            return
        session = self.store.peek(sid)
        if session is None:
            return
        layout = layout_from_dict(future.result(), "re-plan", session.scene.base_dir)
        kept = {p.id for p in session.live}
        plan = [PlanBlock(p.id, p.type, b, p.pose)
                for p, (_, b, _) in zip(layout.blocks, layout.placed(), strict=True) if p.id not in kept]
        self._replans[sid] = (entry[0], future, plan)

    # --- the view ---------------------------------------------------------------

    def watch(self, sid: str) -> tuple[Session, asyncio.Queue[str]]:
        """A queue of the session's events, starting with its state now and every block in it."""
        session = self._session(sid)
        queue: asyncio.Queue[str] = asyncio.Queue(maxsize=QUEUE_EVENTS)
        queue.put_nowait(json.dumps({**self.state(session, time.perf_counter()), "removed": [],
                                     "changed": [session.block_record(p.id) for p in session.live],
                                     "replaced": True}))
        session.watchers.add(queue)
        return session, queue

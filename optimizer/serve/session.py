"""Sessions: one trainee's blocks on one scene, their state, and who is watching.

A session holds a :class:`optimizer.serve.live.LiveLayout`, the frame its
client speaks (``unity`` or ``world``) and the times the client gave. Its
**state** is the answer to every request that changes or reads it
(docs/serve.md). Sessions are kept by a :class:`SessionStore` that holds at
most ``max_sessions`` and forgets one idle for ``idle_s`` seconds, so memory
stays bounded whatever clients do.
"""

from __future__ import annotations

import asyncio
import json
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from geometry.layout import FORMAT
from geometry.pose import Pose
from geometry.scene import Scene
from optimizer.score.scoring import per_hour

from .bodies import MAX_SESSION_BLOCKS, BlockBody, BodyError
from .live import LiveLayout

#: Sessions kept at once, by default; one more is refused with 503 until one ends or expires.
MAX_SESSIONS = 64

#: A session no request has touched for this long is forgotten, by default (seconds).
IDLE_SECONDS = 3600.0

#: Events a slow watcher may fall behind by before its oldest is dropped (it gets the newest state).
QUEUE_EVENTS = 64


@dataclass
class Session:
    """One trainee's layout on one scene.

    Attributes
    ----------
    id : str
        Unguessable: 16 random bytes, URL-safe.
    scene : Scene
    frame : str
        ``unity`` or ``world``: the frame of the poses its client sends and receives.
    origin : (3,) float, metres, world frame
        Where Unity's origin lies (``unity`` frame only).
    live : LiveLayout
    elapsed_s : float or None
        The latest time the client has given, seconds since the session began.
    unstable : set of int
        Blocks the last ``POST /score`` found unstable, less those changed since.
    version : int
        Counts the changes; every event carries it.
    """

    id: str
    scene: Scene
    frame: str
    origin: np.ndarray
    live: LiveLayout
    elapsed_s: float | None = None
    unstable: set[int] = field(default_factory=set)
    version: int = 0
    last_used: float = field(default_factory=time.monotonic)
    watchers: set[asyncio.Queue[str]] = field(default_factory=set)

    # --- changes (each checked before anything is changed) ------------------------

    def put(self, key: int, body: BlockBody) -> dict[str, Any]:
        """Lay or move block ``key``; returns the change for watchers."""
        if key not in self.live and len(self.live) >= MAX_SESSION_BLOCKS:
            raise BodyError(422, f"a session holds at most {MAX_SESSION_BLOCKS} blocks")
        self.live.put(key, body.type, body.block, body.pose, body.time_s)
        if body.time_s is not None:
            self.elapsed_s = max(self.elapsed_s or 0.0, body.time_s)
        self.unstable.discard(key)
        self.version += 1
        return {"changed": [self.block_record(key)], "removed": [], "replaced": False}

    def remove(self, key: int) -> dict[str, Any]:
        if key not in self.live:
            raise BodyError(404, f"block {key} is not laid in this session")
        self.live.remove(key)
        self.unstable.discard(key)
        self.version += 1
        return {"changed": [], "removed": [key], "replaced": False}

    def replace(self, live: LiveLayout, elapsed_s: float | None) -> dict[str, Any]:
        """Every block at once: ``live`` is the new layout, built beside the old one."""
        self.live = live
        self.elapsed_s = elapsed_s
        self.unstable = set()
        self.version += 1
        return {"changed": [self.block_record(p.id) for p in live], "removed": [], "replaced": True}

    # --- answers ----------------------------------------------------------------

    def state(self, reference: dict[str, Any] | None, started: float) -> dict[str, Any]:
        """The session's state (docs/serve.md, "State"); ``started`` is the request's perf_counter."""
        live = self.live
        n = len(live)
        required = self.scene.required_blocks
        elapsed = self.elapsed_s
        return {
            "session": self.id,
            "scene": self.scene.name,
            "frame": self.frame,
            "version": self.version,
            "porosity_percent": live.porosity_percent,
            "blocks": n,
            "required_blocks": required,
            "remaining_blocks": max(0, required - n),
            "out_of_tolerance": [{"id": k, "outside_volume_m3": v} for k, v in live.out_of_tolerance()],
            "collisions": [{"a": a, "b": b, "depth_m": d} for a, b, d in live.collisions()],
            "protruding": live.protruding(),
            "unstable": sorted(self.unstable),
            "elapsed_s": elapsed,
            "blocks_per_hour": per_hour(n, elapsed),
            "reference": reference,
            "seconds": time.perf_counter() - started,
        }

    def block_record(self, key: int) -> dict[str, Any]:
        """Block ``key`` as a layout file writes it (world frame), with its time if given."""
        p = self.live.get(key)
        assert p is not None
        out: dict[str, Any] = {"id": p.id, "type": p.type, "position": [float(v) for v in p.pose.position],
                               "quaternion": [float(v) for v in p.pose.quaternion]}
        if p.time_s is not None:
            out["time_s"] = p.time_s
        return out

    def layout(self) -> dict[str, Any]:
        """The blocks as a ``shoha-layout/1`` object, world frame, installation order."""
        blocks = []
        for p in self.live:
            blocks.append({"id": p.id, "type": p.type, "position": [float(v) for v in p.pose.position],
                           "quaternion": [float(v) for v in p.pose.quaternion]})
        return {"format": FORMAT, "scene": self.scene.reference(), "blocks": blocks}

    def pose_out(self, pose: Pose) -> dict[str, Any]:
        """A world pose in the session's frame: Unity's objects, or the layout file's lists."""
        if self.frame == "world":
            return {"position": [float(v) for v in pose.position],
                    "quaternion": [float(v) for v in pose.quaternion]}
        return world_to_unity(pose, self.origin)

    # --- watchers ---------------------------------------------------------------

    def publish(self, event: dict[str, Any]) -> None:
        """Send an event to everyone watching; a watcher that lags loses its oldest event."""
        if not self.watchers:
            return
        text = json.dumps(event, allow_nan=False)
        for queue in self.watchers:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait(text)


def world_to_unity(pose: Pose, origin: np.ndarray) -> dict[str, Any]:
    """The inverse of :func:`geometry.unity.unity_to_world`: Unity's ``Vector3`` and ``Quaternion``.

    ``p_world = (x_u, z_u, y_u) + origin`` and a Unity ``(x, y, z, w)`` is the
    world ``[w, -x, -z, -y]`` (docs/contract.md), so both are undone by a swap
    and sign flips, exact in floating point.
    """
    d = pose.position - origin
    # "+ 0.0" writes a negated zero as 0.0, not -0.0; every other value is exact.
    w, qx, qy, qz = (float(v) for v in pose.quaternion)
    return {"position": {"x": float(d[0]), "y": float(d[2]), "z": float(d[1])},
            "rotation": {"x": -qx + 0.0, "y": -qz + 0.0, "z": -qy + 0.0, "w": w}}


class SessionStore:
    """Sessions by id, at most ``max_sessions``, each forgotten after ``idle_s`` seconds unused.

    Parameters
    ----------
    max_sessions : int
    idle_s : float, seconds
    clock : callable
        Monotonic seconds; tests may inject one.
    """

    def __init__(self, max_sessions: int = MAX_SESSIONS, idle_s: float = IDLE_SECONDS,
                 clock: Callable[[], float] = time.monotonic):
        self.max_sessions = max_sessions
        self.idle_s = idle_s
        self.clock = clock
        self._sessions: dict[str, Session] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def create(self, scene: Scene, frame: str, origin: np.ndarray) -> Session:
        self.expire()
        if len(self._sessions) >= self.max_sessions:
            raise BodyError(503, f"{self.max_sessions} sessions are open, the most this service keeps: "
                                 "end one (DELETE /sessions/ID) or wait for an idle one to expire")
        sid = secrets.token_urlsafe(16)
        session = Session(sid, scene, frame, origin, LiveLayout(scene), last_used=self.clock())
        self._sessions[sid] = session
        return session

    def get(self, sid: str) -> Session:
        """The session ``sid``, marked used; a 404 if there is none (or it expired)."""
        session = self._sessions.get(sid)
        if session is None or self.clock() - session.last_used > self.idle_s:
            if session is not None:
                self.end(sid)
            raise BodyError(404, f"no session {sid[:40]!r} (ended, expired or never created)")
        session.last_used = self.clock()
        return session

    def peek(self, sid: str) -> Session | None:
        """The session ``sid`` if there is one, without marking it used."""
        return self._sessions.get(sid)

    def end_all(self) -> None:
        for sid in list(self._sessions):
            self.end(sid)

    def end(self, sid: str) -> bool:
        """Forget a session, and tell its watchers; False if there was none."""
        session = self._sessions.pop(sid, None)
        if session is None:
            return False
        for queue in session.watchers:
            if queue.full():
                queue.get_nowait()
            queue.put_nowait("")  # an empty event closes the watcher's socket
        return True

    def expire(self) -> int:
        """Forget every session idle for longer than ``idle_s``; returns how many."""
        now = self.clock()
        stale = [sid for sid, s in self._sessions.items() if now - s.last_used > self.idle_s]
        for sid in stale:
            self.end(sid)
        return len(stale)

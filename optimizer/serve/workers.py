"""Work that takes seconds, done in other processes so the service keeps answering in milliseconds.

Three kinds of job leave the service's own process:

* **references**: ``optimize(scene, seed=0)`` for a scene served without a
  ``--reference``, 20 to 300 s of CPU, cached on disk under
  :func:`geometry.blocks.cache_dir` so that a restart finds it;
* **scores**: ``POST /sessions/{id}/score``, a physics settle of about a
  second;
* **re-plans**: ``optimize(scene, keep=...)`` around a trainee's blocks, for
  hints once the layout has left the reference behind (``shoha optimize
  --keep``'s library side).

A thread would not do: these are Python and NumPy work that holds the GIL for
milliseconds at a time, and every request would wait behind it. Each pool is
one process, started by ``spawn`` (no copy of the event loop or its
sockets). References and re-plans share one pool, lowered in priority
(``os.nice``) so that the service and its scores come first on a busy
machine; scores have their own pool, at normal priority, so a score never
waits for a reference. A child whose service has gone (killed, not stopped)
ends itself rather than run a long optimize for no one.

The functions run in the child take and return plain data (scene names and
paths the service chose, layout dicts), never a client's path.
"""

from __future__ import annotations

import hashlib
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from importlib import metadata
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from geometry.blocks import cache_dir
from geometry.scene import Scene

#: Priority of the child processes below the service's (os.nice increment).
CHILD_NICENESS = 10


def _watch_parent() -> None:
    """End this child once the service that started it is gone (its parent changes)."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, daemon=True).start()


def _lower_priority() -> None:
    _watch_parent()
    try:
        os.nice(CHILD_NICENESS)
    except OSError:  # pragma: no cover - nice is best effort
        pass


def reference_cache(scene: Scene, time_limit: float | None) -> Path:
    """Where the computed reference of ``scene`` is cached: keyed by the scene, the limit and shoha's version.

    The key is the scene's whole description (its ``repr``: design, tolerance,
    foundation, block, counts), seed 0 and the time limit, since a limit that
    binds cuts the search short.
    """
    try:
        version = metadata.version("shoha")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        version = "unknown"
    key = hashlib.sha256(f"{scene!r}|seed=0|limit={time_limit!r}|shoha={version}".encode()).hexdigest()[:24]
    return cache_dir() / "references" / f"{scene.name}-{key}.json"


# --- run in the child ---------------------------------------------------------------


def _load_scene(source: str) -> Scene:
    from geometry.scene import load_scene

    return load_scene(source)


def compute_reference(source: str, time_limit: float | None, path: str) -> str:
    """Optimize the scene ``source`` (a built-in name or a path the service was started with) and cache it.

    ``time_limit`` None leaves optimize's own default.
    """
    from geometry.layout import write_layout
    from optimizer.api import optimize

    scene = _load_scene(source)
    limit = {} if time_limit is None else {"time_limit": time_limit}
    result = optimize(scene, seed=0, **limit)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    layout = result.layout
    layout.scene = scene.reference(out.parent)
    write_layout(layout, out)
    return str(out)


def replan(source: str, kept: dict[str, Any], time_limit: float) -> dict[str, Any]:
    """A layout that keeps ``kept`` (a ``shoha-layout/1`` dict, world frame) and places the rest.

    This is the one place the re-plan meets the optimizer: ``optimize(scene,
    seed=0, keep=LAYOUT, time_limit=...)``, the library side of ``shoha
    optimize --keep``.
    """
    from geometry.layout import layout_from_dict
    from optimizer.api import optimize

    scene = _load_scene(source)
    layout = layout_from_dict(kept, "kept blocks", scene.base_dir)
    result = optimize(scene, seed=0, time_limit=time_limit, keep=layout.blocks)
    return result.layout.to_dict()


_REFERENCES: dict[str, Any] = {}


def _reference(source: str, key: str, reference: dict[str, Any]) -> Any:
    """The scoring analysis of a reference layout, made once per child process."""
    from geometry.layout import layout_from_dict
    from optimizer.score import Reference

    if key not in _REFERENCES:
        scene = _load_scene(source)
        layout = layout_from_dict(reference, "reference", scene.base_dir)
        _REFERENCES[key] = Reference.of(scene, layout.placed())
    return _REFERENCES[key]


def score_layout(source: str, blocks: dict[str, Any], ref_key: str, reference: dict[str, Any],
                 elapsed_s: float | None = None) -> dict[str, Any]:
    """``shoha score --json``'s object for ``blocks`` (a layout dict) against ``reference``.

    ``elapsed_s`` (the session's time) goes to ``score`` where it takes one, so
    that the answer has the completion time ``shoha score`` reports for a save
    with times.
    """
    from geometry.layout import layout_from_dict
    from optimizer.score import score

    scene = _load_scene(source)
    ref = _reference(source, ref_key, reference)
    layout = layout_from_dict(blocks, "session", scene.base_dir)
    return score(scene, layout.placed(), ref, elapsed_s=elapsed_s).to_dict()


def warm(items: list[tuple[str, str, dict[str, Any]]]) -> int:
    """Import the scoring modules and analyse the known references, so the first score is quick."""
    import optimizer.score  # noqa: F401
    import settle  # noqa: F401

    for source, key, reference in items:
        _reference(source, key, reference)
    return len(items)


# --- the pools ---------------------------------------------------------------------


class Workers:
    """The service's two child processes: one for scores, one for references and re-plans."""

    def __init__(self) -> None:
        ctx = get_context("spawn")
        self.scores = ProcessPoolExecutor(1, mp_context=ctx, initializer=_watch_parent)
        self.plans = ProcessPoolExecutor(1, mp_context=ctx, initializer=_lower_priority)

    def restart_scores(self) -> None:
        """A new scoring process, after the last one died (a crash in the settle, say)."""
        self.scores.shutdown(wait=False, cancel_futures=True)
        self.scores = ProcessPoolExecutor(1, mp_context=get_context("spawn"), initializer=_watch_parent)

    def submit_score(self, *args: Any) -> Future[dict[str, Any]]:
        return self.scores.submit(score_layout, *args)

    def submit_reference(self, *args: Any) -> Future[str]:
        return self.plans.submit(compute_reference, *args)

    def submit_replan(self, *args: Any) -> Future[dict[str, Any]]:
        return self.plans.submit(replan, *args)

    def warm(self, items: list[tuple[str, str, dict[str, Any]]]) -> Future[int]:
        return self.scores.submit(warm, items)

    def shutdown(self) -> None:
        """Stop both pools now: a reference being computed is abandoned (its cache file is not written)."""
        for pool in (self.scores, self.plans):
            # ProcessPoolExecutor waits for a running job even with cancel_futures; an optimize may run
            # for minutes, so its process is ended here.
            processes = list((getattr(pool, "_processes", None) or {}).values())
            for process in processes:
                process.terminate()
            pool.shutdown(wait=True, cancel_futures=True)

"""Physics settle: backends and the stability verdict (issue 3, docs/settle.md).

>>> from settle import settle, MujocoBackend          # doctest: +SKIP
>>> result = settle(scene, layout.placed(), seconds=2.0, seed=0)  # doctest: +SKIP
>>> result.stable, result.max_displacement_m          # doctest: +SKIP

``settle`` (:mod:`settle.run`) is the one entry point; the physics engine is
a backend instance (:class:`MujocoBackend` for 3D scenes, :class:`PymunkBackend`
for section scenes), chosen by the scene's kind when none is given. The
interface the backends implement is :mod:`settle.base`, which imports no
backend.
"""

from .base import (
    DEFAULT_SECONDS,
    BlockSettle,
    Diverged,
    Run,
    SettleBackend,
    SettleBody,
    SettleResult,
    Stopped,
    Thresholds,
)
from .mujoco_backend import MujocoBackend
from .pymunk_backend import PymunkBackend
from .run import default_backend, settle

__all__ = [
    "DEFAULT_SECONDS",
    "BlockSettle",
    "Diverged",
    "MujocoBackend",
    "PymunkBackend",
    "Run",
    "SettleBackend",
    "SettleBody",
    "SettleResult",
    "Stopped",
    "Thresholds",
    "default_backend",
    "settle",
]

"""Quaternion helpers: shoha's plain-float code against ``scipy.spatial.transform.Rotation``.

``geometry.pose`` keeps hand-written code only where this benchmark shows it
is needed; everything else is scipy's ``Rotation`` (``scalar_first=True``).
For each helper it measures, in one process:

* microseconds per call, hand-written and scipy, for one quaternion (the
  optimizer's hot path: every candidate pose and every hanging) and for a
  batch of 512 (the sampling paths);
* how often each one-quaternion helper is called in one ``shoha optimize
  mini --seed 1`` run (cProfile's call counts), and so the seconds scipy would
  add to that run;
* how often scipy's answer equals the hand-written one bit for bit over 1000
  random rotations: where it does not, swapping changes the layout's bytes.

Run::

    .venv/bin/python benchmarks/pose_speed.py [--no-profile]

Writes ``benchmarks/results/pose_speed.csv`` and ``.json``.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import timeit

import numpy as np
from common import Run
from scipy.spatial.transform import Rotation

from geometry.pose import axis_angle_quat, quat_multiply, quat_to_matrix
from geometry.scene import load_scene

CALLS = 20_000
BATCH = 512


def per_call(fn, number: int = CALLS) -> float:
    """Microseconds per call: the best of five timeit runs."""
    return min(timeit.repeat(fn, number=number, repeat=5)) / number * 1e6


def hand_matrix_batch(q: np.ndarray) -> np.ndarray:
    """The plain-numpy batch path shoha had before scipy took it over."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    return m.reshape(q.shape[:-1] + (3, 3))


def call_counts() -> dict[str, int]:
    """Calls of each helper in one ``optimize(mini, seed=1)`` run, from cProfile."""
    from optimizer.api import optimize

    profile = cProfile.Profile()
    profile.enable()
    optimize(load_scene("mini"), seed=1, time_limit=600)
    profile.disable()
    stats = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    counts = {"quat_to_matrix": 0, "quat_multiply": 0, "axis_angle_quat": 0}
    for (filename, _, name), row in stats.items():
        if filename.endswith("geometry/pose.py") and name in counts:
            counts[name] += row[1]  # primitive calls
    return counts


def main() -> None:
    profile = "--no-profile" not in sys.argv
    run = Run("pose_speed", {"calls": CALLS, "batch": BATCH, "profile": profile})
    qs = Rotation.random(1000, rng=np.random.default_rng(0)).as_quat(scalar_first=True, canonical=True)
    q, a, b = qs[0], qs[1], qs[2]
    axis, angle = np.array([0.0, 0.0, 1.0]), 0.3

    def scipy_matrix(x):
        return Rotation.from_quat(x, scalar_first=True).as_matrix()

    def scipy_multiply(x, y):
        return (Rotation.from_quat(x, scalar_first=True) * Rotation.from_quat(y, scalar_first=True)
                ).as_quat(scalar_first=True)

    def scipy_axis_angle(u, t):
        return Rotation.from_rotvec(np.asarray(u) * t).as_quat(scalar_first=True)

    cases = [
        ("quat_to_matrix", "one", lambda: quat_to_matrix(q), lambda: scipy_matrix(q),
         sum(np.array_equal(quat_to_matrix(x), scipy_matrix(x)) for x in qs)),
        ("quat_to_matrix", f"batch of {BATCH}", lambda: hand_matrix_batch(qs[:BATCH]),
         lambda: scipy_matrix(qs[:BATCH]), None),
        ("quat_multiply", "one", lambda: quat_multiply(a, b), lambda: scipy_multiply(a, b),
         sum(np.array_equal(quat_multiply(qs[i], qs[i + 1]), scipy_multiply(qs[i], qs[i + 1]))
             for i in range(len(qs) - 1))),
        ("axis_angle_quat", "one", lambda: axis_angle_quat(axis, angle),
         lambda: scipy_axis_angle(axis, angle),
         sum(np.array_equal(axis_angle_quat(axis, t), scipy_axis_angle(axis, t))
             for t in np.linspace(0.0, 2 * np.pi, 1000))),
    ]
    counts = call_counts() if profile else {}
    rows = []
    for name, size, hand, scipy_fn, equal in cases:
        number = CALLS if size == "one" else CALLS // 20
        t_hand, t_scipy = per_call(hand, number), per_call(scipy_fn, number)
        calls = counts.get(name) if size == "one" else None
        extra = calls * (t_scipy - t_hand) * 1e-6 if calls is not None else None
        rows.append({"helper": name, "size": size, "hand_us": t_hand, "scipy_us": t_scipy,
                     "scipy_over_hand": t_scipy / t_hand, "calls_in_mini_run": calls,
                     "scipy_extra_seconds_in_mini_run": extra,
                     "bitwise_equal_of_1000": equal})
        added = f"+{extra:.1f} s" if extra is not None else ""
        print(f"{name:16s} {size:13s} hand {t_hand:7.2f} us  scipy {t_scipy:7.2f} us  "
              f"x{t_scipy / t_hand:5.1f}  calls {calls}  {added}  bit-equal {equal}")
    run.csv("pose_speed", rows)
    run.done()


if __name__ == "__main__":
    main()

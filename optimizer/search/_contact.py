"""The first-contact loop of :func:`optimizer.search.drop.rest_height`, compiled by numba.

Its arrays are a few dozen rows each: in numpy the cost per call, not the
arithmetic, was the drop's time. Compiled once per machine and cached on disk
(``cache=True``, beside this file or in numba's user cache where that is not
writable).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def column(normals, offsets, x, y, eps):  # pragma: no cover - compiled
    """Where the vertical line through (x, y) crosses the polytope ``normals @ p <= offsets``:
    ``(lo, hi)``, with ``lo > hi`` where it misses (as :func:`geometry.polytope.column_intervals`)."""
    lo, hi = -np.inf, np.inf
    for k in range(normals.shape[0]):
        nz = normals[k, 2]
        rhs = offsets[k] - (x * normals[k, 0] + y * normals[k, 1])
        if nz > eps:
            hi = min(hi, rhs / nz)
        elif nz < -eps:
            lo = max(lo, rhs / nz)
        elif rhs < -eps:
            return np.inf, -np.inf
    return lo, hi


@numba.njit(cache=True)
def height_at(mn, mo, fn, fo, ox, oy, x, y, eps, best):  # pragma: no cover - compiled
    """``best``, or the fixed piece's top less the moving piece's bottom on the line through
    (x, y), if both pieces cross it and that is higher (the moving piece moved by (ox, oy))."""
    q_lo, q_hi = column(fn, fo, x, y, eps)
    if not q_hi >= q_lo - eps:
        return best
    p_lo, p_hi = column(mn, mo, x - ox, y - oy, eps)
    if not p_hi >= p_lo - eps:
        return best
    return max(best, q_hi - p_lo)


@numba.njit(cache=True)
def rest_height_kernel(mn, mo, me, mv, fn, fo, fe, fv, ox, oy, eps, parallel):  # pragma: no cover - compiled
    """The largest top-less-bottom over the breakpoints, ``-inf`` where the pieces never meet:
    the moving piece's lower vertices ``mv`` (moved by (ox, oy)), the fixed piece's upper
    vertices ``fv``, and where a lower edge ``me`` of one crosses an upper edge ``fe`` of the
    other in plan. ``mn, mo`` and ``fn, fo`` are the pieces' planes."""
    best = -np.inf
    for i in range(mv.shape[0]):
        best = height_at(mn, mo, fn, fo, ox, oy, mv[i, 0] + ox, mv[i, 1] + oy, eps, best)
    for i in range(fv.shape[0]):
        best = height_at(mn, mo, fn, fo, ox, oy, fv[i, 0], fv[i, 1], eps, best)
    for i in range(me.shape[0]):
        # The edge moved first, then its direction taken (as the numpy version did).
        px, py = me[i, 0, 0] + ox, me[i, 0, 1] + oy
        rx, ry = (me[i, 1, 0] + ox) - px, (me[i, 1, 1] + oy) - py
        for j in range(fe.shape[0]):
            qx, qy = fe[j, 0, 0], fe[j, 0, 1]
            sx, sy = fe[j, 1, 0] - qx, fe[j, 1, 1] - qy
            denom = rx * sy - ry * sx
            if not abs(denom) > parallel:
                continue
            t = ((qx - px) * sy - (qy - py) * sx) / denom
            u = ((qx - px) * ry - (qy - py) * rx) / denom
            if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0:
                best = height_at(mn, mo, fn, fo, ox, oy, px + t * rx, py + t * ry, eps, best)
    return best

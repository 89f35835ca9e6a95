"""The first-contact loop of :func:`optimizer.search.drop.rest_height`, compiled by numba.

Its arrays are a few dozen rows each: in numpy the cost per call, not the
arithmetic, was the drop's time (``benchmarks/drop_speed.py``). Compiled once
per machine and cached on disk beside this file, or in numba's user cache
(``NUMBA_CACHE_DIR``) where this folder is not writable. Where neither is (a
read-only install run by a user with no writable home), numba refuses to cache
at import: the loop is then compiled anew in each process, about a second.
"""

from __future__ import annotations

import numba
import numpy as np


def _jit(function):
    """``function`` compiled, cached on disk where numba finds a place for it, else not."""
    try:
        return numba.njit(cache=True)(function)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return numba.njit(function)


@_jit
def column(normals, offsets, x, y, eps):  # pragma: no cover - compiled
    """Where the vertical line through (x, y) crosses the polytope ``normals @ p <= offsets``.

    Parameters
    ----------
    normals : (k, 3) float
    offsets : (k,) float, metres
    x, y : float, metres
    eps : float, metres
        Planes whose normal's z is within it are vertical.

    Returns ``(lo, hi)``, with ``lo > hi`` where the line misses; NaN where a coordinate is
    NaN (a bound is replaced unless the new value is on the kept side of it). The same as
    :func:`geometry.polytope.column_intervals` for one column, which stays the one for many
    columns at once; a test holds the two together.
    """
    lo, hi = -np.inf, np.inf
    for k in range(normals.shape[0]):
        nz = normals[k, 2]
        rhs = offsets[k] - (x * normals[k, 0] + y * normals[k, 1])
        if nz > eps:
            v = rhs / nz
            if not v >= hi:
                hi = v
        elif nz < -eps:
            v = rhs / nz
            if not v <= lo:
                lo = v
        elif rhs < -eps:
            return np.inf, -np.inf
    return lo, hi


@_jit
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


@_jit
def rest_height_kernel(mn, mo, me, mv, fn, fo, fe, fv, ox, oy, eps, parallel):  # pragma: no cover - compiled
    """The largest top-less-bottom over the breakpoints, ``-inf`` where the pieces never meet.

    Parameters
    ----------
    mn, mo : (k, 3), (k,) float
        The moving piece's planes, its reference point at the origin.
    me, mv : (e, 2, 3), (v, 3) float, metres
        The edges and vertices of its lower side.
    fn, fo, fe, fv : the same for the fixed piece, in the world frame (its upper side).
    ox, oy : float, metres
        Where the moving piece is lowered.
    eps, parallel : float
        ``tol.distance`` and ``tol.parallel``.

    The breakpoints are the moving piece's lower vertices (moved by (ox, oy)), the fixed
    piece's upper vertices, and where a lower edge of one crosses an upper edge of the
    other in plan.
    """
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

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


@_jit
def field_height(xs, ys, h, cell, edge, x, y):  # pragma: no cover - compiled
    """The rough foundation's top at (x, y): :meth:`geometry.scene.Foundation.height_at` for
    one point (``edge`` is ``tol.grid_edge``)."""
    fx = min(max((x - xs[0]) / cell, 0.0), len(xs) - 1 - edge)
    fy = min(max((y - ys[0]) / cell, 0.0), len(ys) - 1 - edge)
    i, j = int(fx), int(fy)
    tx, ty = fx - i, fy - j
    h00, h10, h01, h11 = h[i, j], h[i + 1, j], h[i, j + 1], h[i + 1, j + 1]
    if tx >= ty:
        return h00 + tx * (h10 - h00) + ty * (h11 - h10)
    return h00 + ty * (h01 - h00) + tx * (h11 - h01)


@_jit
def ground_kernel(normals, offsets, starts, vxy, box, xs, ys, h, cell, edge, x, y, eps):  # pragma: no cover
    """Lowest centroid height at which a shape lowered at (x, y) clears a rough foundation.

    Parameters
    ----------
    normals, offsets : (k, 3), (k,) float
        The planes of every piece, one after another, centroid at the origin; piece ``p``'s
        are rows ``starts[p]:starts[p + 1]``.
    vxy : (v, 2) float, metres
        Every piece's vertices in plan, centroid at the origin.
    box : (2, 2) float, metres
        The shape's footprint box, centroid at the origin.
    xs, ys, h, cell : the foundation's grid (:attr:`geometry.scene.Foundation.grid`).
    edge, eps : float
        ``tol.grid_edge`` and ``tol.distance``.

    The ground is sampled where :meth:`optimizer.search.drop.DropWorld.ground_height` samples
    it, the block's vertices and the grid's nodes under its footprint box; each piece meets it
    on the columns it crosses. ``-inf`` if no piece crosses any; NaN where (x, y) is not finite
    (the grid is not indexed by it: numba does not check bounds).
    """
    if not (np.isfinite(x) and np.isfinite(y)):
        return np.nan
    best = -np.inf
    i0 = np.searchsorted(xs, box[0, 0] + x)
    i1 = np.searchsorted(xs, box[1, 0] + x, side="right")
    j0 = np.searchsorted(ys, box[0, 1] + y)
    j1 = np.searchsorted(ys, box[1, 1] + y, side="right")
    n_v = vxy.shape[0]
    n = n_v + (i1 - i0) * (j1 - j0)
    lx = np.empty(n)
    ly = np.empty(n)
    g = np.empty(n)
    for k in range(n_v):
        lx[k], ly[k] = vxy[k, 0], vxy[k, 1]
    k = n_v
    for i in range(i0, i1):
        for j in range(j0, j1):
            lx[k], ly[k] = xs[i] - x, ys[j] - y
            k += 1
    for k in range(n):
        g[k] = field_height(xs, ys, h, cell, edge, lx[k] + x, ly[k] + y)
    for p in range(starts.shape[0] - 1):
        pn = normals[starts[p]:starts[p + 1]]
        po = offsets[starts[p]:starts[p + 1]]
        for k in range(n):
            lo, hi = column(pn, po, lx[k], ly[k], eps)
            if hi >= lo - eps:
                v = g[k] - lo
                if v > best:
                    best = v
    return best


def warm() -> None:
    """Compile every loop here on arrays of the types a search passes, so numba caches them on
    disk before the first ``shoha optimize``: ``make`` runs it after installing
    (``python -m optimizer.search._contact``). Compiled on first use instead, they took about
    1.5 s of a run's time limit (``mini-rough`` at ``--time-limit 2`` wrote 0 blocks in 2.56 s,
    2026-11-28)."""
    cube = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [0, 0, 1.0], [0, 0, -1.0]])
    offsets = np.full(6, 0.5)
    edges = np.zeros((1, 2, 3))
    edges[0, 1] = 1.0
    points = np.zeros((1, 3))
    rest_height_kernel(cube, offsets, edges, points, cube, offsets, edges, points, 0.0, 0.0, 1e-9, 1e-12)
    grid = np.arange(-1.0, 1.5, 0.5)
    ground_kernel(cube, offsets, np.array([0, 6]), np.zeros((1, 2)), np.array([[-0.5, -0.5], [0.5, 0.5]]),
                  grid, grid, np.zeros((len(grid), len(grid))), 0.5, 1e-9, 0.0, 0.0, 1e-9)


if __name__ == "__main__":
    warm()

"""Plan and cross-section drawings of a layout, for print (``shoha render``).

Two views with matplotlib, world frame, metres:

plan
    Looking down -z: each block's convex pieces projected onto the x-y plane,
    with the footprints of the design prism, the tolerance prism and the
    crest. The crest runs left to right (+y), as it does on a drawing sheet.
cross-section
    The x-z plane at ``y = section_y``: the design trapezoid, the tolerance
    trapezoid and the crest (the paper's Fig. 3), each block's pieces cut by
    the plane, and in pale grey every block projected along y behind it.

Blocks out of tolerance are yellow (the paper's Fig. 11), unstable ones red
(when a settle verdict is given), colliding ones orange.

The figure is built with ``matplotlib.figure.Figure`` and the Agg canvas,
never pyplot, so no global state is touched.
"""

from __future__ import annotations

import io
import os
from collections.abc import Collection, Sequence

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from geometry.blocks import Block
from geometry.constants import tol
from geometry.fileio import atomic_write
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism

Placed = Sequence[tuple[int, Block, Pose]]

#: Colours shared with the HTML report (optimizer/report.py).
COLOURS = {
    "block": "#9a9a9a",
    "protruding": "#f5d000",  # yellow, the paper's Fig. 11
    "unstable": "#d62728",
    "colliding": "#ff7f0e",
    "design": "#1f77b4",
    "tolerance": "#2ca02c",
    "crest": "#9467bd",
}

FORMATS = (".png", ".pdf", ".svg")


def block_status(key: int, protruding: Collection[int], unstable: Collection[int],
                 colliding: Collection[int]) -> str:
    """The colour class of a block: unstable before protruding before colliding."""
    if key in unstable:
        return "unstable"
    if key in protruding:
        return "protruding"
    if key in colliding:
        return "colliding"
    return "block"


def _hull2d(points: np.ndarray) -> np.ndarray | None:
    """Convex hull polygon of ``(n, 2)`` points, or None if they span no area."""
    if len(points) < 3:
        return None
    try:
        hull = ConvexHull(points)
    except QhullError:
        return None
    return points[hull.vertices]


def piece_section(vertices: np.ndarray, edges: np.ndarray, y: float) -> np.ndarray | None:
    """Polygon (x, z) where a convex piece meets the plane ``y``, or None.

    Parameters
    ----------
    vertices : (n, 3) float, metres, world frame
    edges : (e, 2) int
        The piece's hull edges.
    """
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    da, db = a[:, 1] - y, b[:, 1] - y
    cross = (da * db < 0) | (np.abs(da) <= tol.distance)
    if not cross.any():
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(db - da) > tol.distance, da / (da - db), 0.0)
    pts = a[cross] + t[cross, None] * (b[cross] - a[cross])
    return _hull2d(pts[:, [0, 2]])


def _prism_outline_xz(prism: TrapezoidalPrism) -> np.ndarray:
    return np.vstack([prism.section, prism.section[:1]])


def _prism_outline_yx(prism: TrapezoidalPrism, half: float) -> np.ndarray:
    y0, y1 = prism.y_start, prism.y_end
    return np.array([[y0, -half], [y1, -half], [y1, half], [y0, half], [y0, -half]])


def draw(
    scene: Scene,
    placed: Placed,
    protruding: Collection[int] = (),
    unstable: Collection[int] = (),
    colliding: Collection[int] = (),
    section_y: float | None = None,
    title: str | None = None,
) -> object:
    """The plan and cross-section figure (a ``matplotlib.figure.Figure``).

    Parameters
    ----------
    scene : Scene
    placed : sequence of (id, Block, Pose)
    protruding, unstable, colliding : collections of int
        Block ids to colour yellow, red and orange.
    section_y : float, metres, optional
        Where the cross-section cuts; the middle of the crest by default.
    title : str, optional
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Polygon

    d, t = scene.design, scene.tolerance
    y_cut = 0.5 * (d.y_start + d.y_end) if section_y is None else float(section_y)
    fig = Figure(figsize=(8.3, 11.7), dpi=150)  # A4 portrait
    plan, cut = fig.subplots(2, 1, gridspec_kw={"height_ratios": [1.6, 1.0]})

    poses = []
    for key, block, pose in placed:
        status = block_status(key, protruding, unstable, colliding)
        pieces = [piece.transformed(pose.rotation, pose.position) for piece in block.pieces]
        poses.append((key, status, pieces, block))

    # Plan view: pieces projected on x-y, drawn y across, x up; lower blocks first.
    def lowest(entry: tuple) -> float:
        return min(p.vertices[:, 2].min() for p in entry[2])

    for _key, status, pieces, _block in sorted(poses, key=lowest):
        for piece in pieces:
            poly = _hull2d(piece.vertices[:, [1, 0]])
            if poly is not None:
                plan.add_patch(Polygon(poly, closed=True, facecolor=COLOURS[status], edgecolor="#333333",
                                       linewidth=0.3, alpha=0.9))
    plan.plot(*_prism_outline_yx(t, t.bottom_half_width).T, color=COLOURS["tolerance"], lw=1.2, ls="--")
    plan.plot(*_prism_outline_yx(d, d.bottom_half_width).T, color=COLOURS["design"], lw=1.2)
    for x in (-d.top_half_width, d.top_half_width):
        plan.plot([d.y_start, d.y_end], [x, x], color=COLOURS["crest"], lw=1.5)
    plan.axhline(0.0, color="#555555", lw=0.5, ls=":")
    plan.axvline(y_cut, color="#555555", lw=0.8, ls="-.")
    plan.set_aspect("equal")
    plan.set_xlabel("y along the crest (m)")
    plan.set_ylabel("x across (m)")
    plan.set_title("Plan (looking down)")
    plan.set_xlim(t.y_start - 0.5, t.y_end + 0.5)
    plan.set_ylim(-t.bottom_half_width - 0.5, t.bottom_half_width + 0.5)

    # Cross-section: projections behind, then the pieces cut by the plane.
    for _key, _status, pieces, _block in poses:
        for piece in pieces:
            poly = _hull2d(piece.vertices[:, [0, 2]])
            if poly is not None:
                cut.add_patch(Polygon(poly, closed=True, facecolor="#e4e4e4", edgecolor="none"))
    for _key, status, pieces, _block in poses:
        for piece in pieces:
            poly = piece_section(piece.vertices, piece.edges, y_cut)
            if poly is not None:
                cut.add_patch(Polygon(poly, closed=True, facecolor=COLOURS[status], edgecolor="#222222",
                                      linewidth=0.5))
    cut.plot(*_prism_outline_xz(t).T, color=COLOURS["tolerance"], lw=1.2, ls="--")
    cut.plot(*_prism_outline_xz(d).T, color=COLOURS["design"], lw=1.2)
    cut.plot([-d.top_half_width, d.top_half_width], [d.z_top, d.z_top], color=COLOURS["crest"], lw=2.5)
    ground = t.bottom_half_width + 1.0
    cut.fill_between([-ground, ground], [scene.foundation.lowest - 0.3] * 2, [0.0, 0.0], color="#c8b99a",
                     zorder=0)
    cut.set_aspect("equal")
    cut.set_xlim(-ground, ground)
    cut.set_ylim(scene.foundation.lowest - 0.3, t.z_top + 0.8)
    cut.set_xlabel("x across (m)")
    cut.set_ylabel("z up (m)")
    cut.set_title(f"Cross-section at y = {y_cut:.2f} m (pale: all blocks seen along the crest)")

    handles = [Line2D([], [], color=COLOURS["design"], lw=1.2, label="design prism"),
               Line2D([], [], color=COLOURS["tolerance"], lw=1.2, ls="--", label="tolerance prism"),
               Line2D([], [], color=COLOURS["crest"], lw=2.5, label="crest")]
    for status, label in (("block", "block"), ("protruding", "out of tolerance"), ("unstable", "unstable"),
                          ("colliding", "colliding")):
        handles.append(Line2D([], [], marker="s", ls="", markersize=9, markerfacecolor=COLOURS[status],
                              markeredgecolor="#333333", label=label))
    fig.legend(handles=handles, loc="lower center", ncol=4, frameon=False, fontsize=8)
    fig.suptitle(title or f"{scene.name}: {len(placed)} blocks")
    fig.subplots_adjust(left=0.1, right=0.97, top=0.94, bottom=0.08, hspace=0.2)
    return fig


def render(
    scene: Scene,
    placed: Placed,
    path: str | os.PathLike,
    protruding: Collection[int] = (),
    unstable: Collection[int] = (),
    colliding: Collection[int] = (),
    section_y: float | None = None,
    title: str | None = None,
) -> None:
    """Draw the plan and cross-section to ``path`` (.png, .pdf or .svg), atomically."""
    fig = draw(scene, placed, protruding, unstable, colliding, section_y, title)
    suffix = os.fspath(path).rsplit(".", 1)[-1].lower()
    buffer = io.BytesIO()
    fig.savefig(buffer, format=suffix)  # type: ignore[attr-defined]
    atomic_write(path, buffer.getvalue())

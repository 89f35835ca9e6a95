"""The HTML report of a score (``shoha score --html``): one file that works offline.

The page holds plotly's JavaScript bundle inline (``plotly.offline.get_plotlyjs``,
no CDN, no other request), and shows:

* the score out of 100 and, apart, its two parts: progress (blocks laid of
  those required) and quality (what is laid), with each penalty and its rule
  (docs/scoring.md);
* an interactive 3D view of the trainee's layout, with check boxes that show
  and hide the design prism, the tolerance prism and the crest (the reference
  paper's Fig. 10 and its display settings, Table III item 9). Blocks out of
  tolerance are yellow (Fig. 11), unstable blocks red, colliding blocks orange;
* the porosity map by zone, the trainee's beside the reference's;
* the metrics table and the faulty blocks by id.

World frame, metres, throughout (docs/contract.md).
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from geometry.blocks import Block
from geometry.fileio import atomic_write
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism

from .render import COLOURS, block_status
from .scoring import ScoreReport, Zone

Placed = Sequence[tuple[int, Block, Pose]]

#: Check boxes of the 3D view: (element id, label, trace group).
TOGGLES = (
    ("toggle-design", "Design prism", "design"),
    ("toggle-tolerance", "Tolerance prism", "tolerance"),
    ("toggle-crest", "Crest (top end)", "crest"),
)

_LABELS = {"block": "blocks", "protruding": "out of tolerance (yellow)", "unstable": "unstable (red)",
           "colliding": "colliding (orange)"}


def _prism_traces(prism: TrapezoidalPrism, name: str, colour: str, opacity: float,
                  group: str) -> list[Any]:
    """A translucent mesh and its edges as lines, world frame."""
    import plotly.graph_objects as go

    poly = prism.polytope
    v, f = poly.vertices, poly.faces
    mesh = go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], color=colour,
                     opacity=opacity, name=name, legendgroup=group, showlegend=True, hoverinfo="name",
                     flatshading=True)
    c = prism.corners  # 4 corners at y_start, then 4 at y_end
    loop = [0, 1, 2, 3, 0, 4, 5, 6, 7, 4]
    pts = [c[i] for i in loop]
    for a, b in ((1, 5), (2, 6), (3, 7)):
        pts += [np.full(3, np.nan), c[a], c[b]]
    p = np.array(pts)
    edges = go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", line={"color": colour, "width": 3},
                         name=f"{name} edges", legendgroup=group, showlegend=False, hoverinfo="skip")
    return [mesh, edges]


def _crest_traces(scene: Scene) -> list[Any]:
    import plotly.graph_objects as go

    c = scene.crest
    mesh = go.Mesh3d(x=c[:, 0], y=c[:, 1], z=c[:, 2], i=[0, 0], j=[1, 2], k=[2, 3],
                     color=COLOURS["crest"], opacity=0.45, name="Crest (top end)", legendgroup="crest",
                     showlegend=True, hoverinfo="name")
    loop = np.vstack([c, c[:1]])
    line = go.Scatter3d(x=loop[:, 0], y=loop[:, 1], z=loop[:, 2], mode="lines",
                        line={"color": COLOURS["crest"], "width": 6}, name="crest edges",
                        legendgroup="crest", showlegend=False, hoverinfo="skip")
    return [mesh, line]


def _block_traces(placed: Placed, report: ScoreReport) -> list[Any]:
    """One mesh per colour class, each vertex labelled with its block."""
    import plotly.graph_objects as go

    protruding = {k: v for k, v in report.out_of_tolerance}
    unstable = {b.id: b for b in report.settle.blocks if not b.stable}
    colliding = {c.a for c in report.collisions} | {c.b for c in report.collisions}
    contacts = report.interlock.by_id()
    groups: dict[str, list[tuple[np.ndarray, np.ndarray, str]]] = {s: [] for s in _LABELS}
    for key, block, pose in placed:
        status = block_status(key, protruding, unstable, colliding)
        info = [f"block {key}"]
        if key in protruding:
            info.append(f"{protruding[key]:.3f} m3 out of tolerance")
        if key in unstable:
            moved = unstable[key]
            info.append(f"moved {moved.displacement_m:.3f} m, turned {moved.rotation_deg:.1f} deg")
        if key in contacts:
            held = contacts[key]
            info.append(f"{held.contact_count} contacts, {len(held.neighbours)} neighbours"
                        + (" (poorly interlocked)" if held.flagged else ""))
        groups[status].append((pose.apply(block.vertices), block.faces, "<br>".join(info)))
    traces = []
    for status, members in groups.items():
        if not members:
            continue
        verts, faces, text, offset = [], [], [], 0
        for v, f, label in members:
            verts.append(v)
            faces.append(f + offset)
            text += [label] * len(v)
            offset += len(v)
        v, f = np.vstack(verts), np.vstack(faces)
        traces.append(go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                                color=COLOURS[status], name=f"{_LABELS[status]}: {len(members)}", text=text,
                                hovertemplate="%{text}<extra></extra>", flatshading=True,
                                lighting={"ambient": 0.7, "diffuse": 0.6, "specular": 0.05},
                                showlegend=True))
    return traces


def view_figure(scene: Scene, placed: Placed, report: ScoreReport) -> tuple[Any, dict[str, list[int]]]:
    """The 3D figure and the trace indices of each toggle group."""
    import plotly.graph_objects as go

    traces: list[Any] = []
    groups: dict[str, list[int]] = {}

    def add(group: str, new: list[Any]) -> None:
        groups.setdefault(group, []).extend(range(len(traces), len(traces) + len(new)))
        traces.extend(new)

    add("blocks", _block_traces(placed, report))
    add("design", _prism_traces(scene.design, "Design prism", COLOURS["design"], 0.12, "design"))
    add("tolerance", _prism_traces(scene.tolerance, "Tolerance prism", COLOURS["tolerance"], 0.08,
                                   "tolerance"))
    add("crest", _crest_traces(scene))
    fig = go.Figure(traces)
    fig.update_layout(
        scene={"aspectmode": "data", "xaxis_title": "x (m)", "yaxis_title": "y along crest (m)",
               "zaxis_title": "z (m)", "camera": {"eye": {"x": -1.5, "y": -1.35, "z": 1.0}}},
        margin={"l": 0, "r": 0, "t": 0, "b": 0}, height=620,
        legend={"x": 0.01, "y": 0.99, "bgcolor": "rgba(255,255,255,0.7)"},
    )
    return fig, groups


def map_figure(zones: list[Zone], reference: list[Zone], target: float) -> Any:
    """Porosity by zone, the trainee's beside the reference's, on one colour scale."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    slices = max(z.slice for z in zones) + 1
    layers = max(z.layer for z in zones) + 1
    labels = [f"y {z.y0:.1f}-{z.y1:.1f} m" for z in zones if z.layer == 0]
    names = ["lower" if j == 0 else "upper" if j == layers - 1 else f"layer {j}" for j in range(layers)]
    values = [z.porosity_percent for z in zones + reference]
    spread = max(5.0, max(abs(v - target) for v in values))
    fig = make_subplots(rows=1, cols=2, subplot_titles=("Trainee", "Reference"), horizontal_spacing=0.08)
    for col, zs in ((1, zones), (2, reference)):
        grid = np.full((layers, slices), np.nan)
        for z in zs:
            grid[z.layer, z.slice] = z.porosity_percent
        fig.add_trace(go.Heatmap(z=grid, x=labels, y=names, coloraxis="coloraxis", texttemplate="%{z:.1f}%",
                                 hovertemplate="%{y} layer, %{x}: %{z:.2f}%<extra></extra>"), row=1, col=col)
    fig.update_layout(
        coloraxis={"colorscale": "RdBu", "cmin": target - spread, "cmax": target + spread,
                   "colorbar": {"title": {"text": "porosity %"}}},
        height=300, margin={"l": 60, "r": 20, "t": 40, "b": 40},
    )
    return fig


def _points(points: float) -> str:
    return f"-{points:.1f}" if points >= 0.05 else ("-0.0" if points > 0 else "0")


def _table(rows: list[tuple[str, str]], cls: str = "metrics") -> str:
    body = "".join(f"<tr><th>{html.escape(a)}</th><td>{html.escape(b)}</td></tr>" for a, b in rows)
    return f'<table class="{cls}">{body}</table>'


def build_html(scene: Scene, placed: Placed, report: ScoreReport, title: str = "") -> str:
    """The report page as one HTML string (about 5 MB: plotly's bundle is inline)."""
    import plotly.offline

    view, groups = view_figure(scene, placed, report)
    config = {"displaylogo": False, "responsive": True}
    view_div = view.to_html(full_html=False, include_plotlyjs=False, div_id="view3d", config=config)
    maps_div = map_figure(report.zones, report.reference_zones, report.target_porosity_percent).to_html(
        full_html=False, include_plotlyjs=False, div_id="porosity-map", config=config)

    r = report
    m = r.measures
    stage = f"reference at {r.stage_blocks} blocks"
    metrics = [
        ("Score", f"{r.score:.1f} / 100"),
        ("Progress", f"{r.progress_percent:.1f} % ({r.blocks} of {r.required_blocks} blocks)"),
        ("Quality", f"{r.quality:.1f} % ({r.points:.1f} penalty points)"),
        ("Porosity (exact)", f"{r.porosity_percent:.2f} % ({stage}: {r.reference_porosity_percent:.2f} %)"),
        ("Target porosity", f"{r.target_porosity_percent:g} %"),
        ("Blocks placed / required", f"{r.blocks} / {r.required_blocks}"),
        ("Blocks remaining", str(r.remaining_blocks)),
        ("Out of tolerance", str(len(r.out_of_tolerance))),
        ("Collisions (pairs)", str(len(r.collisions))),
        ("Stable after settle",
         "yes" if r.stable else f"no: {len(r.unstable_ids)} of {r.blocks} blocks moved"),
        ("Poorly interlocked", f"{len(r.interlock.flagged)} ({stage}: {len(r.reference_flagged)})"),
        ("Bare slope and crest", f"{r.coverage.bare_share_percent:.2f} %"),
        ("Finished with the reference's blocks", f"{len(r.added)} added" if r.added else "nothing to add"),
        ("Finished: porosity",
         f"{m.porosity_percent:.2f} % (reference {m.reference_porosity_percent:.2f} %)"),
        ("Finished: poorly interlocked", f"{m.flagged} (reference {m.reference_flagged})"),
        ("Finished: bare slope and crest",
         f"{m.bare_share_percent:.2f} % (reference {m.reference_bare_share_percent:.2f} %)"),
    ]
    if r.elapsed_s is not None:
        rate = r.blocks_per_hour
        metrics.append(("Time", f"{r.elapsed_s:g} s" + (f", {rate:.1f} blocks per hour" if rate else "")
                        + (" (complete)" if r.completion_time_s is not None else "")))
    pen_rows = "".join(
        f"<tr><td>{html.escape(p.name)}</td><td>{html.escape(p.rule)}</td><td>{p.amount:.3g}</td>"
        f"<td>{_points(p.points)}</td></tr>" for p in r.penalties)
    held = r.interlock.by_id()
    faults = []
    if r.out_of_tolerance:
        faults.append(("Out of tolerance", ", ".join(f"{k} ({v:.3f} m3)" for k, v in r.out_of_tolerance)))
    if r.collisions:
        faults.append(("Collisions", ", ".join(f"{c.a}-{c.b} ({c.depth * 1000:.0f} mm)"
                                               for c in r.collisions)))
    unstable = [b for b in r.settle.blocks if not b.stable]
    if unstable:
        faults.append(("Unstable", ", ".join(f"{b.id} ({b.displacement_m:.2f} m, {b.rotation_deg:.0f} deg)"
                                             for b in unstable)))
    if r.interlock.flagged:
        faults.append(("Poorly interlocked", ", ".join(
            f"{k} ({held[k].contact_count} contacts, {len(held[k].neighbours)} neighbours)"
            for k in r.interlock.flagged)))
    toggles = "".join(
        f'<label><input type="checkbox" id="{tid}" data-traces="{html.escape(json.dumps(groups[g]))}" '
        f'checked> {html.escape(label)}</label>' for tid, label, g in TOGGLES)
    heading = html.escape(title or "shoha score")
    rule = r.interlock.rule
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{heading}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.2em; color: #222; }}
header {{ display: flex; align-items: baseline; gap: 1.5em; }}
#score {{ font-size: 3em; font-weight: 700; }}
.parts {{ display: flex; gap: 2em; margin: 0.3em 0 1em; }}
.part {{ border: 1px solid #ccc; border-radius: 6px; padding: 0.4em 0.9em; }}
.part b {{ font-size: 1.6em; }}
.row {{ display: flex; gap: 1.5em; flex-wrap: wrap; }}
.row > div {{ flex: 1 1 28em; }}
table {{ border-collapse: collapse; margin: 0.4em 0; }}
th, td {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }}
th {{ background: #f3f3f3; }}
.toggles label {{ margin-right: 1.2em; }}
.swatch {{ display: inline-block; width: 0.9em; height: 0.9em; border: 1px solid #444; }}
</style>
<script type="text/javascript">{plotly.offline.get_plotlyjs()}</script>
</head>
<body>
<header><span id="score">{r.score:.1f}</span><span>/ 100</span><h1>{heading}</h1></header>
<div class="parts">
<div class="part">Progress <b id="progress">{r.progress_percent:.1f}</b> %
<br><small>{r.blocks} of {r.required_blocks} blocks laid</small></div>
<div class="part">Quality <b id="quality">{r.quality:.1f}</b> %
<br><small>of what is laid: {r.points:.1f} penalty points</small></div>
</div>
<section id="view">
<h2>Layout</h2>
<div class="toggles">{toggles}</div>
<p><span class="swatch" style="background:{COLOURS['protruding']}"></span> out of tolerance
&nbsp;<span class="swatch" style="background:{COLOURS['unstable']}"></span> unstable
&nbsp;<span class="swatch" style="background:{COLOURS['colliding']}"></span> colliding
&nbsp;<span class="swatch" style="background:{COLOURS['block']}"></span> other blocks</p>
{view_div}
</section>
<section id="maps">
<h2>Porosity by zone</h2>
<p>{len({z.slice for z in r.zones})} slices along the crest, lower and upper half of the design height;
red is denser (lower porosity) than the {r.target_porosity_percent:g} % target, blue looser.</p>
{maps_div}
</section>
<div class="row">
<section id="metrics"><h2>Metrics</h2>{_table(metrics)}</section>
<section id="penalties"><h2>How the score is made</h2>
<table><tr><th>penalty</th><th>rule</th><th>counted</th><th>points</th></tr>{pen_rows}</table>
<p>score = progress &times; quality / 100, and quality = 100 &times; 0.99<sup>points</sup>: each penalty
point takes 1 % of the quality that is left (docs/scoring.md). Porosity, interlock and coverage are
judged on the layout finished with the reference's blocks for the places not yet filled. Contact: within
{r.interlock.contact_gap * 100:g} cm; a block is poorly interlocked with fewer than {rule.min_contacts}
contacts (the foundation counts as one) or fewer than {rule.min_neighbours} neighbours within
{r.interlock.neighbour_distance:.2f} m.</p></section>
</div>
<section id="faults"><h2>Blocks to look at</h2>
{_table(faults, "faults") if faults else "<p>None.</p>"}</section>
<script type="text/javascript">
(function () {{
  var gd = document.getElementById("view3d");
  document.querySelectorAll(".toggles input").forEach(function (box) {{
    box.addEventListener("change", function () {{
      Plotly.restyle(gd, {{visible: box.checked}}, JSON.parse(box.dataset.traces));
    }});
  }});
}})();
</script>
</body>
</html>
"""


def write_report(path: str | os.PathLike, scene: Scene, placed: Placed, report: ScoreReport,
                 title: str = "") -> None:
    """Write the report to ``path`` atomically."""
    atomic_write(path, build_html(scene, placed, report, title))

"""The live view of a session: one offline HTML page, drawn by plotly and fed by the WebSocket.

``GET /sessions/{id}/view`` answers this page. Everything it needs comes from
the service itself: plotly's JavaScript bundle from the installed plotly
package (``/static/plotly.js``, as the HTML report inlines it), and the
scene's prisms and the block meshes inside the page. It opens
``/sessions/{id}/events``; the first event holds every block, each later one
the state and the blocks that changed, and the page draws on the next
animation frame. Blocks are coloured as the report colours them
(:data:`optimizer.score.render.COLOURS`): unstable red (from the last score),
out of tolerance or above the crest yellow (the paper's Fig. 11), colliding
orange, the rest grey. World frame, metres.
"""

from __future__ import annotations

import html
import json
from functools import cache
from typing import Any

import numpy as np

from geometry.scene import Scene
from geometry.tolerance import TrapezoidalPrism

from ..score.render import COLOURS
from .bodies import Catalogue


@cache
def plotly_js() -> bytes:
    """plotly's bundle from the installed package: the page asks no other host for anything."""
    from plotly.offline import get_plotlyjs

    return get_plotlyjs().encode()


def _prism(prism: TrapezoidalPrism) -> dict[str, Any]:
    poly = prism.polytope
    return {"vertices": np.round(poly.vertices, 6).tolist(), "faces": poly.faces.tolist(),
            "corners": np.round(prism.corners, 6).tolist()}


def page(scene: Scene, catalogue: Catalogue, session: str, query: str = "") -> str:
    """The view page of ``session`` on ``scene``; ``query`` (``?token=...``) goes on the script's URL."""
    meshes = {}
    for name in sorted(catalogue.names):
        block = catalogue.block(name, "view")
        meshes[name] = {"vertices": np.round(block.vertices, 6).tolist(), "faces": block.faces.tolist()}
    config = {
        "session": session,
        "scene": scene.name,
        "design": _prism(scene.design),
        "tolerance": _prism(scene.tolerance),
        "crest": np.round(scene.crest, 6).tolist(),
        "meshes": meshes,
        "colours": COLOURS,
    }
    data = json.dumps(config).replace("</", "<\\/")
    return (_PAGE.replace("{{title}}", html.escape(f"shoha live: {scene.name}"))
            .replace("{{query}}", html.escape(query)).replace("{{config}}", data))


_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{{title}}</title>
<style>
  body { font-family: system-ui, sans-serif; margin: 0; display: flex; height: 100vh; }
  #side { width: 300px; padding: 12px 16px; background: #f6f6f6; overflow-y: auto; font-size: 14px; }
  #plot { flex: 1; }
  h1 { font-size: 18px; margin: 0 0 8px; }
  table { border-collapse: collapse; width: 100%; }
  td { padding: 3px 0; }
  td.v { text-align: right; font-variant-numeric: tabular-nums; font-weight: 600; }
  .key { display: inline-block; width: 12px; height: 12px; margin-right: 6px; vertical-align: -1px; }
  #status { color: #666; margin-top: 10px; }
  ul { padding-left: 18px; margin: 4px 0; }
</style>
</head>
<body>
<div id="side">
  <h1 id="title"></h1>
  <table>
    <tr><td>blocks</td><td class="v" id="blocks">0</td></tr>
    <tr><td>required</td><td class="v" id="required">0</td></tr>
    <tr><td>remaining</td><td class="v" id="remaining">0</td></tr>
    <tr><td>porosity (exact)</td><td class="v" id="porosity">-</td></tr>
    <tr><td>reference porosity</td><td class="v" id="reference">-</td></tr>
    <tr><td><span class="key" id="key-tolerance"></span>out of tolerance</td>
        <td class="v" id="out-of-tolerance">0</td></tr>
    <tr><td><span class="key" id="key-protruding"></span>above the crest</td>
        <td class="v" id="protruding">0</td></tr>
    <tr><td><span class="key" id="key-colliding"></span>collisions</td>
        <td class="v" id="collisions">0</td></tr>
    <tr><td><span class="key" id="key-unstable"></span>unstable (last score)</td>
        <td class="v" id="unstable">0</td></tr>
    <tr><td>elapsed</td><td class="v" id="elapsed">-</td></tr>
    <tr><td>blocks per hour</td><td class="v" id="per-hour">-</td></tr>
  </table>
  <div id="status">connecting</div>
</div>
<div id="plot"></div>
<script src="/static/plotly.js{{query}}"></script>
<script id="config" type="application/json">{{config}}</script>
<script>
"use strict";
const cfg = JSON.parse(document.getElementById("config").textContent);
const C = cfg.colours;
const blocks = new Map();
let state = null, pending = false, drawn = 0;
document.getElementById("title").textContent = "shoha live: " + cfg.scene;
for (const [id, c] of [["key-tolerance", C.protruding], ["key-protruding", C.protruding],
                       ["key-colliding", C.colliding], ["key-unstable", C.unstable]])
  document.getElementById(id).style.background = c;

function rotate(q, v) {
  const [w, x, y, z] = q, [a, b, c] = v;
  return [
    (1 - 2 * (y * y + z * z)) * a + 2 * (x * y - w * z) * b + 2 * (x * z + w * y) * c,
    2 * (x * y + w * z) * a + (1 - 2 * (x * x + z * z)) * b + 2 * (y * z - w * x) * c,
    2 * (x * z - w * y) * a + 2 * (y * z + w * x) * b + (1 - 2 * (x * x + y * y)) * c];
}

function prismTraces(p, name, colour, opacity) {
  const v = p.vertices, f = p.faces;
  const mesh = {type: "mesh3d", name: name, x: v.map(a => a[0]), y: v.map(a => a[1]), z: v.map(a => a[2]),
    i: f.map(a => a[0]), j: f.map(a => a[1]), k: f.map(a => a[2]), color: colour, opacity: opacity,
    hoverinfo: "name", flatshading: true, showlegend: true};
  const c = p.corners, loop = [0, 1, 2, 3, 0, 4, 5, 6, 7, 4], pts = loop.map(i => c[i]);
  for (const [a, b] of [[1, 5], [2, 6], [3, 7]]) pts.push([null, null, null], c[a], c[b]);
  const edges = {type: "scatter3d", mode: "lines", name: name + " edges", showlegend: false,
    hoverinfo: "skip", x: pts.map(a => a[0]), y: pts.map(a => a[1]), z: pts.map(a => a[2]),
    line: {color: colour, width: 3}};
  return [mesh, edges];
}

const fixed = [...prismTraces(cfg.design, "design prism", C.design, 0.08),
               ...prismTraces(cfg.tolerance, "tolerance prism", C.tolerance, 0.05),
               {type: "scatter3d", mode: "lines", name: "crest", hoverinfo: "skip",
                x: [...cfg.crest.map(a => a[0]), cfg.crest[0][0]],
                y: [...cfg.crest.map(a => a[1]), cfg.crest[0][1]],
                z: [...cfg.crest.map(a => a[2]), cfg.crest[0][2]], line: {color: C.crest, width: 6}}];

const LABELS = {block: "blocks", unstable: "unstable", protruding: "out of tolerance or above the crest",
                colliding: "colliding"};

function statusOf(id) {
  if (state.unstable.includes(id)) return "unstable";
  if (state.out_of_tolerance.some(o => o.id === id) || state.protruding.includes(id)) return "protruding";
  if (state.collisions.some(c => c.a === id || c.b === id)) return "colliding";
  return "block";
}

function draw() {
  pending = false;
  const groups = {block: [], unstable: [], protruding: [], colliding: []};
  const statuses = {};
  for (const b of blocks.values()) {
    const s = statusOf(b.id);
    statuses[b.id] = s;
    groups[s].push(b);
  }
  const traces = [...fixed];
  for (const [s, members] of Object.entries(groups)) {
    if (!members.length) continue;
    const x = [], y = [], z = [], i = [], j = [], k = [], text = [];
    for (const b of members) {
      const m = cfg.meshes[b.type], off = x.length;
      for (const v of m.vertices) {
        const r = rotate(b.quaternion, v);
        x.push(r[0] + b.position[0]); y.push(r[1] + b.position[1]); z.push(r[2] + b.position[2]);
        text.push("block " + b.id);
      }
      for (const f of m.faces) { i.push(f[0] + off); j.push(f[1] + off); k.push(f[2] + off); }
    }
    traces.push({type: "mesh3d", name: LABELS[s] + ": " + members.length, x, y, z, i, j, k, text,
      color: C[s], hovertemplate: "%{text}<extra></extra>", flatshading: true,
      lighting: {ambient: 0.7, diffuse: 0.6, specular: 0.05}, showlegend: true});
  }
  const layout = {uirevision: "keep", margin: {l: 0, r: 0, t: 0, b: 0}, legend: {x: 0, y: 1},
    scene: {aspectmode: "data", xaxis: {title: {text: "x (m)"}}, yaxis: {title: {text: "y along crest (m)"}},
            zaxis: {title: {text: "z (m)"}}, camera: {eye: {x: -1.5, y: -1.35, z: 1.0}}}};
  Plotly.react("plot", traces, layout, {displaylogo: false});
  const set = (id, text) => { document.getElementById(id).textContent = text; };
  set("blocks", state.blocks); set("required", state.required_blocks);
  set("remaining", state.remaining_blocks);
  set("porosity", state.porosity_percent.toFixed(2) + " %");
  set("reference", state.reference ? state.reference.porosity_percent.toFixed(2) + " %" : "not ready");
  set("out-of-tolerance", state.out_of_tolerance.length); set("protruding", state.protruding.length);
  set("collisions", state.collisions.length); set("unstable", state.unstable.length);
  set("elapsed", state.elapsed_s == null ? "-" : state.elapsed_s.toFixed(0) + " s");
  set("per-hour", state.blocks_per_hour == null ? "-" : state.blocks_per_hour.toFixed(1));
  drawn += 1;
  window.shohaView = {version: state.version, statuses: statuses, drawn: drawn};
  document.body.dataset.version = state.version;
}

function connect() {
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  const ws = new WebSocket(scheme + location.host + "/sessions/" + encodeURIComponent(cfg.session)
                           + "/events" + location.search);
  ws.onopen = () => { document.getElementById("status").textContent = "live"; };
  ws.onmessage = (msg) => {
    const ev = JSON.parse(msg.data);
    if (ev.error) { document.getElementById("status").textContent = ev.error; return; }
    if (ev.replaced) blocks.clear();
    for (const b of ev.changed) blocks.set(b.id, b);
    for (const id of ev.removed) blocks.delete(id);
    state = ev;
    if (!pending) { pending = true; requestAnimationFrame(draw); }
  };
  ws.onclose = (e) => {
    document.getElementById("status").textContent = "disconnected" + (e.reason ? ": " + e.reason : "");
    // A session that ends hands over to the next one: /view follows the session started last.
    if (e.code === 1000) setTimeout(() => { location.href = "/view" + location.search; }, 1000);
  };
}
connect();
</script>
</body>
</html>
"""

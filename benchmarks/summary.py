"""The headline figures of the last ``make bench``, gathered from the result files.

``run_all.py`` writes ``benchmarks/results/summary.md`` with this after every
benchmark has run, and the README's performance section (between its
``performance:start`` and ``performance:end`` markers), so that every figure
they give comes from a file a benchmark wrote. It measures nothing itself.

Run::

    .venv/bin/python benchmarks/summary.py     # rewrite summary.md from the results as they are
"""

from __future__ import annotations

import csv
import json

from common import RESULTS, machine_markdown


def rows(stem: str) -> list[dict[str, str]]:
    path = RESULTS / f"{stem}.csv"
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def meta(stem: str) -> dict | None:
    path = RESULTS / f"{stem}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def section(stem: str, heading: str) -> str:
    """A ``## heading`` section of ``results/STEM.md``, without its heading."""
    path = RESULTS / f"{stem}.md"
    if not path.is_file():
        return ""
    text = path.read_text()
    start = text.find(f"## {heading}")
    if start < 0:
        return ""
    body = text[text.index("\n", start) + 1:]
    end = body.find("\n## ")
    body = body[:end if end >= 0 else len(body)]
    machine = body.find("\nMachine: ")  # the machine block at the page's foot
    return body[:machine if machine >= 0 else len(body)].strip()


def f(value: str, digits: int = 3) -> str:
    return f"{float(value):.{digits}g}" if value not in ("", None) else ""


def table(heading: str, columns: str, cells: list[list[object]], note: str | None = None) -> list[str]:
    """A ``## heading``, a Markdown table of ``cells`` and a ``note`` under it; [] when there are no rows.

    ``columns`` holds the column names separated by ``|``. A name starting
    with ``<`` is a left-aligned text column (the ``<`` is not printed); the
    others are right-aligned numbers.
    """
    if not cells:
        return []
    names = [c.strip() for c in columns.strip().strip("|").split("|")]
    align = "|" + "".join("---|" if n.startswith("<") else "---:|" for n in names)
    header = "| " + " | ".join(n.removeprefix("<") for n in names) + " |"
    body = ["| " + " | ".join(str(c) for c in row) + " |" for row in cells]
    return [f"## {heading}", "", header, align, *body, *(["", note] if note else [])]


def porosity_speed() -> list[str]:
    return table("Porosity speed (`porosity_speed.csv`)",
                 "<case | <method | blocks | divisions | median (ms) | target (ms) | <meets",
                 [[r["case"], r["method"], r["blocks"], r["divisions"], f"{float(r['median_ms']):.3f}",
                   r["target_ms"], r["meets_target"]] for r in rows("porosity_speed")])


def paper() -> list[str]:
    out = ["## The paper's Tables V and VI (`paper_tables.md`)", ""]
    for heading in ("Table V: porosity (%)", "Table VI: processing time (s)"):
        out += [f"### {heading}", "", section("paper_tables", heading), ""]
    checks = section("paper_tables", "Checks")
    return out + ["Checks:", "", checks]


def accuracy() -> list[str]:
    return ["## Speed against accuracy (`speed_vs_accuracy.md`, `.png`)", "",
            section("speed_vs_accuracy", "Which method for what"), "",
            "### Against trimesh", "",
            section("speed_vs_accuracy", "Against trimesh, same run, same layouts")]


def collision() -> list[str]:
    return table("Collision checks against naive pairwise FCL (`collision_speed.csv`)",
                 "<layout | blocks | shoha check (ms) | shoha contact (ms) | naive pairwise (ms) | "
                 "naive pairs/s | shoha contact pairs/s | speed-up | <same pairs",
                 [[r["layout"], r["blocks"], f"{1e3 * float(r['shoha_check_s']):.1f}",
                   f"{1e3 * float(r['shoha_contact_s']):.1f}", f"{1e3 * float(r['naive_s']):.1f}",
                   f(r["naive_pairs_per_s"]), f(r["shoha_contact_pairs_per_s"]),
                   f"{float(r['speedup_contact']):.1f}×", r["same_pairs"]] for r in rows("collision_speed")])


def scaling() -> list[str]:
    data = rows("scaling")
    keys = ("exact", "exact_disjoint", "voxel", "collisions", "settle")
    cells: list[list[object]] = [
        [r["blocks"], *(f(r[f"{k}_s"]) for k in keys[:-1]),
         f(r["settle_s"]) + (" (extrapolated)" if r["settle_extrapolated"] == "True" else "")] for r in data]
    if data:
        cells.append(["slope (log-log, 75+)", *(f"{float(data[0][f'{k}_slope']):.2f}" for k in keys)])
    return table("Scaling (`scaling.csv`, `.png`)", "blocks | " + " | ".join(f"{k} (s)" for k in keys), cells)


def settle_speed() -> list[str]:
    slope = (meta("settle_speed") or {}).get("params", {}).get("cost_exponent_reference_75_up")
    return table("Settle speed (`settle_speed.csv`, owned by settle: docs/settle.md)",
                 "<layout | blocks | <scene | 2 s settle, wall (s) | ms per step | µs per step per block",
                 [[r.get("layout", "poured"), r["blocks"], r["scene"], r["full_wall_s"], r["ms_per_step"],
                   r["us_per_step_per_block"]] for r in rows("settle_speed")],
                 None if slope is None else f"Least-squares log-log slope of CPU time against blocks, "
                 f"reference layouts of 75 blocks and more: {slope:.2f} (1 is linear).")


def score_speed() -> list[str]:
    return table("Scoring a 75-block save (`score_speed.csv`)",
                 "<save | score | `score()` median (s) | of which settle (s) | "
                 "`shoha score` process, wall (s) | <under 3 s",
                 [[r["save"], r["score"], f"{float(r['score_median_s']):.2f}", f"{float(r['settle_s']):.2f}",
                   f"{float(r['cli_wall_s']):.2f}", r["under_target"]] for r in rows("score_speed")])


def batch_cluster() -> list[str]:
    data = rows("batch_cluster")
    comp = [r for r in data if r["phase"] == "compare"]
    c = comp[0] if comp else None
    note = (f"Dask rows identical to `--workers 2`: {c['rows_match_pool']} ({c['rows_differing']} differing, "
            f"{c['repeated_items']} repeated)." if c else None)
    return table("A batch of 200 saves (`batch_cluster.csv`)",
                 "<phase | <runner | ran | skipped | errors | wall (s)",
                 [[r["phase"], r["runner"], r["ran"], r["skipped"], r["errors"], r["wall_s"]]
                  for r in data if r["phase"] != "compare"], note)


def optimizer_quality() -> list[str]:
    return table("Optimizer quality against time (`optimizer_quality.csv`, `.png`)",
                 "<method | budget (s) | took (s) | blocks | porosity (%) | error (pp) | violations | <valid",
                 [[r["method"], r["budget_s"], r["seconds"], r["blocks"],
                   f"{float(r['porosity_percent']):.2f}", f"{float(r['porosity_error']):.2f}",
                   r["violations"], r["valid"]]
                  for r in rows("optimizer_quality")])


def optimizer_scaling() -> list[str]:
    data = rows("optimizer_scaling")
    return table("Optimizer run time against block count (`optimizer_scaling.csv`, `.png`)",
                 "<scene | blocks required | placed | wall (s) | beam (s) | anneal (s) | CP-SAT (s) | "
                 "settle (s) | porosity (%) | CP-SAT gap (%) | <valid",
                 [[r["scene"], r["required_blocks"], r["blocks"], r["seconds"], r["beam_s"], r["anneal_s"],
                   r["cpsat_s"], r["settle_s"], f"{float(r['porosity_percent']):.2f}", r["cpsat_gap_percent"],
                   r["valid"]] for r in data],
                 f"Log-log slope of wall time against blocks over the long scenes: "
                 f"{float(data[0]['fitted_slope_long_scenes']):.2f}." if data else None)


def tetrapod_limit() -> list[str]:
    return table("What limits the tetrapod scene (`tetrapod_limit.csv`)",
                 "seed | required | placed | porosity (%) | wall (s) | collisions | out of tolerance | "
                 "<stable | inside share (%) | on the foundation: blocks, inside (%) | "
                 "on blocks: blocks, inside (%) | porosity at the required count (%) | "
                 "inside share needed (%)",
                 [[r["seed"], r["required_blocks"], r["blocks"], f"{float(r['porosity_percent']):.2f}",
                   r["seconds"], r["collisions"], r["out_of_tolerance"], r["stable"],
                   r["inside_share_percent"],
                   f"{r['ground_blocks']}, {r['ground_inside_share_percent']}",
                   f"{r['upper_blocks']}, {r['upper_inside_share_percent']}",
                   r["porosity_at_required_count_percent"], r["inside_share_needed_percent"]]
                  for r in rows("tetrapod_limit")])


def _loss(value: str) -> str:
    """A lost volume (m^3) as written: rounding can leave -0 where nothing is lost."""
    return f"{max(0.0, float(value)):.3f}".rstrip("0").rstrip(".")


def tetrapod_losses() -> list[str]:
    return table("Where the tetrapods' outside volume is (`tetrapod_limit.csv`, `tetrapod_variants.csv`)",
                 "design height (m) | crest width (m) | seed | required | placed | porosity (%) | "
                 "past the crest (m^3) | past the slopes (m^3) | past the ends (m^3) | "
                 "past two at once (m^3) | total (m^3) | most the required count may lose (m^3)",
                 [[r["height_m"], r.get("crest_width_m", ""), r["seed"], r["required_blocks"], r["blocks"],
                   f"{float(r['porosity_percent']):.2f}",
                   *(_loss(r[f"{k}_loss_m3"]) for k in ("crest", "slopes", "ends", "edges", "total")),
                   r["loss_allowed_m3"]]
                  for r in rows("tetrapod_limit") + rows("tetrapod_variants")[1:]],
                 "The last rows are copies of the scene with another design, seed 1; the "
                 "first row of `tetrapod_variants.csv` is seed 1 of the built-in scene.")


def _taller(copies: list[dict[str, str]]) -> str:
    """A sentence on the tallest copy, if it is taller than 4 m: how short of its count it falls."""
    four = [r for r in copies if float(r["height_m"]) == 4.0]
    tall = max(copies, key=lambda r: float(r["height_m"]))
    if not four or float(tall["height_m"]) <= 4.0:
        return ""
    short = int(tall["required_blocks"]) - int(tall["blocks"])
    worst = max(int(r["required_blocks"]) - int(r["blocks"]) for r in four)
    verdict = "further short than" if short > worst else "no further short than"
    return (f" A {float(tall['height_m']):g} m mound, where the pattern lays more layers on the first two, "
            f"places {tall['blocks']} of its {tall['required_blocks']}: {short} short, {verdict} the 4 m "
            f"copies ({worst} at most).")


def _solid_rows() -> list[dict[str, str]]:
    """The fill maps: the built-in scene's, then the copies' (``--variants``)."""
    return rows("tetrapod_solid") + rows("tetrapod_variants_solid")


def _solid_grid(scene: str) -> tuple[list[float], list[float], dict[tuple[float, float], dict]]:
    """Bands of ``tetrapod_solid.csv`` for one scene: |x| edges, z edges, rows by (x, z)."""
    cells = {(float(r["abs_x_from_m"]), float(r["z_from_m"])): r
             for r in _solid_rows() if r["scene"] == scene}
    return sorted({x for x, _ in cells}), sorted({z for _, z in cells}), cells


def _band_shares(xs: list[float], cells: dict[tuple[float, float], dict]) -> list[float]:
    """Solid share (%) of the prism in each band of distance from the axis, all heights together."""
    out = []
    for x in xs:
        column = [c for (cx, _), c in cells.items() if cx == x]
        volume = sum(float(c["prism_m3"]) for c in column)
        out.append(100 * sum(float(c["prism_m3"]) * float(c["solid_percent"]) / 100 for c in column) / volume)
    return out


def _band() -> float:
    """Width (m) of the fill maps' bands."""
    return float((meta("tetrapod_limit") or {}).get("params", {}).get("band_m", 1.0))


def tetrapod_solid() -> list[str]:
    out: list[str] = []
    band = _band()
    for scene in dict.fromkeys(r["scene"] for r in _solid_rows()):
        xs, zs, cells = _solid_grid(scene)
        body = [[f"{z:g} to {z + band:g}"] + [cells[(x, z)]["solid_percent"] if (x, z) in cells else ""
                                               for x in xs] for z in reversed(zs)]
        body.append(["all heights"] + [f"{v:.1f}" for v in _band_shares(xs, cells)])
        source = "tetrapod_solid" if scene == "tetrapod" else "tetrapod_variants_solid"
        out += table(f"How full the `{scene}` prism is, seed 1 (`{source}.csv`)",
                     "<height (m) / distance from the axis (m) | "
                     + " | ".join(f"{x:g} to {x + band:g}" for x in xs),
                     body, "Each cell: the share (%) of the design prism in that band that the blocks fill, "
                     "both sides of the axis together; the target's 50 % porosity asks for 50 % "
                     "on average.") + [""]
    return out[:-1]


def tetrapod_toe() -> list[str]:
    return table("How far out a tetrapod rests on the foundation (`tetrapod_toe.csv`)",
                 "centroid from the axis (m) | orientations that reach it | best inside share (%)",
                 [[r["centroid_at_least_m"], r["orientations"], r["best_inside_share_percent"]]
                  for r in rows("tetrapod_toe")])


def tetrapod_nest() -> list[str]:
    return table("How low a tetrapod rests on the first layer (`tetrapod_nest.csv`)",
                 "<hanging | drops | first layer's top (m) | lowest top (m) | median top (m) | "
                 "design crest (m) | inside share at the crest: median, 99th percentile, best (%)",
                 [[r["family"], r["drops"], r["first_layer_top_m"], r["lowest_top_m"], r["median_top_m"],
                   r["design_crest_m"],
                   ", ".join(r[k] for k in ("median_inside_share_percent", "p99_inside_share_percent",
                                            "best_inside_share_percent"))]
                  for r in rows("tetrapod_nest")])


def tetrapod_release() -> list[str]:
    def dash(r: dict[str, str], key: str) -> str:
        return r[key] or "-"

    return table("Crane drops released and settled (`tetrapod_release.csv`)",
                 "<where | x from the axis (m) | drops | lowest top at first contact (m) | "
                 "at rest and valid | lowest top (m) | median top (m) | design crest (m) | "
                 "inside share: median, best (%)",
                 [[r["place"], f"{r['x_from_m']} to {r['x_to_m']}", r["drops"],
                   r["first_contact_lowest_top_m"], r["at_rest_valid"], dash(r, "lowest_top_m"),
                   dash(r, "median_top_m"), r["design_crest_m"],
                   f"{dash(r, 'median_inside_share_percent')}, {dash(r, 'best_inside_share_percent')}"]
                  for r in rows("tetrapod_release")])


def tetrapod_release_greedy() -> list[str]:
    return table("A second layer of released drops (`tetrapod_release_greedy.csv`)",
                 "blocks on the foundation | released drops per block | placed / required | "
                 "porosity (%) | upper blocks inside (%) | <settled whole",
                 [[g["ground_blocks"], g["candidates_per_block"], f"{g['blocks']} / {g['required_blocks']}",
                   g["porosity_percent"], g["upper_inside_share_percent"], _stable(g)]
                  for g in rows("tetrapod_release_greedy")])


def tetrapod_upper_bound() -> list[str]:
    return table("CP-SAT's bound on the blocks over seed 1's first layer (`tetrapod_upper_bound.csv`, "
                 "`--bound`)",
                 "blocks on the foundation | blocks over them | candidates in the zone | "
                 "at least the floor | conflicts | CP-SAT | mean inside needed (%) | "
                 "mean inside at most (%) | best candidate (%)",
                 [[b["ground_blocks"], b["upper_blocks"], b["candidates_in_zone"],
                   f"{b['candidates_at_least_floor']} (floor {b['floor_percent']} %)", b["conflicts"],
                   b["cpsat_status"], b["upper_inside_needed_percent"], b["upper_inside_bound_percent"],
                   b["best_candidate_inside_percent"]] for b in rows("tetrapod_upper_bound")])


def tetrapod_layer() -> list[str]:
    return table("The one-layer tetrapod scene (`tetrapod_layer.csv`, `tetrapod_layer_variants.csv`)",
                 "<scene | crest width (m) | seed | required | placed | porosity (%) | wall (s) | "
                 "collisions | out of tolerance | <stable | CP-SAT gap (%) | inside share (%)",
                 [[f"`{r['scene']}`", r["crest_width_m"], r["seed"], r["required_blocks"], r["blocks"],
                   f"{float(r['porosity_percent']):.2f}", r["seconds"], r["collisions"],
                   r["out_of_tolerance"], r["stable"], r["cpsat_gap_percent"], r["inside_share_percent"]]
                  for r in rows("tetrapod_layer") + rows("tetrapod_layer_variants")],
                 "The first rows are the built-in `tetrapod-layer` scene; the rest "
                 "(`tetrapod_layer_variants.csv`) are copies of it with a narrower crest.")


def tetrapod_interior() -> list[str]:
    return table("The optimizer's two-layer pattern away from slopes and ends (`tetrapod_interior.csv`)",
                 "window up to | height (m) | lattice cells | blocks on the patch | collisions | "
                 "area per block (m²) | upper layer tops (m) | solid (%) | porosity (%)",
                 [[r["up_to"], r["height_m"], r["cells"], r["patch_blocks"], r["collisions"],
                   r["area_per_block_m2"], r["upper_tops_m"], r["solid_percent"], r["porosity_percent"]]
                  for r in rows("tetrapod_interior")])


def _pairs(count: str) -> str:
    return "no two interpenetrating" if int(count) == 0 else f"{count} pairs interpenetrating"


def _stable(row: dict[str, str]) -> str:
    return "stable" if row["stable"] == "True" else "not stable"


def run_times() -> list[str]:
    return table("`make bench` wall time (`run_all.csv`)", "<script | wall (s) | exit",
                 [[r["script"], f"{float(r['wall_s']):.1f}", r["exit_status"]] for r in rows("run_all")])


def main() -> None:
    parts = [["# Benchmark summary", "",
              "Gathered by `benchmarks/summary.py` from the files in this folder; each figure is a "
              "median of repeated calls on the machine named at the foot."]]
    parts += [porosity_speed(), paper(), accuracy(), collision(), scaling(), settle_speed(), score_speed(),
              batch_cluster(), optimizer_quality(), optimizer_scaling(), tetrapod_layer(), tetrapod_limit(),
              tetrapod_losses(),
              tetrapod_solid(), tetrapod_toe(), tetrapod_nest(), tetrapod_interior(), tetrapod_release(),
              tetrapod_release_greedy(), tetrapod_upper_bound(), run_times()]
    text = "\n\n".join("\n".join(p) for p in parts if p)
    m = meta("run_all") or meta("porosity_speed")
    if m:
        text += "\n\n" + machine_markdown(m)
    (RESULTS / "summary.md").write_text(text.rstrip() + "\n")
    print(f"wrote {RESULTS / 'summary.md'}")
    write_readme()


# --- README ------------------------------------------------------------------------------

README = RESULTS.parents[1] / "README.md"
START, END = "<!-- performance:start -->", "<!-- performance:end -->"


def _ratio_range(values: list[float]) -> str:
    return f"{min(values):.0f}× to {max(values):.0f}×"


def readme_block() -> list[str]:
    """The README's performance section, every figure read from a result file."""
    out = []
    m = meta("run_all") or meta("porosity_speed")
    if m:
        mach = m["machine"]
        out += [f"Measured by `make bench` on {mach['cpu_model']}, {mach['cores']} cores, Python "
                f"{mach['python']}, at shoha {mach['commit']} on {mach['date'][:10]} (1-minute load "
                f"{mach['load_average'][0]} at the start). Every figure below is read from a file in "
                "[`benchmarks/results/`](benchmarks/results) by `benchmarks/summary.py`; "
                "[`summary.md`](benchmarks/results/summary.md) has them all and "
                "[docs/benchmarks.md](docs/benchmarks.md) says how each was taken.", ""]
    pt = rows("paper_tables")
    if pt:
        out += ["**The paper's Tables V and VI, reproduced** (`benchmarks/paper_tables.py`: 9, 17 and 25 "
                "blocks wholly inside `mini`, porosity and seconds):", "",
                "*Table V, porosity (%):*", "", section("paper_tables", "Table V: porosity (%)"), "",
                "*Table VI, processing time (s):*", "",
                # Its closing paragraph on the speed-up is said below, with exact beside it.
                "\n".join(line for line in section("paper_tables", "Table VI: processing time (s)")
                          .splitlines() if not line.startswith("Speed-up of shoha")).strip(), ""]
        ratios = [float(r["paper_seconds"]) / float(r["seconds"]) for r in pt if r["paper_seconds"]]
        exact = [float(r["seconds"]) for r in pt if r["method"] == "exact"]
        fastest = min(float(r["paper_seconds"]) for r in pt if r["paper_seconds"])
        out += [f"shoha's `voxel-any`, the paper's own rule at the paper's divisions, takes "
                f"{_ratio_range(ratios)} less time than Table VI; `exact`, with no voxel error at all, "
                f"takes {1e3 * min(exact):.1f}-{1e3 * max(exact):.1f} ms, "
                f"{fastest / max(exact):.0f}× less than the paper's fastest entry. The hardware differs: "
                "the paper ran in Unity on a PC it does not describe, we ran on the shared virtual "
                "machine named above, so these ratios mix machine and method. Most of the gap is "
                "the method: the paper calls `Physics.OverlapBox` once per voxel (8 million calls at "
                "200 divisions, hence its time grows with the divisions cubed), while shoha crosses each "
                "convex piece with the voxel columns under it, and `exact` needs no grid.", ""]
    tr = rows("speed_vs_accuracy_trimesh")
    if tr:
        same = [float(r["ratio_same_rule"]) for r in tr if r["ratio_same_rule"]]
        eq = [float(r["ratio_equal_accuracy"]) for r in tr]
        out += ["**Against trimesh** (`speed_vs_accuracy_trimesh.csv`, same run, same layouts): "
                f"`Trimesh.contains` on voxel centres, the same rule as shoha's `voxel`, is "
                f"{_ratio_range(same)} slower than `voxel` at the same divisions; at equal or better "
                f"accuracy, shoha's fastest method is {_ratio_range(eq)} faster than either of trimesh's "
                "voxelizers.", ""]
    out += ["| what | measured | target | file |", "|---|---:|---:|---|"]
    ps = rows("porosity_speed")

    def ps_ms(case: str, method: str, div: str = "") -> float | None:
        for r in ps:
            if r["case"].startswith(case) and r["method"] == method and r["divisions"] == div:
                return float(r["median_ms"])
        return None

    for label, args, target in (
            ("`exact`, 75-block layout, with the overlap search", ("exact, overlap", "exact"), "20 ms"),
            ("`voxel`, 25 blocks, 200 divisions (paper: 32.89 s)", ("full", "voxel", "200"), "500 ms"),
            ("move of one block, exact tracker (the optimizer's)", ("incremental", "exact"), "2 ms"),
            ("move of one block, voxel tracker, 200 divisions", ("incremental", "voxel", "200"), "2 ms")):
        v = ps_ms(*args)
        if v is not None:
            out.append(f"| {label} | {v:.3g} ms | {target} | `porosity_speed.csv` |")
    ss = [r for r in rows("settle_speed") if r.get("layout", "reference") == "reference"]
    for r in ss:
        if r["blocks"] == "75":
            out.append(f"| physics settle, 75 blocks, 2 s simulated | {float(r['full_wall_s']):.2f} s | "
                       "2 s | `settle_speed.csv` |")
    slope = (meta("settle_speed") or {}).get("params", {}).get("cost_exponent_reference_75_up")
    if slope is not None:
        out.append(f"| settle cost against blocks, 75-1000, log-log slope | {slope:.2f} | about 1 | "
                   "`settle_speed.json` |")
    sc = rows("score_speed")
    if sc:
        worst = max(float(r["cli_seconds"]) for r in sc)
        out.append(f"| `shoha score`, 75-block save, settle included (slowest of {len(sc)} saves) | "
                   f"{worst:.2f} s | 3 s | `score_speed.csv` |")
    cs = rows("collision_speed")
    big = [r for r in cs if r["blocks"] == "1000"]
    if big:
        out.append(f"| collision check, 1000 blocks, against naive pairwise FCL | "
                   f"{min(float(r['speedup_contact']) for r in big):.1f}× faster | | `collision_speed.csv` |")
    os_ = rows("optimizer_scaling")
    for r in os_:
        if r["scene"] in ("mini", "full"):
            out.append(f"| `shoha optimize {r['scene']}` ({r['required_blocks']} blocks), seed 1 | "
                       f"{float(r['seconds']):.0f} s, {r['blocks']} placed, "
                       f"{float(r['porosity_percent']):.2f} %, "
                       f"CP-SAT gap {r['cpsat_gap_percent']} %, valid {r['valid']} | "
                       f"{'120 s' if r['scene'] == 'mini' else '20 min'} | `optimizer_scaling.csv` |")
    if os_:
        out.append(f"| optimizer time against blocks, log-log slope over the long scenes | "
                   f"{float(os_[0]['fitted_slope_long_scenes']):.2f} | about 1 | `optimizer_scaling.csv` |")
    bc = [r for r in rows("batch_cluster") if r["phase"] != "compare"]
    if bc:
        pool = next((r for r in bc if r["phase"] == "pool"), None)
        dask = sum(float(r["wall_s"]) for r in bc if r["phase"].startswith("dask"))
        if pool:
            out.append(f"| `shoha batch score`, 200 saves: `--workers 2` / 2-worker Dask cluster, killed "
                       f"half-way and resumed | {float(pool['wall_s']):.0f} s / {dask:.0f} s | | "
                       "`batch_cluster.csv` |")
    rt = [r for r in rows("run_all") if r["script"] == "TOTAL"]
    if rt:
        out.append(f"| `make bench`, every script | {float(rt[0]['wall_s']) / 60:.1f} min | 30 min | "
                   "`run_all.csv` |")
    out += ["", "Charts: [speed against accuracy](benchmarks/results/speed_vs_accuracy.png), "
            "[scaling](benchmarks/results/scaling.png), [settle](benchmarks/results/settle_speed.png), "
            "[optimizer quality against time](benchmarks/results/optimizer_quality.png), "
            "[optimizer scaling](benchmarks/results/optimizer_scaling.png)."]
    return out


def _listed(vals: list[str]) -> str:
    return ", ".join(vals[:-1]) + " and " + vals[-1] if len(vals) > 1 else "".join(vals)


def layer_block() -> list[str]:
    """The README's paragraph on the one-layer tetrapod scene, read from ``tetrapod_layer.csv``."""
    from geometry.scene import load_scene

    runs = rows("tetrapod_layer")
    if not runs:
        return []
    r0, target = runs[0], load_scene("tetrapod-layer").target_porosity
    met = all(int(r["blocks"]) == int(r["required_blocks"]) and int(r["collisions"]) == 0
              and int(r["out_of_tolerance"]) == 0 and r["stable"] == "True"
              and abs(float(r["porosity_percent"]) - target) <= 1.0 for r in runs)
    seeds = _listed([r["seed"] for r in runs])
    line = (f"- **One layer of tetrapods {'meets' if met else 'misses'} its target.** On the built-in "
            f"`tetrapod-layer` scene (H = 2 m tetrapods in one layer: a {float(r0['height_m']):g} m mound "
            f"with a {float(r0['crest_width_m']):g} m crest, {r0['required_blocks']} required at "
            f"{target:g} %), `shoha optimize tetrapod-layer` ")
    if met:
        line += (f"places all {r0['required_blocks']} blocks for seeds {seeds}, valid (no collisions, none "
                 f"out of tolerance, stable), at ")
    else:
        line += (f"places {_listed([r['blocks'] for r in runs])} blocks for seeds {seeds} "
                 f"({_listed([r['collisions'] for r in runs])} collisions, "
                 f"{_listed([r['out_of_tolerance'] for r in runs])} out of tolerance, "
                 f"{_listed([_stable(r) for r in runs])}) at ")
    line += (f"{_listed([format(float(r['porosity_percent']), '.2f') for r in runs])} % porosity in "
             f"{_listed([r['seconds'] for r in runs])} s, CP-SAT gap at most "
             f"{max(float(r['cpsat_gap_percent']) for r in runs):.0e} % (`benchmarks/tetrapod_limit.py`).")
    copies = rows("tetrapod_layer_variants")
    if copies:
        line += (" A narrower crest leaves less interior, where the lattice packs densely, to make up for "
                 "the slopes and toes, which hold little: with seed 1, a crest of "
                 + "; ".join(f"{float(r['crest_width_m']):g} m places {r['blocks']} of "
                             f"{r['required_blocks']} ({float(r['porosity_percent']):.1f} %)" for r in copies)
                 + ".")
    return [line]


def tetrapod_block() -> list[str]:
    """The README's paragraph on the tetrapod scene's limit, every figure read from a result file."""
    runs, toe = rows("tetrapod_limit"), rows("tetrapod_toe")
    if not runs or not toe:
        return []
    r0 = runs[0]

    def each(key: str, digits: int | None = None) -> str:
        return _listed([r[key] if digits is None else f"{float(r[key]):.{digits}f}" for r in runs])

    near = [t for t in toe if t["best_inside_share_percent"] not in ("", None)
            and float(t["best_inside_share_percent"]) < float(r0["inside_share_needed_percent"])]
    required = float(r0["required_blocks"])
    full = all(float(r["blocks"]) >= required for r in runs)
    if full:
        head = (f"- **In two layers, tetrapods reach their count, not their porosity.** On the built-in "
                f"`tetrapod` scene (H = 2 m tetrapods, a 3.5 m mound, {required:.0f} required at 50 %), "
                f"`shoha optimize tetrapod` places all {required:.0f} blocks for seeds {each('seed')}, "
                f"valid, at {each('porosity_percent', 2)} % porosity: more than 1 point above the target")
        then = "so the full count gives"
    else:
        head = (f"- **In two layers, tetrapods fall short of their count.** On the built-in `tetrapod` "
                f"scene (H = 2 m tetrapods, a 3.5 m mound, {required:.0f} required at 50 %), "
                f"`shoha optimize tetrapod` places {each('blocks')} blocks for seeds {each('seed')} "
                f"({each('porosity_percent', 1)} %): valid otherwise, and it says so in plain words")
        then = "so even the full count would give"
    out = [*layer_block(), head + " (`benchmarks/tetrapod_limit.py`; tables in "
           "[`summary.md`](benchmarks/results/summary.md)).",
           f"  With the count fixed, porosity is 1 − N·V·f / V_B, where f is the share of the blocks' "
           f"volume inside the design prism; {r0['required_blocks']} blocks come within 1 point of 50 % "
           f"only if f ≥ {float(r0['inside_share_needed_percent']):.1f} %. The layouts have f = "
           f"{each('inside_share_percent', 1)} %, {then} "
           f"{each('porosity_at_required_count_percent', 1)} %. Blocks on the foundation are "
           f"{each('ground_inside_share_percent', 1)} % inside; blocks resting on them, "
           f"{each('upper_inside_share_percent', 1)} %: the second layer nests into the first but "
           "still stands above the design crest, in the tolerance zone."]
    nest = rows("tetrapod_nest")
    if nest:
        n0 = nest[0]
        low = min(float(r["lowest_top_m"]) for r in nest)
        best = max(nest, key=lambda r: float(r["best_inside_share_percent"]))
        p99 = max(float(r["p99_inside_share_percent"]) for r in nest)
        first, crest = float(n0["first_layer_top_m"]), float(n0["design_crest_m"])
        out.append(f"  A tetrapod lowered onto the first layer, whose tops are at {first:.2f} m, "
                   f"rests with its top at {low:.2f} m at the lowest ({n0['drops']} random drops "
                   f"in each hanging and in free orientation), above the {crest:.1f} m design crest. "
                   f"Over the middle of the crest, where only the crest cuts it, at most "
                   f"{float(best['best_inside_share_percent']):.1f} % of such a block is inside "
                   f"({best['family']} hanging; 99th percentile over all hangings {p99:.1f} %), "
                   f"while with the blocks on the foundation as laid, the blocks on them would need "
                   f"{each('upper_inside_share_needed_percent', 1)} % on average.")
    release = {r["place"]: r for r in rows("tetrapod_release")}
    if "crest" in release and "toes" in release:
        c, t = release["crest"], release["toes"]
        seconds = float(c["seconds_simulated"])
        out.append(f"  Settling after release does not close the gap. The same kind of drops, released and "
                   f"settled for {seconds:g} s with only the dropped block free (MuJoCo): over the crest, "
                   f"onto seed 1's blocks on the foundation, {c['at_rest_valid']} of {c['drops']} come to "
                   f"rest valid, the lowest with its top at {float(c['lowest_top_m']):.2f} m "
                   f"(at first contact {float(c['first_contact_lowest_top_m']):.2f} m), and at most "
                   f"{float(c['best_inside_share_percent']):.1f} % inside (median "
                   f"{float(c['median_inside_share_percent']):.1f} %); at the toes, "
                   f"{float(t['x_from_m']):g} to {float(t['x_to_m']):g} m from the axis, onto seed 1's "
                   f"whole layout, {t['at_rest_valid']} of {t['drops']} come to rest inside the "
                   "tolerance zone.")
    greedy = rows("tetrapod_release_greedy")
    if greedy:
        g = greedy[0]
        out[-1] += (f" A second layer of such blocks, each the one of {g['candidates_per_block']} released "
                    f"drops with the most volume inside, on seed 1's {g['ground_blocks']} blocks on the "
                    f"foundation, places {g['blocks']} of {g['required_blocks']} at "
                    f"{float(g['porosity_percent']):.1f} % ({_stable(g)} when settled whole): "
                    "fewer than the pattern's second layer.")
    bound = rows("tetrapod_upper_bound")
    if bound:
        b = bound[0]
        out.append(f"  CP-SAT bounds it over a candidate set: with seed 1's {b['ground_blocks']} blocks "
                   f"on the foundation as laid, the other {b['upper_blocks']} blocks need "
                   f"{float(b['upper_inside_needed_percent']):.1f} % inside on average; over "
                   f"{b['candidates_in_zone']} candidates in the tolerance zone "
                   f"(a {float(b['grid_step_m']):g} m grid, {b['orientations']} orientations, each lowered "
                   "onto those blocks alone, none required to stand), no "
                   f"{b['upper_blocks']} of them that do not interpenetrate average more than "
                   f"{float(b['upper_inside_bound_percent']):.1f} % (CP-SAT's proven bound"
                   + ("" if b["cpsat_status"] == "OPTIMAL" else ", the search stopped short of optimality")
                   + f"; a block under {float(b['floor_percent']):g} % counted as "
                   f"{float(b['floor_percent']):g} %). With this first layer the target is out of reach "
                   "over that candidate set.")
    tall = rows("tetrapod_variants")
    if "crest_loss_m3" in r0:
        out.append(f"  Of the {float(r0['total_loss_m3']):.1f} m³ of seed {r0['seed']}'s blocks outside the "
                   f"design prism, {float(r0['crest_loss_m3']):.1f} m³ is above the crest, and the "
                   f"{r0['required_blocks']} blocks may lose at most {float(r0['loss_allowed_m3']):.1f} m³.")
    if len(tall) > 1 and all("crest_width_m" in r for r in tall):
        parts = [f"{float(r['height_m']):g} m high and {float(r['crest_width_m']):g} m wide: "
                 f"{r['blocks']} of {r['required_blocks']} placed, {float(r['porosity_percent']):.1f} %, "
                 f"{max(0.0, float(r['crest_loss_m3'])):.1f} m³ above the crest" for r in tall[1:]]
        line = ("  Another design does not help: the same pipeline (seed 1) on copies of the scene "
                "gives " + "; ".join(parts) + ". A 4 m mound takes the second layer under its crest, "
                "and the blocks placed lose less volume than the required count may: what is missing "
                "is the count. Its slopes hold fewer blocks than it requires, and a wider crest adds "
                "about as many blocks as it requires.")
        line += _taller(tall[1:])
        if all("time_limit_s" in r for r in tall[1:]):
            limits = ", ".join(f"{float(r['time_limit_s']):g}" for r in tall[1:])
            line += (" Each copy's time limit is the built-in scene's scaled by its required count "
                     f"({limits} s).")
        out.append(line)
    xs, _, cells = _solid_grid("tetrapod")
    if cells:
        shares = _band_shares(xs, cells)
        band = _band()
        empty = next((x for x, v in zip(xs, shares, strict=True) if v < 1.0), None)
        line = (f"  Seed 1's blocks fill {', '.join(f'{v:.0f}' for v in shares)} % of the `tetrapod` prism "
                f"in {band:g} m bands from the axis outwards, where the target asks for 50 % on average")
        if empty is not None and toe:
            base = float(toe[0]["design_base_half_width_m"])
            line += (f": no block fills any of it beyond {empty:g} m from the axis, though the design "
                     f"prism's base runs to {base:.2f} m (the toes, below)")
        out.append(line + ".")
    interior = {r["up_to"]: r for r in rows("tetrapod_interior")}
    if "design crest" in interior:
        d = interior["design crest"]
        line = (f"  Away from the slopes and ends the block packs denser than the target asks: the "
                f"optimizer's own two-layer pattern, laid in crane order on a patch of "
                f"{d['patch_blocks']} blocks ({_pairs(d['collisions'])}), fills "
                f"{float(d['solid_percent']):.1f} % of a window of {d['cells']} whole lattice cells from "
                f"the foundation up to the {float(d['height_m']):g} m design crest "
                f"({float(d['porosity_percent']):.1f} % porosity)")
        top = interior.get("upper layer's top")
        if top:
            line += (f", and {float(top['solid_percent']):.1f} % up to its upper layer's top at "
                     f"{float(top['height_m']):g} m")
        out.append(line + ". The target is not out of reach for want of packing density: in the scene, "
                   "the required count must spread over slopes and toes that hold little (the bands "
                   "above), and the blocks resting on the first layer stand above the crest.")
    if near:
        t = near[0]
        samples = (meta("tetrapod_toe") or {}).get("params", {}).get("toe_samples", "many")
        out.append(f"  At the toes, no tetrapod resting on the foundation with its centroid "
                   f"{float(t['centroid_at_least_m']):.1f} m or more from the axis is "
                   f"{float(r0['inside_share_needed_percent']):.1f} % inside (best "
                   f"{float(t['best_inside_share_percent']):.1f} % over {samples} random orientations), "
                   f"and none of them reaches past {float(t['reach_m']):.2f} m inside the tolerance zone, "
                   f"while the design prism's base runs to {float(t['design_base_half_width_m']):.2f} m. "
                   "The Shake Block's `mini` and `full` reach their counts (above).")
    return out


BLOCKS = ((START, END, readme_block), ("<!-- tetrapod:start -->", "<!-- tetrapod:end -->", tetrapod_block))


def write_readme() -> None:
    """Replace the README's text between each pair of markers with the block made for it."""
    text = README.read_text()
    for start, end, make in BLOCKS:
        if start not in text or end not in text:
            print(f"README has no {start} ... {end} markers; left alone")
            continue
        head, rest = text.split(start, 1)
        tail = rest.split(end, 1)[1]
        body = "\n".join(make()).strip()
        text = f"{head}{start}\n{body}\n{end}{tail}"
    README.write_text(text)
    print(f"wrote the generated sections of {README}")


if __name__ == "__main__":
    main()

"""``shoha score``: a trainee's save scored against the reference (docs/scoring.md)."""

from __future__ import annotations

import time
from pathlib import Path

import click

from geometry.errors import InputError

from .common import check_out, emit, json_option, parse_origin, save_options


@click.command("score")
@click.argument("save")
@click.option("--reference", required=True, help="The reference layout (shoha-layout/1).")
@save_options
@click.option("--scene", "scene_name", default=None, help="Scene, instead of the save's own.")
@click.option("--seconds", type=float, default=2.0, show_default=True,
              help="Simulated seconds of the stability settle.")
@click.option("--html", "html_out", default=None, help="Write the report: one self-contained HTML file.")
@json_option
def score_cmd(save: str, reference: str, source: str, block_type: str, origin: str,
              scene_name: str | None, seconds: float, html_out: str | None, as_json: bool) -> None:
    """Score a trainee's save against the reference layout, out of 100.

    The score is the share of the required blocks laid (progress) times the
    quality of what is laid; each penalty point takes 1 % of the quality
    that is left (docs/scoring.md). Points are for blocks out of tolerance,
    collisions and unstable blocks, and for porosity, poor interlock and bare
    surface worse than the reference's at the same stage. Block times in the
    save (time_s, elapsed_s) give the completion time and blocks per hour.
    """
    from geometry.layout import read_layout
    from optimizer.batch import load_save
    from optimizer.score import Reference, check_same_scene, score
    from optimizer.score.report import write_report
    from settle.base import MAX_SECONDS

    start = time.perf_counter()
    if not 0 < seconds <= MAX_SECONDS:
        raise InputError(f"--seconds {seconds}: must be more than 0 and at most {MAX_SECONDS:g}")
    html_path = check_out(html_out, (".html", ".htm")) if html_out is not None else None
    ref_layout = read_layout(reference)
    ref_scene = ref_layout.load_scene()
    layout, scene = load_save(save, source, ref_layout.scene, ref_scene, block_type, parse_origin(origin),
                              scene_name)
    check_same_scene(scene, ref_scene, save)
    placed = layout.placed()
    ref = Reference.of(ref_scene, ref_layout.placed())
    result = score(scene, placed, ref, seconds=seconds, elapsed_s=layout.session_seconds())
    if html_path is not None:
        title = f"{Path(save).name} against {Path(reference).name}"
        write_report(html_path, scene, placed, result, title=title)
    payload = result.to_dict()
    payload["save"] = save
    payload["reference"] = reference
    if html_path is not None:
        payload["html"] = str(html_path)
    payload["seconds"] = time.perf_counter() - start
    human = result.summary() + (f"\nwrote {html_path}" if html_path is not None else "")
    emit(payload, as_json, human)

"""The headline figures of the last ``make bench``, gathered from the result files.

``run_all.py`` writes ``benchmarks/results/summary.md`` with this after every
benchmark has run; docs/benchmarks.md and the README quote that page, so that
every figure they give comes from a file a benchmark wrote. It measures
nothing itself.

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


def porosity_speed() -> list[str]:
    out = ["## Porosity speed (`porosity_speed.csv`)", "",
           "| case | method | blocks | divisions | median (ms) | target (ms) | meets |",
           "|---|---|---:|---:|---:|---:|---|"]
    for r in rows("porosity_speed"):
        out.append(f"| {r['case']} | {r['method']} | {r['blocks']} | {r['divisions']} | "
                   f"{float(r['median_ms']):.3f} | {r['target_ms']} | {r['meets_target']} |")
    return out


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
    out = ["## Collision checks against naive pairwise FCL (`collision_speed.csv`)", "",
           "| layout | blocks | shoha check (ms) | shoha contact (ms) | naive pairwise (ms) | "
           "naive pairs/s | shoha contact pairs/s | speed-up | same pairs |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows("collision_speed"):
        out.append(f"| {r['layout']} | {r['blocks']} | {1e3 * float(r['shoha_check_s']):.1f} | "
                   f"{1e3 * float(r['shoha_contact_s']):.1f} | {1e3 * float(r['naive_s']):.1f} | "
                   f"{f(r['naive_pairs_per_s'])} | {f(r['shoha_contact_pairs_per_s'])} | "
                   f"{float(r['speedup_contact']):.1f}× | {r['same_pairs']} |")
    return out


def scaling() -> list[str]:
    data = rows("scaling")
    if not data:
        return []
    keys = ("exact", "exact_disjoint", "voxel", "collisions", "settle")
    out = ["## Scaling (`scaling.csv`, `.png`)", "",
           "| blocks | " + " | ".join(f"{k} (s)" for k in keys) + " |",
           "|---:|" + "---:|" * len(keys)]
    for r in data:
        settle = f(r["settle_s"]) + (" (extrapolated)" if r["settle_extrapolated"] == "True" else "")
        out.append(f"| {r['blocks']} | " + " | ".join(f(r[f"{k}_s"]) for k in keys[:-1]) + f" | {settle} |")
    out.append("| slope (log-log, 75+) | " + " | ".join(f"{float(data[0][f'{k}_slope']):.2f}" for k in keys)
               + " |")
    return out


def settle_speed() -> list[str]:
    data = rows("settle_speed")
    if not data:
        return []
    out = ["## Settle speed (`settle_speed.csv`, owned by settle: docs/settle.md)", "",
           "| blocks | scene | 2 s settle, wall (s) | ms per step |", "|---:|---|---:|---:|"]
    out += [f"| {r['blocks']} | {r['scene']} | {r['full_wall_s']} | {r['ms_per_step']} |" for r in data]
    return out


def run_times() -> list[str]:
    data = rows("run_all")
    if not data:
        return []
    out = ["## `make bench` wall time (`run_all.csv`)", "", "| script | wall (s) | exit |", "|---|---:|---:|"]
    out += [f"| {r['script']} | {float(r['wall_s']):.1f} | {r['exit_status']} |" for r in data]
    return out


def main() -> None:
    parts = [["# Benchmark summary", "",
              "Gathered by `benchmarks/summary.py` from the files in this folder; each figure is a "
              "median of repeated calls on the machine named at the foot."]]
    parts += [porosity_speed(), paper(), accuracy(), collision(), scaling(), settle_speed(), run_times()]
    text = "\n\n".join("\n".join(p) for p in parts if p)
    m = meta("run_all") or meta("porosity_speed")
    if m:
        text += "\n\n" + machine_markdown(m)
    (RESULTS / "summary.md").write_text(text.rstrip() + "\n")
    print(f"wrote {RESULTS / 'summary.md'}")


if __name__ == "__main__":
    main()

"""``shoha optimize --keep``: a layout already begun, completed around its blocks (issue 24)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from geometry.layout import Layout, Placement, read_layout, write_layout
from geometry.pose import Pose
from geometry.scene import load_scene
from geometry.tolerance import out_of_tolerance
from optimizer.api import optimize
from tests.conftest import ROOT, shoha
from tests.test_score_cli import REFERENCE, to_unity_save


def _json(result):
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
    """The first 30 blocks of the seed-1 mini reference, as the layout file a survey writes."""
    ref = read_layout(REFERENCE)
    path = tmp_path_factory.mktemp("keep") / "partial.json"
    write_layout(Layout("mini", ref.blocks[:30]), path)
    return path


@pytest.mark.parametrize("how", ["layout", "unity"])
def test_kept_blocks_are_written_byte_for_byte(tmp_path, partial, how):
    """The completed layout starts with the kept blocks: same ids, same numbers, to the last bit."""
    keep = partial
    if how == "unity":
        keep = tmp_path / "save.json"
        keep.write_text(json.dumps(to_unity_save(read_layout(partial), (0.0, 0.0, 0.0))))
    out = tmp_path / "out.json"
    d = _json(shoha("optimize", "mini", "--keep", str(keep), "--out", str(out), "--seed", "1",
                    "--time-limit", "15", "--json"))
    written = json.loads(out.read_text())["blocks"]
    given = json.loads(partial.read_text())["blocks"]
    assert [json.dumps(b, sort_keys=True) for b in written[:30]] == [json.dumps(b, sort_keys=True)
                                                                     for b in given]
    ids = [b["id"] for b in written]
    assert len(set(ids)) == len(ids) and ids[30:] == list(range(30, len(ids)))
    assert d["kept"] == {"blocks": 30, "colliding": [], "out_of_tolerance": [], "unstable": []}
    # Everything placed around them is valid.
    assert d["blocks"] > 30 and d["collisions"] == 0 and d["out_of_tolerance"] == 0 and d["stable"]


def test_invalid_kept_blocks_stay_and_are_reported(mini):
    """A kept pair that interpenetrates and a kept block past the slope stay where they are,
    named in ``kept``; no block placed around them collides or sticks out."""
    ref = read_layout(REFERENCE).blocks
    ground = [p for p in ref if p.pose.position[2] < 0.5 * mini.block.height]
    a = ground[0]
    twin = Placement(100, "shake-4t", Pose(a.pose.position + [0.3, 0.0, 0.0], a.pose.quaternion))
    zone = mini.tolerance
    outer = max(ground, key=lambda p: p.pose.position[0])
    x, y, z = outer.pose.position
    out = Placement(101, "shake-4t", Pose([zone.bottom_half_width - 0.2, y, z], outer.pose.quaternion))
    assert out_of_tolerance([(101, mini.block, out.pose)], zone)  # the case is what it says
    keep = [a, twin, out]
    result = optimize(mini, seed=2, time_limit=20, keep=keep)
    kept = result.kept
    assert kept["blocks"] == 3
    assert set(kept["colliding"]) == {a.id, 100}
    assert kept["out_of_tolerance"] == [101]
    placed = result.layout.blocks
    assert [(p.id, p.pose.position.tobytes(), p.pose.quaternion.tobytes()) for p in placed[:3]] == [
        (p.id, p.pose.position.tobytes(), p.pose.quaternion.tobytes()) for p in keep]
    assert len(placed) > 3
    assert not result.valid
    check = result.to_dict()
    kept_ids = {p.id for p in keep}
    from geometry.checks import check_layout

    report = check_layout(mini, result.layout.placed(), with_coverage=False)
    assert {i for c in report.collisions for i in (c.a, c.b)} <= kept_ids
    assert {i for i, _ in report.out_of_tolerance} <= kept_ids
    assert check["collisions"] == len(report.collisions)


def test_kept_blocks_one_inside_another_are_held_in_the_settle(mini):
    """The settle that judges a layout lets every block move but kept ones that interpenetrate:
    they are reported as colliding whatever it says, and their overlaps cost the engine seconds
    (84 kept copies at one pose ran a 2 s limit to 5.9 s)."""
    from optimizer.api import kept_build
    from optimizer.search.physics import judged

    ref = read_layout(REFERENCE).blocks
    a, clean = ref[0], ref[1]
    twin = Placement(100, "shake-4t", Pose(a.pose.position + [0.3, 0.0, 0.0], a.pose.quaternion))
    build = kept_build(mini, [a, twin, clean])
    free = build.place_at(ref[2].pose)
    keys = {p: k for k, p in zip(build.order, ("a", "twin", "clean", "free"), strict=True)}
    assert judged(build) == [keys["clean"], free]
    assert judged(kept_build(mini, [a, clean])) is None  # nothing held: every block moves


def test_keep_input_errors(tmp_path, partial):
    out = tmp_path / "out.json"
    tetrapod = tmp_path / "tetrapod.json"
    layout = read_layout(partial)
    tetrapods = [Placement(p.id, "tetrapod", p.pose) for p in layout.blocks[:5]]
    write_layout(Layout("tetrapod", tetrapods), tetrapod)
    wrong_type = tmp_path / "wrong-type.json"
    write_layout(Layout("mini", tetrapods), wrong_type)
    repeated = tmp_path / "repeated.json"
    d = json.loads(partial.read_text())
    d["blocks"][1]["id"] = d["blocks"][0]["id"]
    repeated.write_text(json.dumps(d))
    nan = tmp_path / "nan.json"
    nan.write_text(partial.read_text().replace(str(d["blocks"][2]["position"][0]), "NaN", 1))
    broken = tmp_path / "broken.json"
    broken.write_text(partial.read_text()[:-20])
    near_last_id = tmp_path / "near-last-id.json"  # new ids would pass 2**53, which no reader takes
    write_layout(Layout("mini", [Placement(2**53 - 10 + i, p.type, p.pose)
                                 for i, p in enumerate(layout.blocks[:10])]), near_last_id)
    crowded = tmp_path / "crowded.json"  # 1000 copies of one pose ran 200 s past a 10 s limit
    write_layout(Layout("mini", [Placement(i, layout.blocks[0].type, layout.blocks[0].pose)
                                 for i in range(1000)]), crowded)
    too_many = tmp_path / "too-many.json"  # 5000 blocks far apart took 28 s of a 10 s limit
    write_layout(Layout("mini", [Placement(i, layout.blocks[0].type,
                                           Pose([50.0 * (i % 100), 50.0 * (i // 100), 1.0], [1, 0, 0, 0]))
                                 for i in range(500)]), too_many)
    cases = {
        "more blocks than the tolerance zone holds": (too_many, out),
        "blocks one inside another by the dozen": (crowded, out),
        "ids near 2**53": (near_last_id, out),
        "another scene": (tetrapod, out),
        "another block type": (wrong_type, out),
        "repeated ids": (repeated, out),
        "NaN": (nan, out),
        "malformed JSON": (broken, out),
        "missing": (tmp_path / "none.json", out),
        "--out is the --keep file": (partial, partial),
    }
    before = partial.read_bytes()
    for what, (keep, target) in cases.items():
        r = shoha("optimize", "mini", "--keep", str(keep), "--out", str(target), "--time-limit", "5")
        assert r.returncode == 2, (what, r.stdout, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1, (what, r.stderr)
        assert not out.exists(), what
        if keep.exists() and keep != partial:
            assert str(keep) in r.stderr, (what, r.stderr)  # the message names the file
        if what == "another scene":  # no reference in an optimize: the scene optimized
            assert "scene 'tetrapod' is not the optimized scene 'mini'" in r.stderr, r.stderr
    assert partial.read_bytes() == before


def test_a_kept_layout_of_another_scene_file_of_the_same_name_names_both_and_the_difference(tmp_path):
    """Two scene files both named ``tiny``, 4 m and 8 m long: the refusal once read "scene 'tiny'
    is not the optimized scene 'tiny'" (stop 77's probe); it names both files and the length."""
    text = (ROOT / "tests" / "data" / "tiny.toml").read_text()
    (tmp_path / "tiny.toml").write_text(text)
    (tmp_path / "long.toml").write_text(text.replace("length_m = 4.0", "length_m = 8.0"))
    write_layout(Layout(str(tmp_path / "long.toml"), []), tmp_path / "partial.json")
    r = shoha("optimize", str(tmp_path / "tiny.toml"), "--keep", str(tmp_path / "partial.json"),
              "--out", str(tmp_path / "out.json"), "--time-limit", "5")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"scene 'tiny' ({tmp_path / 'long.toml'}) is not the optimized scene 'tiny' " \
           f"({tmp_path / 'tiny.toml'}): its section (length 8.0 against 4.0) differs" in r.stderr, r.stderr
    assert not (tmp_path / "out.json").exists()


def test_the_api_refuses_a_kept_layout_it_cannot_complete_in_time(mini):
    """``optimize(keep=...)``, as a library caller or a service calls it, refuses what the CLI
    refuses, before its clock runs: crowded copies, more blocks than the zone holds, repeats."""
    from geometry.errors import InputError

    block = read_layout(REFERENCE).blocks[0]
    copies = [Placement(i, block.type, block.pose) for i in range(200)]  # fewer than the zone holds
    far = [Placement(i, block.type, Pose([50.0 * (i % 100), 50.0 * (i // 100), 1.0], [1, 0, 0, 0]))
           for i in range(500)]
    cases = {"one inside another": copies, "at most": far, "repeats block ids": [block, block],
             "one block type a scene": [Placement(0, "tetrapod", block.pose)]}
    for words, keep in cases.items():
        with pytest.raises(InputError, match=f"^the kept layout: .*{words}"):
            optimize(mini, seed=1, keep=keep, time_limit=5.0)


def test_kept_layout_laid_from_the_pattern_is_continued_along_it(mini, partial):
    """The origin that lays the pattern through the kept blocks is found, and the sites they
    stand on are not offered again."""
    from optimizer.api import kept_build
    from optimizer.search.patterns import lattice_for
    from optimizer.search.problem import Problem
    from optimizer.search.sites import kept_origins, laid_sites, pattern_sites

    build = kept_build(mini, read_layout(partial).blocks)
    problem = Problem(mini, mini.required_blocks, mini.target_porosity, lattice_for(mini.block, "shake-4t"))
    origins = kept_origins(problem, build)
    assert origins
    sites = pattern_sites(problem, origins[0])
    taken = laid_sites(problem, build, sites)
    # Every kept block of the reference's first pass stands on a site of that origin.
    assert len(taken) == 30
    xy = np.array([(x, y) for _, _, x, y in sites])[sorted(taken)]
    kept_xy = np.array([build.poses[k].position[:2] for k in build.kept])
    assert np.abs(np.sort(xy, axis=0) - np.sort(kept_xy, axis=0)).max() < 0.5


def test_a_whole_layout_kept_gains_no_block(mini):
    """Kept blocks that hold the count already: nothing is added (a block more made the layout
    invalid, at 76 of 75), and the layout is valid as it was."""
    ref = read_layout(REFERENCE).blocks
    assert len(ref) == mini.required_blocks
    result = optimize(mini, seed=1, time_limit=30.0, keep=ref, settle_layout=False, cover=False)
    assert result.blocks == mini.required_blocks and result.valid
    assert [p.pose for p in result.layout.blocks] == [p.pose for p in ref]
    assert result.kept == {"blocks": 75, "colliding": [], "out_of_tolerance": [], "unstable": []}


def test_an_empty_kept_layout_is_reported_as_kept_and_without_keep_not(mini):
    """``kept`` says what --keep kept, nothing included (it was null for an empty file), and is
    null without --keep."""
    empty = optimize(mini, seed=1, time_limit=2.0, keep=[], settle_layout=False, cover=False)
    assert empty.kept == {"blocks": 0, "colliding": [], "out_of_tolerance": [], "unstable": []}
    assert empty.to_dict()["kept"] == empty.kept
    assert optimize(mini, seed=1, time_limit=2.0, settle_layout=False, cover=False).kept is None


@pytest.mark.parametrize("name", ["shake-4t", "tetrapod:2", "box:1.6x1.6x1.6"])
def test_the_crowding_bound_holds_for_the_densest_packing_of_the_block(name):
    """``most_within_reach`` bounds how many blocks can reach one without overlaps. The
    densest packing of copies of one pose is a lattice whose neighbours touch: it stays under
    the bound, and the same count squeezed to a quarter of the spacing, overlapping, is refused."""
    from geometry.blocks import get_block
    from geometry.checks import check_not_crowded, most_within_reach
    from geometry.errors import InputError

    block = get_block(name)
    step = np.ptp(block.vertices, axis=0)  # boxes of the block's extent: no two copies overlap
    grid = np.stack(np.meshgrid(*[np.arange(-6, 7)] * 3, indexing="ij"), -1).reshape(-1, 3) * step
    ids = list(range(len(grid)))
    check_not_crowded(block, grid, ids, "lattice")
    with pytest.raises(InputError, match=f"more than the {most_within_reach(block)} that could lie there"):
        check_not_crowded(block, grid / 4, ids, "squeezed")


def test_pattern_origin_found_behind_rows_laid_off_it(mini):
    """Kept blocks that begin with toe rows, off the pattern, and go on along the pattern: the
    origin the pattern was laid from is among those proposed, though the rows come first in
    crane order and the dense sites put some site near many a block of other origins too."""
    from scipy.spatial import cKDTree

    from optimizer.api import kept_build
    from optimizer.search.patterns import lattice_for
    from optimizer.search.problem import Problem
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import kept_origins, pattern_pass, pattern_sites
    from optimizer.search.toe import ToeRows

    problem = Problem(mini, mini.required_blocks, mini.target_porosity, lattice_for(mini.block, "shake-4t"))
    rows = ToeRows().run(problem, None, np.random.default_rng(1)).build
    origin = (0.115, 0.735)
    laid = pattern_pass(problem, ShapeCache(mini.block), rows, origin, laid=list(rows.order))
    keep = [Placement(i, "shake-4t", laid.poses[k]) for i, k in enumerate(laid.order[:len(rows) + 16])]
    build = kept_build(mini, keep)
    on_pattern = np.array([p.pose.position[:2] for p in keep[len(rows):]])

    def under(o):
        sites = np.array([(x, y) for _, _, x, y in pattern_sites(problem, o)])
        return int((cKDTree(sites).query(on_pattern)[0] < 0.01).sum())

    assert len(rows) >= 10
    assert max(under(o) for o in kept_origins(problem, build)) == 16


def test_a_limit_too_short_to_settle_the_kept_blocks_is_kept_and_said(monkeypatch):
    """900 kept blocks of ``full`` under a 2 s limit, with a clock that charges a settle of the
    whole layout what one takes on 2 cores (about 7 s for 900 blocks): the beam does not judge
    a search that ended past its time, and the layout is written not settled, said so and not
    valid, within the limit. Before, the beam's verdict and the confirmation ran 21 s past it."""
    import optimizer.search.physics as physics
    from optimizer.search.build import Build
    from optimizer.search.patterns import lattice_for
    from optimizer.search.problem import Problem
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass
    from tests.clock import WorkClock

    full = load_scene("full")
    problem = Problem(full, full.required_blocks, full.target_porosity, lattice_for(full.block, "shake-4t"))
    laid = pattern_pass(problem, ShapeCache(full.block), Build(full), (0.3, 0.7))
    keep = [Placement(i, "shake-4t", laid.poses[k]) for i, k in enumerate(laid.order[:900])]
    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    charged, whole = physics.settle, []

    def slow(scene, placed, *args, **kwargs):
        movable = kwargs.get("movable")
        if movable is None or len(movable) > 1:
            clock.t += 7.0 * len(placed) / 900
            whole.append(len(placed))
        return charged(scene, placed, *args, **kwargs)

    monkeypatch.setattr(physics, "settle", slow)
    r = optimize(full, seed=1, time_limit=2.0, keep=keep, clock=clock)
    assert r.seconds <= 2.0 + 2.0, f"whole settles of {whole} blocks"
    assert r.stable is None and not r.valid and r.settle == {"skipped": "time"}
    assert "the layout was not settled: one settle of it would not fit in the time limit" in r.summary()
    assert r.kept["blocks"] == 900 and r.collisions == 0


def test_a_kept_mesh_block_named_from_another_folder_is_the_scenes_block(tmp_path):
    """``optimize``'s own output, fed back with ``--keep``, names the scene's mesh relative to the
    layout's folder (``mesh:../scene/shake.stl``), where the scene says ``mesh:shake.stl``: one
    file, and it was refused as another block type (exit 2). Its blocks are kept as written."""
    scene_dir, out_dir = tmp_path / "scene", tmp_path / "out"
    scene_dir.mkdir()
    out_dir.mkdir()
    shoha("block", "export", "shake-4t", "--out", str(scene_dir / "shake.stl"))
    text = (ROOT / "tests" / "data" / "tiny.toml").read_text().replace('"shake-4t"', '"mesh:shake.stl"')
    (scene_dir / "tiny.toml").write_text(text)
    scene = load_scene(str(scene_dir / "tiny.toml"))
    block = scene.block
    poses = [Pose([x, 2.0, -block.vertices[:, 2].min() + 0.01], [1, 0, 0, 0]) for x in (-1.0, 1.0)]
    partial = out_dir / "partial.json"
    write_layout(Layout("../scene/tiny.toml", [Placement(i, "mesh:../scene/shake.stl", p)
                                               for i, p in enumerate(poses)], base_dir=str(out_dir)), partial)
    assert '"mesh:../scene/shake.stl"' in partial.read_text()
    r = shoha("optimize", str(scene_dir / "tiny.toml"), "--keep", str(partial), "--time-limit", "8",
              "--out", str(out_dir / "done.json"), "--json")
    assert r.returncode == 0, r.stderr
    done = read_layout(out_dir / "done.json")
    assert [p.pose.position.tobytes() for p in done.blocks[:2]] == [p.position.tobytes() for p in poses]
    assert {p.type for p in done.blocks} == {"mesh:../scene/shake.stl"}


def test_kept_blocks_that_cannot_be_taken_in_within_the_limit_are_refused_at_once(monkeypatch):
    """Taking in a kept block costs most of a millisecond, and 15 920 kept blocks under a 5 s
    limit ran to 14 s before (stop 77's probe). On a clock that charges 50 ms a kept block, 900
    kept blocks of ``full`` are refused under a 5 s limit after the first 200 (an InputError,
    exit 2, that names the time they need), and taken in under a 60 s one."""
    from geometry.errors import InputError
    from optimizer.api import kept_in_time
    from optimizer.search.build import Build
    from optimizer.search.patterns import lattice_for
    from optimizer.search.problem import Problem
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass

    full = load_scene("full")
    problem = Problem(full, full.required_blocks, full.target_porosity, lattice_for(full.block, "shake-4t"))
    laid = pattern_pass(problem, ShapeCache(full.block), Build(full), (0.3, 0.7))
    keep = [Placement(i, "shake-4t", laid.poses[k]) for i, k in enumerate(laid.order[:900])]
    now = [0.0]
    taken = Build.keep

    def charged(build, *args):
        now[0] += 0.05
        return taken(build, *args)

    monkeypatch.setattr(Build, "keep", charged)
    slow = r"its 900 blocks take about 45 s to take in .* give it at least 4\d s"
    with pytest.raises(InputError, match=slow):
        kept_in_time(full, keep, 0.0, 5.0, lambda: now[0])
    assert now[0] == pytest.approx(200 * 0.05)  # refused at the first look, not after all 900
    now[0] = 0.0
    assert len(kept_in_time(full, keep, 0.0, 60.0, lambda: now[0]).kept) == 900

"""The placement optimizer: drops, annealing, the CP-SAT model, determinism."""

from __future__ import annotations

import itertools
import json
from dataclasses import replace

import numpy as np
import pytest

from geometry.clip import volumes_inside
from geometry.collision import CollisionWorld, collisions
from geometry.constants import tol
from geometry.pose import Pose
from geometry.samples import random_quaternion
from geometry.scene import load_scene
from optimizer.api import _attempt, optimize
from optimizer.search.anneal import Annealing, energy_of
from optimizer.search.beam import BeamSearch
from optimizer.search.build import Build
from optimizer.search.cpsat import CpSat
from optimizer.search.drop import DropWorld, Shape
from optimizer.search.hangings import BASE, FAMILIES, hanging
from optimizer.search.patterns import (
    TUNED,
    UPPER_KEYS,
    InterlockLattice,
    UpperLayer,
    _lattice_penalty,
    first_layer,
    lattice_for,
    lay_upper,
    upper_tops,
)
from optimizer.search.problem import Phase, Problem
from tests.clock import WorkClock
from tests.conftest import ROOT, shoha
from tests.test_strategies import TINY, assert_valid, problem


@pytest.fixture(scope="module")
def tiny():
    return load_scene(TINY)


@pytest.mark.parametrize("block_name", ["shake-4t", "tetrapod:2", "box:1.6x1.6x1.6"])
def test_the_compiled_column_is_the_polytope_modules_column(block_name):
    """The drop's compiled loop crosses a piece with one vertical line at a time
    (``_contact.column``); ``geometry.polytope.column_intervals`` does many at once. On
    lines through, beside and far from every piece of a turned block (a cube's vertical
    faces too), the two give the same extent, and both say where a line misses."""
    from geometry.blocks import get_block
    from geometry.polytope import column_intervals
    from optimizer.search._contact import column

    block = get_block(block_name)
    rng = np.random.default_rng(5)
    turns = [np.array([1.0, 0.0, 0.0, 0.0]), random_quaternion(rng)]
    misses = 0
    for q in turns:
        for piece in Shape.of(block, q).pieces:
            xy = rng.uniform(-1.5 * block.bounding_radius, 1.5 * block.bounding_radius, (200, 2))
            lo, hi = column_intervals(piece.normals, piece.offsets, xy)
            for (x, y), a, b in zip(xy, lo, hi, strict=True):
                c_lo, c_hi = column(piece.normals, piece.offsets, float(x), float(y), tol.distance)
                if a > b:
                    misses += 1
                    assert c_lo > c_hi
                else:
                    assert (c_lo, c_hi) == (pytest.approx(a, abs=1e-12), pytest.approx(b, abs=1e-12))
    assert misses > 0, "some lines miss a piece"


@pytest.mark.parametrize("block_name", ["shake-4t", "tetrapod:2", "box:1.6x1.6x1.6"])
def test_a_turned_shape_is_each_piece_turned_with_its_faces_that_look_down_and_up(block_name):
    """``Shape.of`` turns all pieces in one pass: each piece is the block's piece turned
    (``ConvexPolytope.transformed``), with its lowest and highest z and footprint box, and its
    lower (upper) side holds the vertices and edges of exactly the triangles whose turned
    normal points down (up)."""
    from geometry.blocks import get_block
    from geometry.pose import quat_to_matrix

    block = get_block(block_name)
    rng = np.random.default_rng(8)
    for q in [np.array([1.0, 0.0, 0.0, 0.0]), *[random_quaternion(rng) for _ in range(6)]]:
        shape = Shape.of(block, q)
        r = quat_to_matrix(q)
        assert len(shape.pieces) == len(block.pieces)
        world = np.concatenate([own.transformed(r, np.zeros(3)).vertices for own in block.pieces])
        np.testing.assert_array_equal(shape.footprint, [world[:, :2].min(axis=0), world[:, :2].max(axis=0)])
        for i, own in enumerate(block.pieces):
            turned = own.transformed(r, np.zeros(3))
            piece = shape.pieces[i]
            np.testing.assert_array_equal(piece.vertices, turned.vertices)
            np.testing.assert_array_equal(piece.normals, turned.normals)
            np.testing.assert_array_equal(piece.offsets, turned.offsets)
            z = turned.vertices[:, 2]
            assert shape.lows[i] == z.min() and shape.highs[i] == z.max()
            np.testing.assert_array_equal(shape.xy_boxes[i], turned.aabb[:, :2])
            tri = turned.vertices[own.faces]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            for side, sign in ((shape.lower[i], -1.0), (shape.upper[i], 1.0)):
                facing = sign * n[:, 2] > tol.orientation * np.linalg.norm(n, axis=1)
                corners = {tuple(v) for v in turned.vertices[np.unique(own.faces[facing])]}
                edges, vertices = side
                assert {tuple(v) for v in vertices} == corners and len(vertices) == len(corners)
                assert {tuple(v) for v in edges.reshape(-1, 3)} == corners


@pytest.mark.parametrize("block_name", ["shake-4t", "tetrapod:2", "box:1.6x1.6x1.6"])
def test_the_compiled_ground_test_is_the_numpy_one_and_leaves_every_vertex_above_the_rubble(block_name):
    """On rough ground a block is lowered until one of its pieces meets the height field at a
    vertex of the block or a node of the field under it. The compiled loop
    (``_contact.ground_kernel``) gives the height that the numpy form, written out here from
    ``column_intervals`` and ``Foundation.height_at``, gives, for turned blocks anywhere over
    the field, its edges too; and at that height no vertex of the block is under the ground,
    nor any node of the field over the block."""
    from geometry.blocks import get_block
    from geometry.polytope import column_intervals
    from geometry.scene import Foundation

    block = get_block(block_name)
    field = Foundation(kind="rough", amplitude=0.3, cell=0.4, seed=2, extent=(-4.0, 4.0, -3.0, 3.0))
    world = DropWorld(field)
    rng = np.random.default_rng(3)
    xs, ys, _ = field.grid
    for _ in range(60):
        shape = Shape.of(block, random_quaternion(rng))
        x, y = rng.uniform(-4.5, 4.5), rng.uniform(-3.5, 3.5)
        z = world.ground_height(shape, x, y)
        offset = np.array([x, y])
        lo_xy = shape.xy_boxes[:, 0].min(axis=0) + offset
        hi_xy = shape.xy_boxes[:, 1].max(axis=0) + offset
        gx, gy = np.meshgrid(xs[(xs >= lo_xy[0]) & (xs <= hi_xy[0])], ys[(ys >= lo_xy[1]) & (ys <= hi_xy[1])],
                             indexing="ij")
        local = np.concatenate([shape.vertices_xy, np.column_stack([gx.ravel(), gy.ravel()]) - offset])
        ground = field.height_at(local + offset)
        expected = -np.inf
        for piece in shape.pieces:
            lo, hi = column_intervals(piece.normals, piece.offsets, local)
            ok = hi >= lo - tol.distance
            if ok.any():
                expected = max(expected, float(np.max(ground[ok] - lo[ok])))
        assert z == pytest.approx(expected, abs=1e-12)
        world_vertices = Pose([x, y, z], shape.quaternion).apply(block.vertices)
        clearance = world_vertices[:, 2] - field.height_at(world_vertices[:, :2])
        assert clearance.min() >= -1e-9
        nodes = np.column_stack([gx.ravel(), gy.ravel()])
        under = [z + lo - field.height_at(nodes)[ok] for piece in shape.pieces
                 for lo, hi in [column_intervals(piece.normals, piece.offsets, nodes - offset)]
                 for ok in [hi >= lo - tol.distance] for lo in [lo[ok]]]
        node_clearance = min((float(c.min()) for c in under if len(c)), default=np.inf)
        assert node_clearance >= -1e-9


def test_the_warm_up_compiles_the_loops_for_the_types_a_search_passes():
    """``make`` compiles the drop's loops once (``python -m optimizer.search._contact``), so that
    a first run does not spend its time limit compiling. That helps only if a search then calls
    them with the very types the warm-up compiled: after the warm-up and a few drops on rubble
    among blocks, every loop has one compiled signature."""
    from optimizer.search import _contact

    _contact.warm()
    scene = load_scene(ROOT / "benchmarks" / "scenes" / "mini-rough.toml")
    build = Build(scene)
    rng = np.random.default_rng(4)
    placed = 0
    for _ in range(40):
        shape = Shape.of(scene.block, random_quaternion(rng))
        c = build.lower(shape, float(rng.uniform(-3, 3)), float(rng.uniform(2, 10)))
        if c is not None:
            build.place(c)
            placed += 1
    assert placed >= 3 and any(s != -1 for k in build.order for s in build.supports[k]), "drops onto blocks"
    # The two a search calls; the others are compiled into them.
    for name in ("rest_height_kernel", "ground_kernel"):
        assert len(getattr(_contact, name).signatures) == 1, name


@pytest.mark.parametrize("block_name", ["shake-4t", "tetrapod:2"])
def test_a_drop_by_linear_programme_lands_where_one_by_breakpoints_does(block_name, monkeypatch):
    """Pieces with many planes are lowered by a linear programme (two 2500-vertex spheres took
    0.7 s a drop by breakpoints). Forced on for every pair here, the drops land on the same
    blocks at the same height, to a nanometre."""
    import optimizer.search.drop as drop
    from geometry.blocks import get_block
    from geometry.scene import Foundation

    block = get_block(block_name)
    rng = np.random.default_rng(11)
    placed = [(k, block, Pose([x, y, 0.0], random_quaternion(rng)))
              for k, (x, y) in enumerate([(0.0, 0.0), (1.2, 0.3), (-0.4, 1.3)])]
    world = DropWorld.of(Foundation(), placed)
    shapes = [Shape.of(block, random_quaternion(rng)) for _ in range(12)]
    spots = rng.uniform(-1.5, 2.0, (12, 2))
    every = [world.drop(sh, *xy) for sh, xy in zip(shapes, spots, strict=True)]
    monkeypatch.setattr(drop, "MANY_PLANES", 0)
    by_lp = [world.drop(sh, *xy) for sh, xy in zip(shapes, spots, strict=True)]
    assert sum(len(s) > 0 for _, s, _ in every) >= 6, "most drops land on blocks"
    for (z, support, ground), (z_lp, support_lp, ground_lp) in zip(every, by_lp, strict=True):
        assert z_lp == pytest.approx(z, abs=1e-9) and set(support_lp) == set(support) and ground_lp == ground


@pytest.mark.parametrize("name", ["mini", "tetrapod"])
def test_lower_refuses_exactly_the_drops_that_end_out_of_tolerance(name):
    """``Build.lower`` skips the drop of a block that crosses the zone's ceiling at
    ground height; that shortcut must refuse no block the drop would accept. Sites
    over the whole zone and past its slopes, on the ground and on a first layer."""
    from optimizer.search.build import Build
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass

    scene = load_scene(name)
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    zone = scene.tolerance
    rng = np.random.default_rng(7)
    refused = accepted = 0
    for base in (Build(scene), pattern_pass(prob, shapes, Build(scene), (0.0, 0.0))):
        for _ in range(150):
            shape = shapes.get(hanging(str(rng.choice(FAMILIES)), float(rng.uniform(0, 2 * np.pi))))
            x = float(rng.uniform(-zone.bottom_half_width - 1.0, zone.bottom_half_width + 1.0))
            y = float(rng.uniform(zone.y_start - 1.0, zone.y_end + 1.0))
            z, _, _ = base.drops.drop(shape, x, y)
            world = Pose([x, y, z], shape.quaternion).apply(scene.block.vertices)
            inside = bool(zone.polytope.contains(world).all())
            assert (base.lower(shape, x, y) is not None) == inside, (x, y)
            accepted += inside
            refused += not inside
    assert refused > 50 and accepted > 50


def test_candidates_touch_what_they_rest_on(mini, shake):
    """Every drop ends in contact (FCL): not hovering, not penetrating."""
    rng = np.random.default_rng(0)
    drops = DropWorld(mini.foundation, cell=2.2)
    world = CollisionWorld(cell=2.4)
    assert drops.top() == 0.0
    top = 0.0
    for k in range(40):
        shape = Shape.of(shake, random_quaternion(rng))
        x, y = rng.uniform([-3, 1], [3, 11])
        z, support, on_ground = drops.drop(shape, x, y)
        pose = Pose([x, y, z], shape.quaternion)
        assert world.query(shake, pose, threshold=-1.0) == []  # no contact at rest height
        lower = Pose([x, y, z - 2 * tol.drop_resolution], shape.quaternion)
        touched = {key for key, _ in world.query(shake, lower, threshold=-1.0)}
        if on_ground:
            assert pose.apply(shake.vertices)[:, 2].min() == pytest.approx(tol.drop_resolution, abs=1e-9)
        else:
            assert touched, "a block rests on nothing"
            assert set(support) <= touched
        drops.add(k, shape, pose.position)
        world.add(k, shake, pose)
        top = max(top, float(pose.apply(shake.vertices)[:, 2].max()))
        assert drops.top() == pytest.approx(top, abs=1e-9)


@pytest.mark.parametrize("family", FAMILIES)
def test_hangings_are_the_documented_orientations(shake, family):
    from geometry.blocks import LEG_DIRECTIONS

    r = Pose([0, 0, 0], hanging(family, 0.3)).rotation
    legs_z = (LEG_DIRECTIONS @ r.T)[:, 2]
    up = np.sort(legs_z)[::-1]
    if family == "crown":  # one leg straight up
        assert up[0] == pytest.approx(1.0)
    elif family == "level":  # one leg straight down, three up at the same height
        assert up[-1] == pytest.approx(-1.0) and np.ptp(up[:3]) < 1e-9
    else:  # two up, two down, symmetric
        assert up[0] == pytest.approx(up[1]) and up[2] == pytest.approx(up[3])
        assert up[0] == pytest.approx(-up[3])
    assert set(BASE) == set(FAMILIES)


@pytest.mark.parametrize("name", list(TUNED))
def test_tuned_lattices_are_crane_feasible(name):
    from geometry.blocks import get_block

    block = get_block(name)
    lat = lattice_for(block, name)
    params = np.array([lat.p, lat.w, lat.q, lat.u, lat.v, lat.yaw_a, lat.yaw_b])
    # The penalty adds 20 per metre a block stops short of the ground: zero means feasible.
    assert _lattice_penalty(params, block, (lat.family_a, lat.family_b)) == pytest.approx(lat.area_per_block)
    f = 0.9
    tighter = InterlockLattice(lat.p * f, lat.w * f, lat.q * f, lat.u * f, lat.v * f, lat.yaw_a, lat.yaw_b)
    p2 = np.array([tighter.p, tighter.w, tighter.q, tighter.u, tighter.v, tighter.yaw_a, tighter.yaw_b])
    assert _lattice_penalty(p2, block, ("crown", "level")) > tighter.area_per_block + 0.01


def test_tuned_upper_layer_nests_under_the_tetrapod_crest():
    """The tetrapod's second layer sinks into the first and stays under the zone's crest.

    Its blocks, lowered in crane order onto a patch of the first layer, top
    out below the ``tetrapod`` scene's tolerance crest; its first site (the
    one the tuning lowers first) ends more than 0.1 m lower than a block
    height above the first layer: it nests.
    """
    from geometry.blocks import get_block

    block = get_block("tetrapod:2.0")
    lat = lattice_for(block, "tetrapod:2.0")
    assert lat.upper is not None
    crest = load_scene("tetrapod").tolerance.z_top
    world = first_layer(lat, block)
    tops = upper_tops(world, block, lat, lat.upper)
    first_top = max(p.vertices[:, 2].max() for k in range(len(world)) for p in world._placed[k][2])
    assert first_top == pytest.approx(block.height, abs=2 * tol.drop_resolution)  # on the ground
    assert tops.max() < crest
    assert tops[0] < first_top + block.height - 0.1


def test_two_layer_patch_stands_clear_and_its_poses_round_trip():
    """The pattern's two layers on a patch, as ``tetrapod_limit.interior_rows`` measures them.

    Every block of both layers is in the drop world, no two interpenetrate
    (FCL), and the world's poses rebuild the same world
    (:meth:`DropWorld.poses` is the inverse of :meth:`DropWorld.of`).
    """
    from geometry.blocks import get_block

    block = get_block("tetrapod:2.0")
    lat = lattice_for(block, "tetrapod:2.0")
    world = first_layer(lat, block, ring=1)
    tops = lay_upper(world, block, lat, lat.upper, ring=1)
    poses = world.poses()
    assert len(poses) == 4 * 3 * 3  # two sites per cell, two layers, 3 x 3 cells
    placed = [(k, block, pose) for k, pose in poses.items()]
    assert collisions(placed, threshold=0.0) == []
    lows = {k: pose.apply(block.vertices)[:, 2].min() for k, pose in poses.items()}
    first = [k for k in poses if k < UPPER_KEYS]
    assert len(first) == 2 * 3 * 3
    assert all(abs(lows[k]) <= 2 * tol.drop_resolution for k in first)  # on the ground
    assert all(lows[k] > 2 * tol.drop_resolution for k in poses if k not in first)  # on the first layer
    assert tops.max() > block.height
    again = DropWorld.of(world.foundation, placed).poses()
    assert again.keys() == poses.keys()
    for k, pose in poses.items():
        np.testing.assert_allclose(again[k].position, pose.position)
        np.testing.assert_allclose(again[k].quaternion, pose.quaternion)


def test_second_pass_lays_the_upper_layer():
    """The beam's second pass is the tuned upper layer; without one, the first shifted by half a cell."""
    from optimizer.search.sites import pattern_sites

    scene = load_scene("tetrapod")
    prob = problem(scene)
    lat, up = prob.lattice, prob.lattice.upper
    sites = pattern_sites(prob, (0.0, 0.0))
    first = lat.sites((-scene.tolerance.bottom_half_width, scene.tolerance.bottom_half_width),
                      (scene.tolerance.y_start, scene.tolerance.y_end), (0.0, 0.0))
    assert sites[: len(first)] == first
    second = sites[len(first):]
    assert {(f, round(yaw, 9)) for f, yaw, _, _ in second} == {(up.family_a, round(up.yaw_a, 9)),
                                                                (up.family_b, round(up.yaw_b, 9))}
    crown = next((x, y) for f, yaw, x, y in second if f == up.family_a)
    # On the lattice through (dx, dy): an integer combination of the lattice vectors away.
    j = round((crown[0] - up.dx) / lat.w)
    assert crown[0] == pytest.approx(up.dx + j * lat.w)
    i = (crown[1] - up.dy - j * lat.q) / lat.p
    assert i == pytest.approx(round(i), abs=1e-9)
    plain = Problem(scene, scene.required_blocks, scene.target_porosity, replace(lat, upper=None))
    shifted = pattern_sites(plain, (0.0, 0.0))[len(first):]
    assert shifted == lat.sites((-scene.tolerance.bottom_half_width, scene.tolerance.bottom_half_width),
                                (scene.tolerance.y_start, scene.tolerance.y_end), (lat.w / 2, lat.p / 2))


def test_sites_and_drops_stay_near_the_design_prism_however_wide_the_tolerance_zone():
    """Allowances of kilometres (a user's typo) leave the search where a block can fill
    the prism; over the whole zone, listing the sites alone overran a 5 s limit by a
    minute. Ordinary allowances change nothing."""
    from geometry.scene import parse_scene
    from optimizer.search.build import fill_window, search_window
    from optimizer.search.sites import pattern_sites
    from tests.test_scene import MINI_TOML

    mini = parse_scene(MINI_TOML, "mini.toml", None)
    z = mini.tolerance
    assert search_window(mini) == ((-z.bottom_half_width, z.bottom_half_width), (z.y_start, z.y_end))
    wide = parse_scene(MINI_TOML + "[tolerance]\nslope_lengthening_m = 5000.0\n"
                       "end_extension_m = 5000.0\ncrest_widening_m = 3000.0\n", "wide.toml", None)
    d, r = wide.design, wide.block.bounding_radius
    assert wide.tolerance.bottom_half_width > 1000 and wide.tolerance.y_end > 1000
    sites = pattern_sites(problem(wide), (0.0, 0.0))
    xs, ys = np.array([s[2] for s in sites]), np.array([s[3] for s in sites])
    assert np.abs(xs).max() <= d.bottom_half_width + r
    assert ys.min() >= d.y_start - r and ys.max() <= d.y_end + r
    assert len(sites) < 2 * len(pattern_sites(problem(mini), (0.0, 0.0)))
    (x0, x1), (y0, y1) = fill_window(wide)
    assert -d.bottom_half_width - r <= x0 and x1 <= d.bottom_half_width + r
    assert d.y_start - r <= y0 and y1 <= d.y_end + r


def test_origin_scans_reach_the_tetrapod_count():
    """From the best-ranked origin, the pattern alone places all of ``tetrapod``'s blocks.

    The count the pattern places is a step function of its origin (60 to 81
    blocks here), and the steps that reach 81 are narrow; the line scans of
    :func:`rank_origins` must land on them. The ranking is best first.
    """
    from optimizer.search.build import Build
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass, rank_origins

    scene = load_scene("tetrapod")
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    origins = rank_origins(prob, shapes, np.random.default_rng(1), Build(scene), 1, float("inf"), 3, 16)
    assert len(origins) == 1 + 16 + 8 + 16
    best, worst = (pattern_pass(prob, shapes, Build(scene), o) for o in (origins[0], origins[-1]))
    assert len(best) == scene.required_blocks
    assert best.inside_volume >= worst.inside_volume


def test_origins_of_the_covering_attempt_are_ranked_by_coverage():
    """:func:`rank_by_coverage` puts first the best origin by volume of each of ``n`` x (across
    the crest), ordered by the count their pattern alone places, then how it covers; the rest
    keep their order, as do all once its time is up."""
    from geometry.coverage import coverage
    from optimizer.search.build import Build
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass, rank_by_coverage

    scene = load_scene("mini")
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    origins = [(x, 0.5) for x in (0.0, 0.3, 0.6, 0.9, 1.2)] + [(0.0, 1.0)]
    ranked = rank_by_coverage(prob, shapes, Build(scene), origins, 4, float("inf"))
    assert sorted(ranked) == sorted(origins)
    assert set(ranked[:4]) == set(origins[:4]) and ranked[4:] == origins[4:]

    def key(origin):
        b = pattern_pass(prob, shapes, Build(scene), origin)
        report = coverage(scene, b.placed())
        return -min(len(b), scene.required_blocks), -report.aims_met(), report.bare_share_percent

    keys = [key(o) for o in ranked[:4]]
    assert keys == sorted(keys) and ranked[:4] != origins[:4]  # these four were not in that order
    assert rank_by_coverage(prob, shapes, Build(scene), origins, 4, -1.0) == origins


def test_the_anchors_origins_along_the_crest_are_each_ranked_by_coverage():
    """Where the anchor fixes x (``Problem.anchor``), each of its origins along the crest is one
    of the ``n`` that :func:`rank_by_coverage` ranks; without an anchor only the best by volume
    of that x is, and the others keep their order after the ranked ones."""
    from dataclasses import replace

    from optimizer.search.build import Build
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import rank_by_coverage

    scene = load_scene("mini")
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    origins = [(0.0, 0.5), (0.0, 1.0), (0.0, 1.5), (0.3, 0.5)]
    plain = rank_by_coverage(prob, shapes, Build(scene), origins, 4, float("inf"))
    assert set(plain[:2]) == {(0.0, 0.5), (0.3, 0.5)} and plain[2:] == [(0.0, 1.0), (0.0, 1.5)]
    anchored = replace(prob, anchor=0.0)
    ranked = rank_by_coverage(anchored, shapes, Build(scene), origins, 3, float("inf"))
    assert set(ranked[:3]) == set(origins[:3]) and ranked[3:] == [(0.3, 0.5)]


def test_a_later_pass_of_the_pattern_is_shifted_as_its_origin_says():
    """An origin ``(x, y, dx, dy, ...)`` lays the first pass from ``(x, y)`` and shifts each later
    pass by its own ``(dx, dy)`` from where it nests by default: by a period, the same sites;
    by a share of one, none of them."""
    from optimizer.search.sites import pass_sites, pattern_passes, pattern_sites

    scene = load_scene("mini")
    prob = problem(scene)
    w, p = prob.lattice.w, prob.lattice.p
    origin = (0.3, 0.2)
    assert pattern_passes(prob) >= 2
    nested = pass_sites(prob, origin, 1)
    assert pattern_sites(prob, (*origin, 0.0, 0.0)) == pattern_sites(prob, origin)
    assert pass_sites(prob, (*origin, 0.5 * w, 0.0), 0) == pass_sites(prob, origin, 0)  # the first stays

    def xy(sites):
        return {(round(x, 6), round(y, 6)) for _, _, x, y in sites}

    q = prob.lattice.q  # the lattice's periods are (0, p) and (w, q)
    whole, off = pass_sites(prob, (*origin, w, q), 1), pass_sites(prob, (*origin, 0.37 * w, 0.41 * p), 1)
    assert xy(whole) == xy(nested) and len(nested) > 10
    assert len(off) > 10 and not xy(off) & xy(nested)


def test_a_crest_allowance_of_kilometres_adds_no_passes(tmp_path):
    """The pattern lays as many passes under a crest allowance of 5 km as under one of a
    block's bounding radius: a block above that fills none of the design prism. Counted from
    the zone's height alone, a 1 km mound made about 3800 passes, and ``optimize`` ran out of
    memory listing their sites before its first time check."""
    from optimizer.search.sites import pattern_passes

    def passes(rise: float) -> int:
        path = tmp_path / f"rise-{rise}.toml"
        path.write_text('block = "shake-4t"\ntarget_porosity_percent = 56.0\n[design]\ncrest_width_m = 4.0\n'
                        'height_m = 3.0\nslope_rise_run = [3.0, 4.0]\nlength_m = 1000.0\n'
                        f'[tolerance]\ncrest_rise_m = {rise}\nslope_lengthening_m = {2 * rise}\n')
        return pattern_passes(problem(load_scene(str(path))))

    r = load_scene("mini").block.bounding_radius
    assert passes(5000.0) == passes(r) == passes(r + 10.0) < 10
    assert passes(0.5) <= passes(r)


def _uncapped(prob):
    return replace(prob, required=10**9)


def test_later_passes_fitted_to_a_wall_backed_section_hold_more_blocks():
    """On ``wall-shake`` the pattern nested as tuned, from (0, 0), holds fewer than its 72 blocks;
    fitted pass by pass (:func:`fit_layers`) it holds more, and origins rank by what they hold. Where the
    pattern holds the count from every origin tried, :func:`fitted_origins` leaves them as
    they were."""
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import fit_layers, fitted_origins, pattern_pass, rank_by_coverage

    scene = load_scene(ROOT / "benchmarks" / "scenes" / "wall-shake.toml")
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    nested = pattern_pass(_uncapped(prob), shapes, Build(scene), (0.0, 0.0))
    assert len(nested) < scene.required_blocks
    fitted = fit_layers(prob, shapes, Build(scene), (0.0, 0.0), float("inf"))
    assert len(fitted) > 2 and fitted[:2] == (0.0, 0.0)
    laid = pattern_pass(_uncapped(prob), shapes, Build(scene), fitted)
    assert len(laid) > len(nested)
    ranked = fitted_origins(prob, shapes, Build(scene), [(0.0, 0.0), (0.9, 0.3)], float("inf"))
    assert fitted in ranked and len(ranked) == 2
    counts = [len(pattern_pass(prob, shapes, Build(scene), o)) for o in ranked]
    assert counts == sorted(counts, reverse=True)
    # The attempt with toe rows ranks fitted origins by coverage as any others (it took an
    # origin for two numbers, and two held-out runs failed on it).
    both = [fitted, (0.9, 0.3)]
    assert sorted(rank_by_coverage(prob, shapes, Build(scene), both, 2, float("inf"))) == sorted(both)
    # Where every origin holds the count, they come back as they were.
    roomy = replace(prob, required=20)
    origins = [(0.0, 0.0), (0.9, 0.3)]
    assert fitted_origins(roomy, shapes, Build(scene), origins, float("inf")) == origins


def test_fitting_does_not_lay_again_the_quick_passes_the_ranking_laid(monkeypatch):
    """The beam ranks origins by quick passes of the pattern and then fits the best of them: the
    blocks those passes hold are handed on (``counts``), not laid again (a pass over ``big-shake``
    takes about a second), and the origins come out as when they are laid again."""
    from optimizer.search import sites
    from optimizer.search.shapes import ShapeCache

    scene = load_scene(ROOT / "benchmarks" / "scenes" / "wall-shake.toml")
    prob = problem(scene)
    shapes = ShapeCache(scene.block)
    counts: dict = {}
    ranked = sites.rank_origins(prob, shapes, np.random.default_rng(1), Build(scene), 3, float("inf"),
                                counts=counts)
    assert set(counts) == set(ranked)
    assert counts[(0.0, 0.0)] == len(sites.pattern_pass(prob, shapes, Build(scene), (0.0, 0.0)))
    again = sites.fitted_origins(prob, shapes, Build(scene), ranked, float("inf"))
    laid = []
    real = sites.pattern_pass

    def counted(problem, shapes, start, origin, *args, **kwargs):
        laid.append(origin)
        return real(problem, shapes, start, origin, *args, **kwargs)

    monkeypatch.setattr(sites, "pattern_pass", counted)
    assert sites.fitted_origins(prob, shapes, Build(scene), ranked, float("inf"), counts=counts) == again
    assert not set(laid) & set(ranked[:sites.FITTED])  # only the shifted passes are laid


def test_lattice_with_upper_layer_round_trips_through_json(tmp_path):
    from dataclasses import asdict

    from geometry.blocks import get_block

    lat = lattice_for(get_block("tetrapod:2.0"), "tetrapod:2.0")
    back = InterlockLattice(**json.loads(json.dumps(asdict(lat))))
    assert back == lat and isinstance(back.upper, UpperLayer)
    assert back.scaled(2.0).upper.dx == pytest.approx(2.0 * lat.upper.dx)


class _CheckedAnnealing(Annealing):
    """Annealing that checks each accepted move independently before applying it."""

    def __init__(self, problem, **kw):
        super().__init__(**kw)
        self.problem = problem
        self.applied = 0
        self.energies: list[tuple[float, float]] = []

    def _apply(self, build, energy, key, c):
        others = [(k, build.block, build.poses[k]) for k in build.order if k != key]
        assert collisions(others + [(-5, build.block, c.pose)], threshold=0.0) == []
        super()._apply(build, energy, key, c)
        self.applied += 1
        incremental = energy.total(len(build), build.porosity.percent,
                                   sum(1 for s in build.supports.values() if -1 not in s and len(s) < 3))
        self.energies.append((incremental, energy_of(self.problem, build)))


def test_annealing_never_accepts_a_collision_and_its_energy_is_exact(tiny):
    pr = problem(tiny)
    start = BeamSearch(restarts=1, origins=3).run(pr, None, np.random.default_rng(1))
    a = _CheckedAnnealing(pr, iterations=300, jitter_xy=0.3)
    out = a.run(pr, start, np.random.default_rng(2))
    assert a.applied > 0, "no move was accepted: the test would check nothing"
    for incremental, full in a.energies:
        assert incremental == pytest.approx(full, abs=1e-9)
    assert out.stats.energy == pytest.approx(energy_of(pr, out.build), abs=1e-9)
    assert_valid(tiny, out.build)


def test_annealing_fills_a_short_layout(tiny):
    """A layout whose crane sequence stopped three blocks early gets blocks back.

    The last three blocks placed go, not the first: a crown of the first row,
    lowered again at its own place, catches on the level blocks dropped
    after it and ends out of the zone, so no crane can put it back.

    A random search: over four streams, one at least must add a block (on one 2-core machine
    streams 1 and 3 did, on another stream 0; last-bit differences between CPUs change the
    drops' outcomes), and each that does lowers the energy.
    """
    pr = problem(tiny)
    start = BeamSearch(restarts=1, origins=3).run(pr, None, np.random.default_rng(1))
    short = start.build.copy()
    for k in short.order[-3:]:
        short.remove(k)
    anneal = Annealing(iterations=300)
    outs = [anneal.run(pr, Phase(short, origin=start.origin), np.random.default_rng(s)).build
            for s in range(4)]
    grown = [out for out in outs if len(out) > len(short)]
    assert grown
    assert all(energy_of(pr, out) < energy_of(pr, short) for out in grown)


def test_cpsat_returns_the_known_optimum_on_a_tiny_candidate_set(tiny):
    """Brute force over every subset of a small candidate set against CP-SAT."""
    pr = problem(tiny)
    c = CpSat(origins=1, jitter=2)
    cands = c.candidates(pr, [(0.3, 0.2)], np.random.default_rng(0))[:14]
    conflicts, before = c.relations(pr, cands)
    values = [v for *_, v in cands]
    assert len(conflicts) >= 3, "the set must have conflicts for the test to mean anything"
    for limit in (3, 6, len(values)):
        best = 0.0
        for r in range(limit + 1):
            for subset in itertools.combinations(range(len(values)), r):
                s = set(subset)
                if any(i in s and j in s for i, j in conflicts):
                    continue
                best = max(best, sum(values[i] for i in subset))
        chosen, objective, bound, status = c.solve(values, conflicts, limit, seed=0)
        assert status == "OPTIMAL"
        assert objective == pytest.approx(best, abs=1e-5)
        assert bound == pytest.approx(best, abs=1e-5)
        assert len(chosen) <= limit and not any(i in chosen and j in chosen for i, j in conflicts)


def _light(seed_scene, seed, seconds=120, cover=True):
    return optimize(seed_scene, seed=seed, time_limit=seconds, cover=cover,
                    strategies=[BeamSearch(restarts=1, origins=3), Annealing(iterations=60)])


@pytest.fixture(scope="module")
def light_tiny_1(tiny):
    """``_light(tiny, 1)``, run once for the tests that read it (about 40 s)."""
    return _light(tiny, 1)


@pytest.fixture(scope="module")
def plain_tiny_1(tiny):
    """``_light(tiny, 1)`` without the coverage attempts and moves (about 8 s)."""
    return _light(tiny, 1, cover=False)


def _poses(layout):
    return {json.dumps([list(p.pose.position), list(p.pose.quaternion)]) for p in layout.blocks}


def test_a_covered_attempt_that_falls_short_is_not_kept(tiny, light_tiny_1, plain_tiny_1):
    """On ``tiny`` the first layout reaches its count and porosity and leaves 19 % bare; the
    attempts with toe rows first fall short of the count there (rows on a 4 m slice), so the
    layout is the one without them, byte for byte, but for the blocks the covering repair moved.
    With time left after each, ``COVER_ATTEMPTS`` of them are made (one until 2026-11-27)."""
    from optimizer.api import COVER_ATTEMPTS

    r, plain = light_tiny_1, plain_tiny_1
    attempts = next(p for p in r.phases if p["strategy"] == "attempts")
    toes = [p for p in r.phases if p["strategy"] == "toe"]
    assert COVER_ATTEMPTS > 1 and len(toes) == COVER_ATTEMPTS  # each found the time
    covered = toes[-1]["attempt"]
    assert covered == attempts["attempts"] and all(t["placed"] > 0 for t in toes)
    assert [t["attempt"] for t in toes] == list(range(covered - COVER_ATTEMPTS + 1, covered + 1))
    assert all(attempts["blocks"][t["attempt"] - 1] < tiny.required_blocks for t in toes)
    assert attempts["chosen"] < toes[0]["attempt"]
    assert attempts["bare_share_percent"][attempts["chosen"] - 1] > 5.0
    assert not any(p["strategy"] in ("toe", "cover") for p in plain.phases)
    moves = next(p for p in r.phases if p["strategy"] == "cover")
    assert moves["attempt"] == attempts["chosen"] and moves["moved"] > 0 and moves["stood"]
    assert 1 <= len(_poses(r.layout) - _poses(plain.layout)) <= moves["moved"]  # a block may move twice
    assert len(r.layout.blocks) == len(plain.layout.blocks)
    # The summary says the mound is not covered, and what came of the attempt and the moves.
    said = r.summary().splitlines()[-1]
    assert said.startswith("the mound is not covered: ") and "over H/2" in said
    # Short in its search ("placed 21 of 25 blocks") or in its settle ("... but 21 of 25 blocks stood").
    assert f"{attempts['blocks'][covered - 1]} of {tiny.required_blocks} blocks" in said
    assert "so it was not kept" in said
    assert f"; {COVER_ATTEMPTS} attempts with toe rows first were made: an attempt" in said
    assert said.endswith("can reach: shoha scene info SCENE --floor)")
    assert ("to bare areas took the bare share from" in said) == (moves["moved"] > 0 and moves["stood"])
    assert "toe rows" not in plain.summary()


def test_an_all_or_nothing_attempt_left_short_is_not_settled(tiny):
    """The coverage attempt counts only if its search reaches the count: a build left short is
    returned as the strategies left it, unconfirmed, where an ordinary attempt is settled."""
    short = replace(problem(tiny), required=tiny.required_blocks + 40)
    end = short.deadline

    def run(all_or_nothing):
        return _attempt(short, [BeamSearch(restarts=1, origins=3)], tiny, None, np.random.default_rng(1),
                        True, end, 1, all_or_nothing=all_or_nothing)

    settled, unsettled = run(False), run(True)
    assert len(unsettled.build) < short.required
    assert settled.settle and settled.stable is not None
    assert unsettled.settle == {} and unsettled.stable is None
    assert not unsettled.reached(short)


def test_the_refill_sweeps_first_where_the_confirming_settle_took_blocks_out(tiny, monkeypatch):
    """``_attempt`` tells the refill's sweep where the blocks stood that the settle confirming a
    search at its count took out (``taken_out``). The settle is a stand-in here that takes out
    the last block laid, then confirms what is left with the real one; the sweep is asked
    first at that block's place, and only there."""
    import optimizer.api as api
    from optimizer.search.fill import PocketFill
    from optimizer.search.physics import raised_check

    pr = replace(problem(tiny), required=5)
    out: list[np.ndarray] = []
    real_confirm = api.confirm

    def confirm(problem_, build, rng, origin=None, end=None, whole=False):
        if not out:  # the first confirmation: the search's layout
            k = build.order[-1]
            out.append(build.poses[k].position[:2].copy())
            build = build.copy()
            build.remove(k)
        return real_confirm(problem_, build, rng, origin, end, whole)

    asked: list[np.ndarray | None] = []
    real_sweeping = PocketFill.sweeping

    def sweeping(self, first=None):
        asked.append(first)
        return real_sweeping(self, first=first)

    monkeypatch.setattr(api, "confirm", confirm)
    monkeypatch.setattr(PocketFill, "sweeping", sweeping)
    strategies = [BeamSearch(restarts=1, origins=3), PocketFill(accept=raised_check, draws=60, checks=10)]
    attempt = _attempt(pr, strategies, tiny, None, np.random.default_rng(1), True, pr.deadline, 1)
    assert attempt.searched == pr.required and out, "the search must reach its count for the test to mean it"
    assert asked and asked[0] is not None
    np.testing.assert_allclose(asked[0], [out[0]])
    assert any(p["strategy"] == "refill" for p in attempt.phases)


def test_a_refill_is_tried_where_the_time_left_holds_one_more_confirmation_and_a_quarter(tiny, monkeypatch):
    """A confirming settle that takes blocks out is followed by a refill where the time left
    before the confirmations' end holds the refill's own confirmation, taken as long as the last
    one with a quarter to spare: the confirmation is stopped at its end anyway. Here the
    confirmations are stand-ins on a clock that moves only when they run: each takes 10 s, and
    15 s are left after the first. (With twice the last confirmation kept free, ``big-shake`` seed
    2 ended at 267 of 269 with 56 s of its 134.5 s unused, stop 80; so did seed 1 at f086e50.)"""
    import optimizer.api as api
    from optimizer.search.fill import PocketFill
    from optimizer.search.physics import Confirmation, raised_check

    now = [0.0]
    pr = replace(problem(tiny), required=5, clock=lambda: now[0], deadline=1e9)
    calls: list[int] = []

    def confirm(problem_, build, rng, origin=None, end=None, whole=False):
        calls.append(len(build))
        if len(calls) == 1:  # the search's layout: its last block does not stand
            build = build.copy()
            build.remove(build.order[-1])
        now[0] += 10.0
        return build, Confirmation(True, 0.0, 0.0, [], 1, 0, 0, 10.0)

    monkeypatch.setattr(api, "confirm", confirm)
    strategies = [BeamSearch(restarts=1, origins=3), PocketFill(accept=raised_check, draws=60, checks=10)]
    attempt = _attempt(pr, strategies, tiny, None, np.random.default_rng(1), True, 25.0, 1)
    assert calls[0] == pr.required, "the search must reach its count for the test to mean it"
    refills = [p for p in attempt.phases if p["strategy"] == "refill"]
    assert refills and refills[0]["added"] == 1, attempt.phases
    assert len(attempt.build) == pr.required and calls == [pr.required, pr.required]
    assert now[0] <= 25.0 + 10.0  # its confirmation, the second, began before the end


@pytest.mark.parametrize("stands, searches", [(True, 1), (False, 3)])
def test_beam_restarts_only_until_a_full_layout_stands(tiny, stands, searches):
    """The next origin is searched only while no full layout stands: results, not the clock,
    decide how much work a seed does. The judge is the beam's input here, not under test; the
    target is the first layout's own porosity, which it meets."""
    pr = replace(problem(tiny), required=5)
    first = BeamSearch(restarts=1, origins=3).run(pr, None, np.random.default_rng(1)).build
    pr = replace(pr, target=first.porosity.percent)
    beam = BeamSearch(restarts=3, origins=3, judge=lambda p, b: stands)
    phase = beam.run(pr, None, np.random.default_rng(1))
    assert len(phase.build) == 5
    assert phase.stats.restarts == searches


@pytest.mark.parametrize("near, searches", [(True, 1), (False, 3)])
def test_beam_restarts_go_on_while_a_full_layout_misses_the_target(tiny, near, searches):
    """A full layout that stands ends the restarts only if its porosity is within the window
    of the target; otherwise the next origins are searched for one nearer it."""
    pr = replace(problem(tiny), required=5)
    first = BeamSearch(restarts=1, origins=3).run(pr, None, np.random.default_rng(1)).build
    target = first.porosity.percent if near else 0.0
    beam = BeamSearch(restarts=3, origins=3, judge=lambda p, b: True)
    phase = beam.run(replace(pr, target=target), None, np.random.default_rng(1))
    assert len(phase.build) == 5
    assert phase.stats.restarts == searches


def _origins_ranked(monkeypatch) -> list[int]:
    """How many origins each call of the beam's ``rank_origins`` ranks, from now on."""
    from optimizer.search import beam as beam_module

    ranked: list[int] = []
    real = beam_module.rank_origins

    def counted(*args, **kwargs):
        ranked.append(kwargs.get("n", args[7] if len(args) > 7 else None))  # origins on a scan
        return real(*args, **kwargs)

    monkeypatch.setattr(beam_module, "rank_origins", counted)
    return ranked


def test_a_beam_started_late_in_the_run_does_the_same_work(tiny, monkeypatch):
    """How many origins the beam ranks follows from the run's span, not from the time left: a
    beam started with a fifth of the span left (after slow steps) ranks as many, and lays the
    same layout, as one started at once. The clock stands still, so no deadline binds."""
    ranked = _origins_ranked(monkeypatch)
    still = problem(tiny, clock=lambda: 0.0)
    early = replace(still, deadline=100.0, span=100.0)
    late = replace(still, deadline=20.0, span=100.0)
    runs = [BeamSearch(restarts=1, origins=3).run(pr, None, np.random.default_rng(1)) for pr in (early, late)]
    layouts = [run.build.layout({}).dumps() for run in runs]
    assert ranked[0] == ranked[1] == BeamSearch().scan_origins
    assert layouts[0] == layouts[1]
    # Without a span the time left is what there is to plan for: fewer origins late in a run.
    BeamSearch(restarts=1, origins=3).run(replace(late, span=None), None, np.random.default_rng(1))
    assert ranked[2] < ranked[0]


def test_the_settles_repair_plans_its_ranking_from_its_own_time(tiny, monkeypatch):
    """The confirming settle's repair beam has a short deadline of its own: it ranks as few
    origins as that time asks, not as many as the whole run's span would."""
    from optimizer.search import physics

    ranked = _origins_ranked(monkeypatch)
    still = replace(problem(tiny, clock=lambda: 0.0), deadline=600.0, span=600.0)
    physics._repaired(still, Build(tiny), None, 6.0, np.random.default_rng(1))
    assert ranked == [4]  # 16 origins for a 3 s plan is cut to the least, 4


def test_same_seed_same_layout_different_seed_different(tiny, plain_tiny_1):
    """The pipeline gives one layout a seed, and another seed gives another (without the
    coverage attempts, which take most of a run on ``tiny``: with them, the next test)."""
    assert plain_tiny_1.layout.dumps() == _light(tiny, 1, cover=False).layout.dumps()
    assert plain_tiny_1.layout.dumps() != _light(tiny, 2, cover=False).layout.dumps()


@pytest.mark.slow
def test_the_coverage_attempts_give_one_layout_a_seed(tiny, light_tiny_1):
    """The whole pipeline, coverage attempts and moves too, gives one layout a seed (a second
    run of about 45 s, so not in ``make test``)."""
    assert light_tiny_1.layout.dumps() == _light(tiny, 1).layout.dumps()


def test_a_run_short_of_its_count_tries_again_and_keeps_the_best(tiny):
    """More blocks asked of the slice than fit: every attempt ends short with its time left, so
    the pipeline runs ``ATTEMPTS`` times, each on a stream of its own, and returns the best layout."""
    from optimizer.api import ATTEMPTS

    scene = replace(tiny, required_blocks=2 * tiny.required_blocks)
    r = optimize(scene, seed=1, time_limit=300,
                 strategies=[BeamSearch(restarts=1, origins=1), Annealing(iterations=20)])
    summary = r.phases[-1]
    assert summary["strategy"] == "attempts" and summary["attempts"] == ATTEMPTS
    assert sorted({p["attempt"] for p in r.phases[:-1]}) == list(range(1, ATTEMPTS + 1))
    counts, porosities = summary["blocks"], summary["porosity_percent"]
    assert max(counts) < scene.required_blocks
    # Every attempt stands (the settle repairs what does not): the chosen one has the most blocks,
    # then the porosity nearest the target.
    best = max(range(ATTEMPTS), key=lambda i: (counts[i], -abs(porosities[i] - scene.target_porosity)))
    assert summary["chosen"] == best + 1
    assert r.blocks == counts[best] and r.porosity_percent == pytest.approx(porosities[best], abs=1e-6)
    assert r.collisions == 0 and r.out_of_tolerance == 0 and r.stable is True
    # The attempts are not copies of one another: each drew on a stream of its own.
    assert len({round(p, 9) for p in porosities}) > 1 or len(set(counts)) > 1


def test_an_attempt_draws_the_same_however_much_the_one_before_it_drew(tiny):
    """Each attempt draws from a stream of its own (``api.streams``): what an attempt before it
    drew, more where its time let it search longer, does not change the next one's draws. A
    stand-in strategy places nothing, so every attempt ends short with its time left, and
    records its first draws; the first attempt draws 0 or 1000 numbers more."""
    from optimizer.api import ATTEMPTS
    from optimizer.search.problem import Strategy

    class Draws(Strategy):
        name = "draws"

        def __init__(self, extra):
            self.extra, self.first = extra, []

        def run(self, problem_, previous, rng):
            self.first.append(rng.random(3).tolist())
            if len(self.first) == 1:
                rng.random(self.extra)
            return previous if previous is not None else Phase(Build(problem_.scene))

    runs = []
    for extra in (0, 1000):
        draws = Draws(extra)
        optimize(tiny, seed=4, time_limit=60, strategies=[draws], settle_layout=False, cover=False)
        runs.append(draws.first)
    assert ATTEMPTS > 1 and len(runs[0]) == len(runs[1]) == ATTEMPTS
    assert runs[0] == runs[1]
    assert len({tuple(d) for d in runs[0]}) == ATTEMPTS  # and the attempts' streams differ


def test_another_attempt_needs_only_the_last_ones_search_time(tiny):
    """An attempt short of its count (or off its porosity window) is followed by another where
    its search, not its settles and refills, fits again before the deadline; one that reaches
    the count within its window, or whose search would not fit, is the last."""
    from optimizer.api import _Attempt
    from optimizer.search.build import Build

    # 50 s in all, 20 of them its search: the refills after a short search took the rest.
    short = _Attempt(Build(tiny), [], {}, {}, True, seconds=50.0, search_seconds=20.0)
    at = replace(problem(tiny), deadline=80.0)
    assert short.another(at, now=50.0)  # 50 + 20 <= 80, though 50 + 50 is not
    assert not short.another(at, now=61.0)  # 61 + 20 > 80
    assert replace(short, stable=False).another(at, now=50.0)  # a layout that falls: again too
    # The count reached (none required; the empty build's porosity is 100 %): the last only
    # within its porosity window.
    assert short.another(replace(at, required=0), now=0.0)
    assert not short.another(replace(at, required=0, target=100.0), now=0.0)


def test_optimize_result_is_valid_on_tiny(tiny):
    """The pipeline with the bound step (beam, fill, anneal, CP-SAT, settle) on a 25-block, 4 m slice of mini.

    Validity is never traded for count. The count itself is the slow mini
    acceptance test's business; the slice's ends cost it a block or two, so
    here a floor of 80 % only catches a broken search. The coverage attempt is left out
    (``cover=False``): its own tests are below.
    """
    r = optimize(tiny, seed=1, time_limit=120, bound=True, cover=False)
    assert r.collisions == 0 and r.out_of_tolerance == 0
    assert r.stable is True
    assert r.blocks >= 0.8 * tiny.required_blocks
    names = [p["strategy"] for p in r.phases]
    # First whether to spread the pattern: not on a slice whose count covers its crest.
    assert names[:5] == ["spread", "beam", "fill", "anneal", "cpsat"] and r.phases[0]["factor"] == 1.0
    if r.blocks == tiny.required_blocks:  # reached at the first attempt: no other
        assert set(names[5:]) <= {"refill"} and {p["attempt"] for p in r.phases} == {1}
    assert r.gap["seconds"] > 0.0  # the bound's cost is reported
    if r.blocks < tiny.required_blocks:
        assert r.summary().startswith(f"{tiny.required_blocks} required, {r.blocks} fit: porosity ")
    assert r.gap["gap_percent"] >= 0.0 and r.gap["bound_m3"] >= r.gap["heuristic_m3"] - 1e-5
    # What the blocks lose outside the design prism, against each block clipped on its own.
    inside = volumes_inside(r.layout.placed(), tiny.design.polytope).sum()
    assert r.outside_design_prism_m3 == pytest.approx(r.blocks * tiny.block.volume - inside, abs=1e-4)
    assert r.outside_design_prism_m3 > 0.1  # a slice's blocks stick out at its ends and slopes


def test_summary_says_when_porosity_misses_the_target():
    """A full count off target by more than 1 point gets a plain second line."""
    from optimizer.api import OptimizeResult

    full = OptimizeResult(layout=None, porosity_percent=53.18, blocks=81, required_blocks=81,
                          target_porosity_percent=50.0, collisions=0, out_of_tolerance=0, stable=True,
                          seconds=49.0, outside_design_prism_m3=12.82)
    assert full.summary().endswith("\nporosity is 3.18 points above the target: 12.8 m³ of the blocks "
                                   "lies outside the design prism, in the tolerance zone")
    assert "points" not in replace(full, porosity_percent=50.9).summary()
    assert full.summary().count("\n") == 1
    # Kept blocks one inside another: their overlap is in the figure, and it need not be in the zone.
    overlapping = replace(full, collisions=4)
    assert overlapping.summary().endswith("12.8 m³ of the blocks lies outside the design prism or inside "
                                          "other blocks")
    low = replace(full, porosity_percent=47.0)
    assert low.summary().endswith("\nporosity is 3.00 points below the target")
    short = replace(full, blocks=70)  # the count's own line says what is wrong
    assert short.summary().startswith("81 required, 70 fit") and "points" not in short.summary()
    # Blocks the confirming settle took out are why a count ends below what the search showed.
    lost = replace(short, searched=78)
    assert "\nthe search placed 78 blocks; the confirming settle took out" in lost.summary()
    assert lost.summary().splitlines()[1].endswith("and 70 stood in the end")
    assert "settle took out" not in replace(short, searched=70).summary()  # the search was short itself
    assert "settle took out" not in replace(full, searched=81).summary()
    # The coverage figures stay on the first line, the aims missed on a line of their own.
    covered = {"bare_share_percent": 15.8, "max_bare_m": 2.22, "worst_point": [6.0, 10.6, 0.0],
               "bare_distance_m": 0.83, "spacing_m": 0.25}
    lines = replace(lost, coverage=covered).summary().splitlines()
    assert lines[0].endswith("; bare 15.8%, farthest 2.22 m from a block")
    assert lines[1].startswith("the search placed") and lines[2].startswith("the mound is not covered")


def test_summary_says_when_the_blocks_placed_hold_more_outside_than_the_count_may():
    """A layout short of its count whose blocks already hold more volume outside the design prism
    than the whole count may within the porosity window says that no completion of it reaches
    both; one under that budget, a full one, or one with collisions (overlaps count as outside)
    does not."""
    from optimizer.api import OptimizeResult

    short = OptimizeResult(layout=None, porosity_percent=58.2, blocks=65, required_blocks=75,
                           target_porosity_percent=50.0, collisions=0, out_of_tolerance=0, stable=True,
                           seconds=92.0, outside_design_prism_m3=19.7, outside_budget_m3=14.0)
    assert short.summary().endswith(
        "\nthe 65 blocks placed already hold 19.7 m³ outside the design prism, where all 75 may hold "
        "at most 14.0 m³ with the porosity within 1 point of its target: no layout that keeps these "
        "blocks where they are reaches both the count and the porosity")
    # Figures that round alike at one digit get more (0.5 and 0.5 read as a contradiction).
    close = replace(short, outside_design_prism_m3=0.5341, outside_budget_m3=0.4987)
    assert "already hold 0.53 m³ outside the design prism, where all 75 may hold at most 0.50 m³" \
        in close.summary()
    for other in (replace(short, outside_design_prism_m3=13.9), replace(short, blocks=75),
                  replace(short, collisions=2), replace(short, outside_budget_m3=None)):
        assert "placed already hold" not in other.summary()
    # A scene's own count under what its target asks: even all of it inside would not do.
    too_few = replace(short, outside_budget_m3=-3.0, outside_design_prism_m3=0.0)
    assert too_few.summary().endswith(
        "\neven all 75 blocks wholly inside the design prism would leave its porosity more than 1 "
        "point over the target: the required count is too small for the target porosity")


@pytest.mark.parametrize("name, over", [("mini-reference.json", False), ("mini-rows-seed1.json", True)])
def test_a_full_layout_holds_more_than_the_budget_outside_exactly_where_it_is_over_its_window(name, over):
    """``outside_budget`` against real layouts of the count, measured as ``optimize`` measures the
    volume outside (the blocks' volume less what fills the prism): ``mini``'s reference at 56.99 %
    is within it, the attempt with toe rows of seed 1 at 57.06 % over it, as each is within or
    over its porosity window."""
    from geometry.checks import check_layout
    from geometry.layout import read_layout
    from optimizer.api import outside_budget

    scene = load_scene("mini")
    placed = read_layout(ROOT / "tests" / "data" / name).placed()
    report = check_layout(scene, placed, with_coverage=False)
    assert report.blocks == scene.required_blocks
    outside = report.blocks * scene.block.volume - (1 - report.porosity_percent / 100) * scene.design_volume
    assert (outside > outside_budget(scene)) is over
    assert (report.porosity_percent > scene.target_porosity + 1.0) is over


def test_optimize_gives_its_result_the_scene_s_budget(tiny):
    """``optimize`` sets the budget its summary weighs from the scene it ran on."""
    from optimizer.api import optimize, outside_budget

    r = optimize(tiny, seed=1, time_limit=5.0, strategies=[BeamSearch(restarts=1, origins=1)],
                 settle_layout=False, cover=False)
    assert r.outside_budget_m3 == pytest.approx(outside_budget(tiny))


def test_the_runs_last_repair_goes_on_in_rounds_while_the_time_lasts(tiny, monkeypatch):
    """The covering repair at the end of ``optimize`` is asked for rounds of moves without
    bound (``rounds=None``: while each makes all its moves and the time lasts); the repairs
    made while attempts are weighed make one (the test above)."""
    import optimizer.api as api

    asked = []

    def repair_once(problem_, attempt, rng, number, end, rounds=1):
        asked.append(rounds)
        return attempt, None

    monkeypatch.setattr(api, "repair_once", repair_once)
    monkeypatch.setattr(api, "covered_attempts",
                        lambda problem_, strategies, tried, chosen, *args: (chosen, None))
    api.optimize(tiny, seed=1, time_limit=20.0, strategies=[BeamSearch(restarts=1, origins=1)])
    assert asked == [None]


@pytest.mark.parametrize("ending", ["not kept", "no time"])
def test_a_later_round_that_ends_the_rounds_is_counted_in_the_phase(monkeypatch, ending):
    """A round after the first that is not kept, or finds no time to be made, ends the rounds:
    the layout is the one before it, and its time is in the phase's seconds (a round not kept
    counts in ``rounds`` and ``tried``, not in ``moved``). The round itself is stood in for,
    on fake seconds: it takes 5 s."""
    from types import SimpleNamespace

    import optimizer.api as api

    now = [100.0]

    def round_(problem_, attempt, rng, number, end, unmoved):
        now[0] += 5.0
        if ending == "no time":
            return attempt, None
        return attempt, {"tried": 3, "moved": 12, "undone": 0, "adopted": True}

    monkeypatch.setattr(api, "_cover_round", round_)
    kept = api._Attempt(None, [], {}, {}, True, more_cover=True)
    phase = {"rounds": 1, "tried": 10, "moved": 12, "undone": 0, "seconds": 20.0, "stood": True}
    out = api.more_rounds(SimpleNamespace(clock=lambda: now[0]), kept, phase, None, 1, 200.0)
    assert out.more_cover is False and out.build is kept.build
    assert phase["seconds"] == 25.0 and phase["moved"] == 12 and "adopted" not in phase
    assert (phase["rounds"], phase["tried"]) == ((2, 13) if ending == "not kept" else (1, 10))


def test_summary_says_why_a_layout_written_does_not_stand():
    """A verdict that fails on blocks not kept (no time was left to take them out) gets its own line."""
    from optimizer.api import OptimizeResult

    short = OptimizeResult(layout=None, porosity_percent=68.0, blocks=34, required_blocks=64,
                           target_porosity_percent=40.0, collisions=0, out_of_tolerance=0, stable=False,
                           seconds=7.1, settle={"stable": False, "unstable": [13, 14, 17]})
    said = short.summary().splitlines()
    assert "NOT stable" in said[0]
    assert said[1].startswith("3 blocks did not stand when the layout was settled, and the time limit left")
    stood = replace(short, stable=True, settle={"stable": True, "unstable": []})
    assert "did not stand" not in stood.summary()
    one = replace(short, settle={"stable": False, "unstable": [2]}).summary()
    assert "\n1 block did not stand" in one
    # Only kept blocks fail: their own line names them, and none is said to be the time's.
    kept = replace(short, settle={"stable": False, "unstable": [2]},
                   kept={"blocks": 30, "colliding": [], "out_of_tolerance": [], "unstable": [2]})
    assert "did not stand" not in kept.summary() and "1 do not stand: 2" in kept.summary()
    # A diverged settle names no block.
    assert "named no block" in replace(short, settle={"stable": False, "unstable": []}).summary()


def test_time_limit_is_honoured_and_result_valid(tiny, monkeypatch):
    """4 s of a clock that advances with the work (tests/clock.py): the run keeps them, within 2 s."""
    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    r = optimize(tiny, seed=3, time_limit=4.0, clock=clock)
    assert r.seconds == clock() and r.seconds <= 4.0 + 2.0, f"{clock.drops} drops, {clock.settles} settles"
    assert clock() > 4.0 * 0.5, "the budget must bind for the test to mean anything"


def test_time_spent_before_the_run_counts_against_its_limit(tiny, monkeypatch):
    """``started``: what the caller spent before (reading a scene, cutting a mesh) is in the limit."""
    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    clock.t = 3.0  # the command began 3 fake seconds before it called optimize
    r = optimize(tiny, seed=3, time_limit=4.0, clock=clock, started=0.0)
    assert r.seconds == clock() and r.seconds <= 4.0 + 2.0
    assert clock() - 3.0 < 4.0 * 0.75, "the run itself must have had only what was left of the limit"
    assert r.collisions == 0 and r.out_of_tolerance == 0 and r.stable is True


def test_a_coverage_that_would_overrun_the_limit_is_left_out(tiny, monkeypatch):
    """Slender blocks made the final coverage take 137 s after a 10 s limit. Here each block's
    surface samples cost a fake second: the measure stops at the limit (+1 s), the result
    has no coverage and says so, and the run keeps its limit."""
    import geometry.coverage as cov

    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    samples = cov.block_samples

    calls = []

    def slow(block, spacing, most=None):
        clock.t += 1.0
        calls.append(1)
        return samples(block, spacing, most)

    monkeypatch.setattr(cov, "block_samples", slow)
    r = optimize(tiny, seed=3, time_limit=4.0, clock=clock, cover=False)
    assert r.blocks > 3 and r.coverage is None and r.seconds <= 4.0 + 2.0
    assert 0 < len(calls) < r.blocks, "the measure began, and stopped before its last block"
    assert "the coverage was not measured" in r.summary()
    with pytest.raises(cov.TimeUp):
        cov.coverage(tiny, r.layout.placed(), deadline=clock() + 2.5, clock=clock)
    monkeypatch.setattr(cov, "block_samples", samples)
    assert cov.coverage(tiny, r.layout.placed(), deadline=clock() + 0.5, clock=clock) is not None


def test_the_searchs_coverage_is_none_past_its_deadline(tiny):
    """The toe rows, the trim, the covering repair and the origin ranking measure coverage
    through ``Problem.coverage``: by the problem's deadline, or not at all (None), never
    after it."""
    from optimizer.search.problem import Problem

    placed = [(0, tiny.block, Pose([0.0, tiny.length / 2, 1.0], [1, 0, 0, 0]))]
    t = [0.0]

    def clock() -> float:
        t[0] += 1.0
        return t[0]

    lattice = lattice_for(tiny.block, tiny.block.name)
    assert Problem(tiny, 25, 56.0, lattice, deadline=0.5, clock=clock).coverage(placed) is None
    t[0] = 0.0
    report = Problem(tiny, 25, 56.0, lattice, deadline=1e9, clock=clock).coverage(placed)
    assert report is not None and report.bare_share_percent > 50.0


def test_short_limit_on_a_long_scene_is_honoured_and_places_blocks(tmp_path, monkeypatch):
    """A 2 km breakwater (about 12 000 blocks) in 4 s of a clock that advances with the work:
    one quick pass of the pattern over it would take 120 of them, so the origin ranking must
    stop at its deadline too, and leave the search its time to place what it can."""
    text = (ROOT / "geometry" / "scenes" / "mini.toml").read_text()
    long = tmp_path / "long.toml"
    long.write_text(text.replace("length_m = 12.220833333333333", "length_m = 2000.0"))
    scene = load_scene(long)
    assert scene.required_blocks > 10_000  # the edit took: not mini's 75
    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    r = optimize(scene, seed=1, time_limit=4.0, clock=clock)
    assert r.seconds <= 4.0 + 2.0, f"{clock.drops} drops, {clock.settles} settles"
    assert r.blocks > 0 and r.collisions == 0 and r.out_of_tolerance == 0 and r.stable is True
    assert r.summary().startswith(f"{scene.required_blocks} required, {r.blocks} fit: porosity ")


LOW_LONG = """name = "low-long"
block = "shake-4t"
[design]
crest_width_m = 6.0
height_m = 2.0
slope_rise_run = [1.0, 2.0]
length_m = 30.0
"""


def test_a_short_limit_keeps_room_for_the_settle_before_the_coverage(tmp_path, monkeypatch):
    """A 153-block mound under a 5 s limit: the final checks, the settles and the coverage ask
    more than the half of it a run keeps from its search. The capped reserve went to the checks
    and the coverage, the search ran to the moment the settle had to end, and the layout was
    written unsettled and unmeasured at 2.5 s (its settle took 0.2 s). Now the settle keeps its
    part before the coverage, and the coverage is measured up to the limit where its own
    estimate does not fit. On a clock that advances with the work (tests/clock.py)."""
    from optimizer.api import RESERVE_SHARE, check_reserve, coverage_reserve, kept_reserves, settle_reserve

    (tmp_path / "low.toml").write_text(LOW_LONG)
    scene = load_scene(tmp_path / "low.toml")
    n, limit = scene.required_blocks, 5.0
    assert check_reserve(scene, n) + coverage_reserve(scene) >= RESERVE_SHARE * limit  # the case
    checks, settles, measure = kept_reserves(scene, limit, n)
    assert checks == check_reserve(scene, n) and 0 < settles < settle_reserve(scene, n)
    assert measure == 0.0 and checks + settles + measure == pytest.approx(RESERVE_SHARE * limit)
    # A limit that holds them all keeps each whole.
    assert kept_reserves(scene, 120.0, n) == (check_reserve(scene, n), settle_reserve(scene, n),
                                              coverage_reserve(scene))
    # Drops cheap enough that the search lays over a hundred blocks by its deadline: a verdict on
    # them (two settles) is then estimated at over 2 s, the room it was once not left.
    clock = WorkClock(per_drop=0.0005, per_settle=0.05).install(monkeypatch)
    r = optimize(scene, seed=1, time_limit=limit, clock=clock)
    assert r.blocks > 100 and r.seconds <= limit + 2.0
    assert r.settle.get("skipped") is None and r.stable is not None, r.summary()
    assert r.coverage is not None, r.summary()


def test_cli_optimize_writes_the_contract_keys(tmp_path):
    out = tmp_path / "ref.json"
    r = shoha("optimize", TINY, "--out", str(out), "--seed", "1", "--time-limit", "10",
              "--strategy", "beam", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d) >= {"porosity_percent", "blocks", "collisions", "out_of_tolerance", "stable", "seconds",
                      "path"}
    assert d["path"] == str(out) and out.exists()
    assert isinstance(d["outside_design_prism_m3"], float) and d["outside_design_prism_m3"] >= 0.0
    # stdout is the JSON object alone; what the run found is said on stderr, as without --json.
    said = (f"{d['required_blocks']} required, {d['blocks']} fit: " if d["blocks"] < d["required_blocks"]
            else f"{d['blocks']} blocks, porosity ")
    assert said in r.stderr and f"wrote {out}" in r.stderr
    written = json.loads(out.read_text())
    assert written["format"] == "shoha-layout/1"
    # The scene is a file here: the layout names it relative to itself, and it resolves.
    assert not written["scene"].startswith("/")
    c = shoha("check", str(out), "--json")
    assert c.returncode == 0, c.stderr
    assert json.loads(c.stdout)["blocks"] == d["blocks"]


def test_cli_optimize_bad_input(tmp_path):
    r = shoha("optimize", "atlantis", "--out", str(tmp_path / "x.json"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    r = shoha("optimize", "mini", "--out", str(tmp_path / "x.json"), "--strategy", "magic")
    assert r.returncode == 2 and "magic" in r.stderr
    r = shoha("optimize", "mini", "--out", str(tmp_path / "x.json"), "--time-limit", "nan")
    assert r.returncode == 2
    for listed, said in (("beam,toe", "comes first"), ("toe", "besides toe")):
        r = shoha("optimize", "mini", "--out", str(tmp_path / "x.json"), "--strategy", listed)
        assert r.returncode == 2 and said in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.json").exists()


def test_toe_first_lays_the_rows_in_the_first_attempt_and_not_again(tmp_path):
    """``--strategy toe,...``: the rows along the toes come first in the first attempt, the
    beam lays the pattern around them, and no attempt lays rows a second time (a mound with time
    for one attempt only never made the attempt with rows, and its toes stayed bare)."""
    from optimizer.api import rows_first
    from optimizer.search.toe import ToeRows

    listed = rows_first([BeamSearch(restarts=1, origins=3), Annealing(iterations=20)])
    assert isinstance(listed[0], ToeRows) and sum(isinstance(s, ToeRows) for s in listed) == 1
    assert rows_first(listed)[1:] and sum(isinstance(s, ToeRows) for s in rows_first(listed)) == 1
    # The attempt with rows that follows a layout left bare is not made: the rows were laid.
    from optimizer.api import _Attempt, covered_attempt, streams

    tiny = load_scene(TINY)
    tried = [_Attempt(Build(tiny), [], {}, {}, True)]
    chosen, words = covered_attempt(problem(tiny), listed, tried, 0, streams(1), True, end=1e9)
    assert chosen == 0 and len(tried) == 1 and "laid first" in words
    out = tmp_path / "rows.json"
    r = shoha("optimize", TINY, "--out", str(out), "--seed", "1", "--time-limit", "20",
              "--strategy", "toe,beam,anneal", "--json")
    assert r.returncode == 0, r.stderr
    phases = json.loads(r.stdout)["phases"]
    first = [p["strategy"] for p in phases
             if p.get("attempt") == 1 and p["strategy"] not in ("tune", "spread")]
    assert first[:2] == ["toe", "beam"] and next(p for p in phases if p["strategy"] == "toe")["placed"] > 0
    # Each attempt made (an attempt short of its count starts over) lays its rows once, first.
    attempts = {p["attempt"] for p in phases if p["strategy"] == "beam"}
    assert [p["attempt"] for p in phases if p["strategy"] == "toe"] == sorted(attempts)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mini", "tetrapod-layer"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_reference_layout_is_valid(name, seed):
    """Acceptance: the required count (75 for ``mini``, 68 for ``tetrapod-layer``), 0 collisions,
    0 out of tolerance, stable, within 1 point of the scene's target (56 %, 50 %)."""
    scene = load_scene(name)
    r = optimize(scene, seed=seed, time_limit=120)
    assert r.blocks == scene.required_blocks and r.valid and r.stable is True, r.summary()
    assert abs(r.porosity_percent - scene.target_porosity) <= 1.0, r.summary()
    assert r.seconds <= 120


@pytest.mark.slow
def test_tetrapod_same_seed_same_layout_at_the_default_limit():
    """The contract's byte-for-byte rule at ``shoha optimize``'s default 120 s, on the
    scene whose origin ranking is the longest: its work is fixed by count, not cut by
    a clock (at a 40 % ranking cap, runs differed)."""
    scene = load_scene("tetrapod")
    a, b = (optimize(scene, seed=1, time_limit=120) for _ in range(2))
    assert a.layout.dumps() == b.layout.dumps()
    assert a.blocks == scene.required_blocks and a.valid, a.summary()


def test_a_run_short_of_room_says_so(tiny):
    """More blocks asked of the slice than fit, with time to spare: the pocket fill ends its
    search after ``patience`` rounds in a row in which nothing came to rest, and the result
    says that no room was found, with the fill's own figures."""
    from optimizer.search.fill import PocketFill
    from optimizer.search.physics import raised_check

    scene = replace(tiny, required_blocks=2 * tiny.required_blocks)
    fill = PocketFill(accept=raised_check, draws=100, checks=10, patience=2)
    r = optimize(scene, seed=1, time_limit=300, cover=False,
                 strategies=[BeamSearch(restarts=1, origins=1), fill])
    assert r.blocks < scene.required_blocks
    chosen = r.phases[-1]["chosen"] if r.phases[-1]["strategy"] == "attempts" else 1
    last = [p for p in r.phases if p.get("attempt") == chosen and "ended" in p][-1]
    assert last["ended"] == "room" and last["fruitless"] == 2
    assert f"lowered {last['drops']} blocks" in r.summary() and "no room was found for more:" in r.summary()


def test_a_shortfall_in_words():
    """What the last fill of the chosen attempt says, in words: nothing once the count is
    reached or where no fill ran."""
    from optimizer.api import shortfall

    room = {"strategy": "fill", "drops": 900, "checks": 60, "fruitless": 4, "ended": "room"}
    time_out = {"strategy": "refill", "drops": 10, "checks": 2, "fruitless": 0, "ended": "time"}
    assert shortfall([room], 75, 57, 120.0, kept=True).startswith(
        "no room was found for more around the kept blocks: the last pocket fill lowered 900 blocks")
    assert shortfall([room, time_out], 75, 57, 120.0, kept=False) == (
        "the search's time ran out (the limit of 120 s, less what the settle and checks keep): "
        "a longer --time-limit may place more")
    assert shortfall([room], 75, 75, 120.0, kept=False) is None
    # Without a fill: the strategies that ran, or CP-SAT's ground layer.
    assert shortfall([{"strategy": "beam"}], 75, 57, 120.0, kept=False).startswith(
        "the strategies run (beam) placed no more")
    solved = {"strategy": "cpsat", "candidates": 160, "placed": 52, "optimal": True, "skipped": False}
    assert shortfall([solved], 75, 52, 5.0, kept=False).startswith(
        "CP-SAT lays the ground layer only: the best choice among its 160 candidate poses on the "
        "foundation holds 52 blocks (proved optimal among them)")
    assert shortfall([solved], 75, 75, 5.0, kept=False) is None
    # Every block on the foundation: the zone's height beside the block's, after the fill's words.
    alone = shortfall([room], 61, 52, 120.0, kept=False, one_layer=(2.9534, 1.6601))
    assert alone.startswith(shortfall([room], 61, 52, 120.0, kept=False))
    assert alone.endswith("; all 52 blocks stand on the foundation, one layer, and the zone's crest is "
                          "2.95 m over its base against a block 1.66 m tall: a second layer of this "
                          "block found no room under it")
    assert shortfall([room, time_out], 61, 52, 120.0, kept=False, one_layer=(2.95, 1.66)) == (
        shortfall([room, time_out], 61, 52, 120.0, kept=False))  # out of time: not said


def test_a_layout_is_one_layer_only_where_every_block_stands_on_the_foundation(tiny):
    """``single_layer``: the zone's height over the base and the block's where every block rests
    on the ground; None once one rests on blocks alone, or with no block."""
    from optimizer.api import single_layer
    from optimizer.search import sites
    from optimizer.search.build import GROUND
    from optimizer.search.shapes import ShapeCache

    p = problem(tiny)
    laid = sites.pattern_pass(p, ShapeCache(tiny.block), Build(tiny), (0.0, 0.0))
    ground = [k for k in laid.order if GROUND in laid.supports[k]]
    assert 0 < len(ground) < len(laid), "the slice's pattern lays a second layer"
    assert single_layer(laid) is None
    first = Build(tiny)
    for k in ground:
        first.place_at(laid.poses[k])
    assert single_layer(first) == (tiny.tolerance.z_top - tiny.design.z_bottom, tiny.block.height)
    assert single_layer(Build(tiny)) is None


def test_a_mound_shorter_than_a_block_gets_no_block_and_no_error(tmp_path):
    """A mound 0.3 m long for a 1.66 m block: the window where a block's centroid may fall is
    empty (it was a reversed range, and the beam's random drop raised), so nothing is placed."""
    from optimizer.search.build import fill_window

    path = tmp_path / "slice.toml"
    path.write_text('block = "shake-4t"\n[design]\ncrest_width_m = 4.0\nheight_m = 3.0\n'
                    'slope_rise_run = [3.0, 4.0]\nlength_m = 0.3\n')
    scene = load_scene(path)
    (x0, x1), (y0, y1) = fill_window(scene)
    assert x0 <= x1 and y0 <= y1
    result = optimize(scene, seed=1, time_limit=5.0, settle_layout=False, cover=False)
    assert result.blocks == 0 and result.collisions == 0


@pytest.mark.parametrize("kept, made", [((True, True), 2), ((True, False), 2), ((True, None), 1),
                                        ((False, True), 2), ((False, None), 1), ((None, None), 0)])
def test_the_words_of_the_attempts_with_rows_are_those_of_the_one_kept(monkeypatch, kept, made):
    """``covered_attempts`` around its calls of ``covered_attempt`` (stood in for here: each call
    makes an attempt or not, kept or not). The words are those of the attempt kept, else of the
    last one made, led by how many were made where more than one; a second attempt kept is
    told the bare share of the layout without rows, not of the first attempt with them. Each
    attempt kept is repaired (``cover_repair``, stood in for too) before the next is made, and
    the next is weighed against the repaired one."""
    from types import SimpleNamespace

    import optimizer.api as api

    monkeypatch.setattr(api, "COVER_ATTEMPTS", 2)  # as many as the stand-in's cases make
    calls, events = [], []
    plain = SimpleNamespace(coverage=SimpleNamespace(bare_share_percent=15.0), seconds=1.0, phases=[])
    tried = [plain]

    def stand_in(problem_, strategies, tried_, chosen, stream, settle_layout, end, needs=None, without=None,
                 number=1):
        calls.append(without)
        events.append(("attempt", tried_[chosen].coverage.bare_share_percent))
        keep = kept[len(calls) - 1]
        if keep is None:
            return chosen, None if len(calls) > 1 else "no time was left"
        tried_.append(SimpleNamespace(coverage=SimpleNamespace(bare_share_percent=9.0), seconds=1.0,
                                      phases=[]))
        return (len(tried_) - 1 if keep else chosen), f"attempt {len(calls)}" + (" kept" if keep else "")

    def repair(problem_, attempt, rng, number, end, rounds=1):
        events.append(("repair", number))
        assert rounds == 1, "while attempts are weighed a repair makes one round of moves"
        moved = SimpleNamespace(coverage=SimpleNamespace(bare_share_percent=7.0), seconds=1.0,
                                phases=attempt.phases)
        return moved, {"strategy": "cover", "attempt": number, "seconds": 0.0}

    monkeypatch.setattr(api, "covered_attempt", stand_in)
    monkeypatch.setattr(api, "cover_repair", repair)
    chosen, words = api.covered_attempts(SimpleNamespace(now=lambda: 0.0), [], tried, 0, lambda step, n: None,
                                         True, 0.0)
    assert len(tried) == 1 + made
    # The kept attempts' repairs, each before the next attempt, which is weighed against it.
    expected_events = {(True, True): [("attempt", 15.0), ("repair", 2), ("attempt", 7.0), ("repair", 3)],
                       (True, False): [("attempt", 15.0), ("repair", 2), ("attempt", 7.0)],
                       (True, None): [("attempt", 15.0), ("repair", 2), ("attempt", 7.0)],
                       (False, True): [("attempt", 15.0), ("attempt", 15.0), ("repair", 3)],
                       (False, None): [("attempt", 15.0), ("attempt", 15.0)],
                       (None, None): [("attempt", 15.0)]}[kept]
    assert events == expected_events
    assert all(t.phases == [{"strategy": "cover", "attempt": i + 1, "seconds": 0.0}]
               for i, t in enumerate(tried) if ("repair", i + 1) in events)
    expected = {2: f"{made} attempts with toe rows first were made: ", 1: "", 0: ""}[made]
    if kept[0] is None:
        assert chosen == 0 and words == "no time was left"
    elif kept == (True, True):
        assert chosen == 2 and words == expected + "attempt 2 kept" and calls == [None, 15.0]
    elif kept[0]:
        assert chosen == 1 and words == expected + "attempt 1 kept"
    elif kept[1]:
        assert chosen == 2 and words == expected + "attempt 2 kept" and calls == [None, 15.0]
    else:
        assert chosen == 0 and words == "attempt 1"



def test_the_next_attempt_with_rows_is_timed_without_the_moves_that_weighed_the_last(monkeypatch):
    """``covered_attempts`` tells the next attempt with rows how long the last one took, without
    the covering moves made within it to weigh it (``covered_attempt``, stood in for: 10 s, of
    which 4 s of moves on the attempt it made and 1 s on the one it was weighed against)."""
    from types import SimpleNamespace

    import optimizer.api as api

    monkeypatch.setattr(api, "COVER_ATTEMPTS", 2)
    now, told = [0.0], []
    plain = SimpleNamespace(coverage=SimpleNamespace(bare_share_percent=15.0), seconds=1.0, phases=[])
    tried = [plain]

    def stand_in(problem_, strategies, tried_, chosen, stream, settle_layout, end, needs=None, without=None,
                 number=1):
        told.append(needs)
        now[0] += 10.0
        tried_[chosen].phases.append({"strategy": "cover", "attempt": chosen + 1, "seconds": 1.0})
        made = {"strategy": "cover", "attempt": len(tried_) + 1, "seconds": 4.0}
        tried_.append(SimpleNamespace(coverage=SimpleNamespace(bare_share_percent=9.0), seconds=1.0,
                                      phases=[made]))
        return chosen, "covered no better"

    monkeypatch.setattr(api, "covered_attempt", stand_in)
    api.covered_attempts(SimpleNamespace(now=lambda: now[0]), [], tried, 0, lambda step, n: None, True, 0.0)
    assert told == [None, 5.0]


def test_the_layout_kept_is_repaired_once(monkeypatch):
    """``repair_once``: a layout that ``covered_attempts`` repaired already (its last phase is
    ``cover``) is not repaired again, and its phase is the one returned; another is repaired,
    and its phase appended (``cover_repair`` stood in for)."""
    from types import SimpleNamespace

    import optimizer.api as api

    calls = []

    def repair(problem_, attempt, rng, number, end, rounds=1):
        calls.append(number)
        return SimpleNamespace(phases=attempt.phases), {"strategy": "cover", "attempt": number}

    monkeypatch.setattr(api, "cover_repair", repair)
    done = {"strategy": "cover", "attempt": 2}
    repaired = SimpleNamespace(phases=[{"strategy": "beam", "attempt": 2}, done])
    assert api.repair_once(None, repaired, None, 2, 0.0) == (repaired, done) and calls == []
    plain = SimpleNamespace(phases=[{"strategy": "beam", "attempt": 1}, {"strategy": "anneal", "attempt": 1}])
    kept, phase = api.repair_once(None, plain, None, 1, 0.0)
    assert calls == [1] and phase == {"strategy": "cover", "attempt": 1} and kept.phases[-1] == phase
    assert len(plain.phases) == 3  # one list: the attempt's phases are the repaired one's


@pytest.mark.parametrize("left, adopted", [(25.0, True), (19.0, False)])
def test_a_failed_settle_is_taken_where_it_left_the_blocks_where_two_verdicts_fit(tiny, monkeypatch, left,
                                                                                     adopted):
    """A confirmation whose first verdict fails takes the layout where that settle left it, and
    judges it, wherever the time left after the verdict holds two more verdicts and a second,
    as a repair round needs: not only where it holds three. The verdicts are stand-ins here,
    each 10 s on a clock that moves only with them; the layout as settled stands. With 25 s
    left it is taken so, every block kept; with 19 s there is no time for it, nor for a repair,
    and what the verdict failed is taken out and what is left judged. (With three verdicts
    needed, ``big-shake`` seed 2 run beside another lost 41 and 69 of 269 blocks to repairs,
    where the layout as settled stood with 267: stop 80.)"""
    from types import SimpleNamespace

    import optimizer.search.physics as physics
    from optimizer.search.shapes import ShapeCache
    from optimizer.search.sites import pattern_pass

    now = [0.0]
    pr = replace(problem(tiny), required=6, clock=lambda: now[0], deadline=1e9)
    build = pattern_pass(pr, ShapeCache(tiny.block), Build(tiny), (0.0, 0.0))
    assert len(build) == 6
    last = build.order[-1]
    verdicts = []

    def verdict(problem_, placed, rng, movable=None, side_by_side=None):
        now[0] += 10.0
        verdicts.append(len(placed))
        fails = len(verdicts) == 1
        return SimpleNamespace(stable=not fails, unstable_ids=[last] if fails else [], diverged=False,
                               max_displacement_m=0.0, max_rotation_deg=0.0)

    def settled_layout(problem_, b, result, rng):
        now[0] += 10.0
        return b, SimpleNamespace(stable=True, unstable_ids=[], diverged=False, max_displacement_m=0.0,
                                  max_rotation_deg=0.0)

    monkeypatch.setattr(physics, "verdict", verdict)
    monkeypatch.setattr(physics, "settled_layout", settled_layout)
    out, conf = physics._confirm(pr, build, np.random.default_rng(0), None, 10.0 + 10.0 + left, False, [])
    assert conf.stable
    if adopted:
        assert conf.adopted >= 1 and conf.repaired == 0 and len(out) == 6
    else:
        assert conf.adopted == 0 and conf.repaired >= 1 and len(out) < 6


def test_the_confirming_settles_get_the_time_that_settles_timed_in_the_run_need(tiny, monkeypatch):
    """Settles of the whole layout far slower than the estimate (a tall mound, a busy machine):
    the first one timed in the run (the beam's verdict on its layout) brings the search's
    deadline forward, so that the confirming settles fit in the limit. Without it, the pocket
    fill went on to the deadline of the estimate, and the run ended 2.96 s past its limit."""
    import optimizer.search.physics as physics

    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    charged = physics.settle
    whole = []

    def slow(scene, placed, *args, **kwargs):
        movable = kwargs.get("movable")
        if movable is None or len(movable) > 1:  # a whole layout, not one block let go
            clock.t += 5.0 * len(placed) / tiny.required_blocks
            whole.append(len(placed))
        return charged(scene, placed, *args, **kwargs)

    monkeypatch.setattr(physics, "settle", slow)
    r = optimize(tiny, seed=3, time_limit=30.0, clock=clock, cover=False)
    assert r.seconds <= 30.0 + 2.0, f"{clock.drops} drops, whole settles of {whole} blocks"
    assert r.collisions == 0 and r.out_of_tolerance == 0
    fill = next(p for p in r.phases if p["strategy"] == "fill")
    assert fill["seconds"] < 1.0, "the search ended when the settle timed said it must"


def test_a_search_far_short_of_a_large_count_is_confirmed_in_the_time_its_own_checks_leave(
        tmp_path, monkeypatch):
    """10 645 tetrapods of 0.35 t under a 5 s limit: the checks of the whole count would keep
    half the limit, but those of the few blocks placed need little of it, so a layout that
    fails its first verdict is taken where the settle left it, or repaired, and stands."""
    text = (ROOT / "geometry" / "scenes" / "mini.toml").read_text()
    small = tmp_path / "small.toml"
    small.write_text(text.replace('block = "shake-4t"', 'block = "tetrapod:0.35"'))
    scene = load_scene(small)
    assert scene.required_blocks > 10_000
    clock = WorkClock(per_drop=0.01, per_settle=0.05).install(monkeypatch)
    r = optimize(scene, seed=1, time_limit=5.0, clock=clock)
    assert r.seconds <= 5.0 + 2.0 and 0 < r.blocks < scene.required_blocks
    assert r.stable is True, r.settle


def test_a_settle_is_stopped_when_asked_and_otherwise_left_alone(tiny):
    """``settle(stop=...)``: asked every few steps, True raises ``Stopped``; never True, the
    result is the one without it, bit for bit."""
    from settle import Stopped, settle

    beam = BeamSearch(restarts=1, origins=3)
    placed = beam.run(problem(tiny), None, np.random.default_rng(1)).build.placed()
    asked = []
    with pytest.raises(Stopped):
        settle(tiny, placed, seed=1, stop=lambda: asked.append(1) or True)
    assert len(asked) == 1
    plain, watched = settle(tiny, placed, seed=1), settle(tiny, placed, seed=1, stop=lambda: False)
    assert [(b.id, b.pose.position.tobytes()) for b in plain.blocks] == [
        (b.id, b.pose.position.tobytes()) for b in watched.blocks]


def test_the_meter_estimates_verdicts_from_the_verdicts_once_one_is_timed():
    """A lone settle (a beam restart's ``stands``) is the only measure until a verdict is timed;
    then the verdicts' own settles are, the slowest of them; settles of too few blocks are not
    counted."""
    from optimizer.search.problem import SETTLE_EXPONENT, SettleMeter

    meter = SettleMeter()
    assert meter.seconds(100) is None
    meter.record(10, 50.0, 100)  # a tenth of the count says little of the whole
    assert meter.seconds(100) is None
    meter.record(100, 10.0, 100)
    assert meter.seconds(100) == pytest.approx(10.0)
    meter.record(100, 4.0, 100, verdict=True)  # two settles side by side, 8 s in all
    assert meter.seconds(100) == pytest.approx(4.0)
    assert meter.seconds(200) == pytest.approx(4.0 * 2**SETTLE_EXPONENT)
    meter.record(100, 6.0, 100, verdict=True)
    meter.record(100, 5.0, 100, verdict=True)
    assert meter.seconds(100) == pytest.approx(6.0)  # the slowest verdict seen
    meter.record(100, 30.0, 100)  # a lone settle, slower: not a verdict's measure
    assert meter.seconds(100) == pytest.approx(6.0)
    assert meter.rate == pytest.approx(30.0 / 100**SETTLE_EXPONENT)


def test_a_verdicts_second_settle_runs_beside_it_only_on_an_idle_core(monkeypatch):
    """One core, or every core busy with a running thread (this one among them): one after
    the other. A core left idle: side by side."""
    import os

    import optimizer.search.physics as physics

    if not hasattr(os, "sched_getaffinity"):
        pytest.skip("no CPU affinity on this platform")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    for running, spare in ((1, True), (2, False), (3, False)):
        monkeypatch.setattr(physics, "_running_threads", lambda running=running: running)
        assert physics._spare_core() is spare
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    monkeypatch.setattr(physics, "_running_threads", lambda: 1)
    assert physics._spare_core() is False
    # Where the file is there, it counts this thread at least.
    if os.path.exists("/proc/loadavg"):
        monkeypatch.undo()
        assert physics._running_threads() >= 1


def test_a_verdict_side_by_side_answers_as_one_in_turn(tiny, monkeypatch):
    """The verdict's two settles run at once on two cores (``physics._side_by_side``): the same
    answer, pose for pose, as one after the other, on a layout that stands and on one that
    falls; where the random kick fails, the other settle is called off, not run to its end.
    (The ``VERDICT_SEED`` settle waits at its first check for the random kick's answer, so that it
    cannot end first.)"""
    import threading

    import optimizer.search.physics as physics
    from settle import Stopped

    settle, ended, answered = physics.settle, [], threading.Event()

    def watched(*args, seed=None, stop=None, **kwargs):
        checked = stop
        if seed == physics.VERDICT_SEED and stop is not None:
            def checked():
                assert answered.wait(60)
                return stop()
        try:
            result = settle(*args, seed=seed, stop=checked, **kwargs)
        except Stopped:
            ended.append("stopped")
            raise
        finally:
            if seed != physics.VERDICT_SEED:
                answered.set()
        ended.append(seed)
        return result

    standing = optimize(load_scene(TINY), seed=1, time_limit=30.0, cover=False).layout.placed()
    assert len(standing) >= 10
    monkeypatch.setattr(physics, "settle", watched)
    # The same blocks 0.4 m higher: they fall onto the ground and onto one another.
    falling = [(k, b, Pose(p.position + [0.0, 0.0, 0.4], p.quaternion)) for k, b, p in standing]
    for placed, stands in ((standing, True), (falling, False)):
        answers = {}
        for two in (False, True):
            monkeypatch.setattr(physics, "_spare_core", lambda two=two: two)
            ended.clear()
            answered.clear()
            pr = problem(tiny)
            answers[two] = physics.verdict(pr, placed, np.random.default_rng(5))
            assert pr.meter.seconds(len(placed)) is not None  # timed, either way
            if stands:
                # Both kicks ran to their end: the random one and VERDICT_SEED's.
                assert len(ended) == 2 and physics.VERDICT_SEED in ended and "stopped" not in ended, ended
            elif two:
                assert ended == [ended[0], "stopped"] and ended[0] != physics.VERDICT_SEED, ended
            else:
                assert len(ended) == 1, ended  # in turn, the second is never begun
        in_turn, side = answers[False], answers[True]
        assert in_turn.stable is side.stable is stands
        assert [(b.id, b.pose.position.tobytes(), b.pose.quaternion.tobytes()) for b in in_turn.blocks] == [
            (b.id, b.pose.position.tobytes(), b.pose.quaternion.tobytes()) for b in side.blocks]


def test_a_layout_that_stood_is_kept_when_a_settle_after_its_verdict_is_stopped(tiny, monkeypatch):
    """A confirmation whose verdict stood, and whose next settle (taking the layout where the
    verdict left it) ran past its end, returns the layout that stood, as stable: a stopped
    settle after a verdict does not undo it. Here the verdict's two settles are quick, and
    each check of any settle after them costs a fake second."""
    import optimizer.search.physics as physics
    from optimizer.search.build import GROUND, Build
    from optimizer.search.physics import confirm
    from optimizer.search.shapes import ShapeCache
    from settle import Stopped

    clock = WorkClock(per_drop=0.0, per_settle=0.0).install(monkeypatch)
    settle = physics.settle
    settles, stopped = [], []

    def slow_after_verdict(*args, stop=None, **kwargs):
        if stop is None:
            return settle(*args, **kwargs)
        number = len(settles)
        settles.append(number)

        def charged():
            if len(settles) > 2:  # the verdict's two settles (random kick, VERDICT_SEED) are quick
                clock.t += 100.0  # the first check after them is past any grace
            return stop()
        try:
            return settle(*args, stop=charged, **kwargs)
        except Stopped:
            stopped.append(number)
            raise

    monkeypatch.setattr(physics, "settle", slow_after_verdict)
    pr = replace(problem(tiny, clock=clock), deadline=clock() + 50.0)
    # Three blocks on the ground far apart, each on its own: a layout that stands.
    build = Build(tiny)
    shape = ShapeCache(tiny.block).hung("crown", 0.0)
    for x in (-2.6, 0.0, 2.6):
        c = build.lower(shape, x, 2.0)
        assert c is not None and c.support == (GROUND,)
        build.place(c)
    end = clock() + 3.0
    kept, confirmation = confirm(pr, build, np.random.default_rng(1), end=end)
    # The settles after the verdict's (one, or the next verdict's two side by side) were stopped.
    assert settles[2:] and sorted(stopped) == settles[2:], (settles, stopped)
    assert confirmation.stable and not confirmation.stopped
    # As it stood: the stopped settle's adoption (the layout where the verdict left it) is not taken.
    assert confirmation.adopted == 0
    where = [p.position.tolist() for *_, p in build.placed()]
    assert [p.position.tolist() for *_, p in kept.placed()] == where


@pytest.mark.parametrize("two", [False, True], ids=["in turn", "side by side"])
def test_a_confirming_settle_that_outlasts_the_limit_is_stopped(tiny, monkeypatch, two):
    """Slender mesh blocks settled at 0.15 s a step, and the confirming settle ran 5 s past the
    time limit (7 s past a 2 s one with kept rods). Here each check of a settle's steps costs a
    fake second: the settle is stopped a second past the confirmation's end, the layout is
    written unsettled and says so, and the run keeps its limit. A verdict's two settles side by
    side each charge their checks, so the clock can pass the grace by a check of each."""
    import optimizer.search.physics as physics
    from optimizer.search.physics import SETTLE_GRACE, confirm

    monkeypatch.setattr(physics, "_spare_core", lambda: two)
    clock = WorkClock(per_drop=0.001, per_settle=0.0).install(monkeypatch)
    settle = physics.settle

    def slow(*args, stop=None, **kwargs):
        # Whole-layout settles are the ones given a stop; a block let go alone stays quick.
        def charged():
            clock.t += 1.0
            return stop()
        return settle(*args, stop=charged if stop is not None else None, **kwargs)

    monkeypatch.setattr(physics, "settle", slow)
    pr = replace(problem(tiny, clock=clock), deadline=clock() + 5.0)
    beam = BeamSearch(restarts=1, origins=3, judge=lambda p, b: True)
    build = beam.run(pr, None, np.random.default_rng(1)).build
    end = clock() + 3.0
    same, confirmation = confirm(pr, build, np.random.default_rng(1), end=end)
    assert confirmation.stopped and not confirmation.stable and same is build
    assert end + SETTLE_GRACE < clock() <= end + SETTLE_GRACE + (2.0 if two else 1.0)
    r = optimize(tiny, seed=1, time_limit=20.0, clock=clock, cover=False)
    assert r.settle == {"skipped": "time"} and r.stable is None and not r.valid
    assert r.seconds <= 20.0 + 2.0 and "was not settled" in r.summary()


def test_the_repairs_judge_the_window_as_the_layout_written_measures_it():
    """The search counts each block's volume inside the design prism on its own; the layout
    written is measured as the blocks' union. Two cubes a settle left overlapping by 5 mm make
    the counted porosity lower than the written one by exactly their shared volume inside the
    prism (``counted_below``), and the repairs' moves (``as_written``) judge the window from a
    target lowered by that much: on the held-out ``cube-small`` the covering moves had taken
    seed 1 to 47.9998 % as counted, 48.0001 % as written, over its window."""
    from optimizer.api import as_written, counted_below

    scene = load_scene(str(ROOT / "benchmarks" / "scenes" / "cube.toml"))
    side = scene.block.height
    build = Build(scene)
    z0 = scene.design.z_bottom + side / 2
    build.place_at(Pose([0.0, 6.0, z0], [1.0, 0.0, 0.0, 0.0]))
    assert counted_below(scene, build) == pytest.approx(0.0, abs=1e-9)
    build.place_at(Pose([0.0, 6.0, z0 + side - 0.005], [1.0, 0.0, 0.0, 0.0]))  # 5 mm into the one below
    shared = side * side * 0.005  # all of it inside the prism, on the axis
    expected = 100.0 * shared / scene.design_volume
    assert counted_below(scene, build) == pytest.approx(expected, rel=1e-6)
    pr = problem(scene)
    written = as_written(pr, build)
    assert written.target == pytest.approx(pr.target - expected, rel=1e-9)
    assert written.deadline == pr.deadline


def test_an_attempt_is_on_target_only_where_the_layout_written_is_within_its_window():
    """The attempts' gates read the porosity as written (``_Attempt.as_written``), not as the
    search counts it: two cubes 5 mm into each other, with the target set so that the counted
    porosity is half the overlap inside the window and the written one half of it outside, are
    not on target (until stop 74 they were: the gates read the counted porosity). An attempt
    replaced by another layout measures that layout's union anew."""
    from optimizer.api import _Attempt, counted_below
    from optimizer.search.problem import TARGET_POINTS, off_window

    scene = load_scene(str(ROOT / "benchmarks" / "scenes" / "cube.toml"))
    side = scene.block.height
    z0 = scene.design.z_bottom + side / 2
    apart, into = Build(scene), Build(scene)
    for build, gap in ((apart, 0.0), (into, 0.005)):
        build.place_at(Pose([0.0, 6.0, z0], [1.0, 0.0, 0.0, 0.0]))
        build.place_at(Pose([0.0, 6.0, z0 + side - gap], [1.0, 0.0, 0.0, 0.0]))
    overlap = counted_below(scene, into)
    assert overlap > 0 and counted_below(scene, apart) == pytest.approx(0.0, abs=1e-9)
    counted = into.porosity.percent
    pr = replace(problem(scene), required=2, target=counted - TARGET_POINTS + overlap / 2)
    assert off_window(pr, into) == 0.0  # as counted, within its window
    attempt = _Attempt(into, [], {}, {}, True)
    assert not attempt.on_target(pr)
    assert attempt.as_written(pr).target == pytest.approx(pr.target - overlap, rel=1e-9)
    # The same target with the cubes apart: the counted porosity is the written one.
    level = replace(pr, target=apart.porosity.percent - TARGET_POINTS + overlap / 2)
    first = _Attempt(apart, [], {}, {}, True)
    assert first.on_target(level)  # its union measured, and kept on it
    assert not replace(first, build=into).on_target(pr)
    assert attempt.written_percent(pr) == pytest.approx(counted + overlap, rel=1e-12)


@pytest.mark.parametrize("change, words", [
    (("height_m = 3.0", "height_m = 0.3"), "no block fits in the tolerance zone: turned any way, the block "
                                            "is at least 1.25 m thick"),
    (('target_porosity_percent = 56.0', 'target_porosity_percent = 56.0\nrequired_blocks = 100000'),
     "no layout holds 100000 blocks"),
])
def test_a_count_no_layout_can_reach_is_said_so_not_blamed_on_the_time(tmp_path, change, words):
    """A mound lower than the block is thick, or a count whose concrete is more than twice the
    tolerance zone: the run says why no layout reaches the count, never that a longer
    --time-limit may place more (it did, for both: stop 77's probe)."""
    text = (ROOT / "tests" / "data" / "tiny.toml").read_text().replace(*change)
    assert text != (ROOT / "tests" / "data" / "tiny.toml").read_text()
    (tmp_path / "scene.toml").write_text(text)
    r = optimize(load_scene(str(tmp_path / "scene.toml")), seed=1, time_limit=3.0)
    assert r.blocks < r.required_blocks
    assert words in r.shortfall and "a longer --time-limit" not in r.summary()
    searched = {p["strategy"] for p in r.phases} & {"beam", "fill", "anneal"}
    assert not searched if words.startswith("no block fits") else searched  # no search where none fits


def test_the_ball_inside_a_hull_bounds_its_thinnest_width():
    """``inscribed_radius``: 1 for a 2 m cube wherever it lies and however it is turned, the
    half of its thinnest side for a slab, and 0 (no claim) for points in one plane."""
    from optimizer.api import inscribed_radius

    cube = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))
    turned = cube @ Pose([0, 0, 0], random_quaternion(np.random.default_rng(1))).rotation.T + 1000.0
    assert inscribed_radius(cube) == pytest.approx(1.0) and inscribed_radius(turned) == pytest.approx(1.0)
    assert inscribed_radius(cube * [3.0, 2.0, 0.25]) == pytest.approx(0.25)
    assert inscribed_radius(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])) == 0.0

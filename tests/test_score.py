"""The score (optimizer/score/scoring.py): a perturbed reference is scored on its faults and nothing else.

The reference is tests/data/mini-reference.json (a valid 75-block layout of
``mini``). Each perturbation of optimizer/perturb.py puts one fault in; the
test scores the perturbed copy against the reference and checks that exactly
the metrics the fault touches change, in the way the fault says, and that
every other metric is what the reference's own score gives. Expected values
are computed from the files, never written down.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from geometry.blocks import get_block
from geometry.clip import volume_inside
from geometry.constants import tol
from geometry.errors import InputError
from geometry.layout import Layout, read_layout
from optimizer.score.interlock import InterlockRule, interlock
from optimizer.score.scoring import (
    Measures,
    Reference,
    ScoreWeights,
    combined,
    penalties,
    porosity_map,
    progress_percent,
    quality_percent,
    score,
    zone_prisms,
)
from tests.perturb import (
    jitter,
    lift_out_of_tolerance,
    push_together,
    remove_last,
    stand_on_leg_tip,
)

DATA = Path(__file__).parent / "data"
REFERENCE = DATA / "mini-reference.json"


@pytest.fixture(scope="module")
def ref_layout() -> Layout:
    return read_layout(REFERENCE)


@pytest.fixture(scope="module")
def scene(ref_layout):
    return ref_layout.load_scene()


@pytest.fixture(scope="module")
def reference(scene, ref_layout) -> Reference:
    return Reference.of(scene, ref_layout.placed())


@pytest.fixture(scope="module")
def base(scene, ref_layout, reference) -> dict:
    """The reference scored against itself."""
    return score(scene, ref_layout.placed(), reference).to_dict()


def _contacts(d: dict) -> dict[int, set[int]]:
    return {b["id"]: set(b["contact_ids"]) for b in d["interlock"]["blocks"]}


def _filled(d: dict) -> list[float]:
    return [z["filled_m3"] for z in d["zones"]["save"]]


def _assert_interlock_only_through(base: dict, got: dict, moved: set[int]) -> None:
    """Contacts among blocks that did not move are exactly the reference's."""
    before, after = _contacts(base), _contacts(got)
    for k in after:
        if k in moved:
            continue
        assert after[k] - moved == before[k] - moved, f"block {k}: contacts changed among unmoved blocks"


def _assert_zones_only_near(scene, base: dict, got: dict, poses: list) -> None:
    """Zones that no moved block (before or after) can reach keep their filled volume exactly."""
    radius = scene.block.bounding_radius
    for zb, zg in zip(base["zones"]["save"], got["zones"]["save"], strict=True):
        near = any(zb["y0_m"] - radius <= p.position[1] <= zb["y1_m"] + radius
                   and zb["z0_m"] - radius <= p.position[2] <= zb["z1_m"] + radius for p in poses)
        if not near:
            assert zg["filled_m3"] == zb["filled_m3"], f"zone {zb['slice']},{zb['layer']} changed"


def _assert_score_is_formula(d: dict) -> None:
    """score = progress x quality / 100, quality = 100 x 0.99 ** points (docs/scoring.md)."""
    total = sum(p["points"] for p in d["penalties"])
    np.testing.assert_allclose(d["penalty_points"], total, rtol=1e-15)
    np.testing.assert_allclose(d["quality"], 100.0 * 0.99 ** total, rtol=1e-12)
    np.testing.assert_allclose(d["progress_percent"], 100.0 * min(d["blocks"], d["required_blocks"])
                               / d["required_blocks"], rtol=1e-15)
    np.testing.assert_allclose(d["score"], d["progress_percent"] * d["quality"] / 100.0, rtol=1e-15)


def _pose(layout: Layout, key: int):
    return next(p.pose for p in layout.blocks if p.id == key)


def test_reference_is_valid_and_scores_100_against_itself(base, reference, ref_layout):
    assert reference.out_of_tolerance == 0 and reference.collisions == 0
    assert base["blocks"] == base["required_blocks"] == len(ref_layout.blocks) == 75
    assert base["stable"] is True and base["unstable_blocks"] == []
    assert base["out_of_tolerance"] == [] and base["collisions"] == []
    assert base["porosity_percent"] == base["reference_porosity_percent"]
    assert base["score"] == 100.0
    assert all(p["points"] == 0.0 for p in base["penalties"])
    for key in ("score", "porosity_percent", "reference_porosity_percent", "out_of_tolerance", "collisions",
                "stable", "blocks", "required_blocks"):
        assert key in base


def test_zone_map_partitions_the_design_prism(scene, ref_layout, base):
    zones = zone_prisms(scene)
    np.testing.assert_allclose(sum(p.volume for _, _, p in zones), scene.design_volume, rtol=1e-12)
    filled = sum(_filled(base))
    phi = 100.0 * (scene.design_volume - filled) / scene.design_volume
    np.testing.assert_allclose(phi, base["porosity_percent"], atol=1e-9)
    # The same map from a finer cut adds up to the same filled volume.
    fine = porosity_map(scene, ref_layout.placed(), slices=7, layers=3)
    np.testing.assert_allclose(sum(z.filled_m3 for z in fine), filled, rtol=1e-9)
    assert all(0.0 <= z.porosity_percent <= 100.0 for z in fine)


def test_lifted_out_of_tolerance(scene, ref_layout, reference, base):
    layout, key = lift_out_of_tolerance(scene, ref_layout)
    got = score(scene, layout.placed(), reference).to_dict()
    block = get_block("shake-4t")
    old, new = _pose(ref_layout, key), _pose(layout, key)

    # The fault: that block, and only it, out of tolerance, by its exact outside volume.
    assert [o["id"] for o in got["out_of_tolerance"]] == [key]
    outside = block.volume - volume_inside(block, new, scene.tolerance.polytope)
    np.testing.assert_allclose(got["out_of_tolerance"][0]["outside_volume_m3"], outside, rtol=1e-9)
    assert outside > tol.volume
    # Its consequences: less block inside the design prism, and its contacts.
    lost = volume_inside(block, old, scene.design.polytope) - volume_inside(block, new, scene.design.polytope)
    assert lost > 0
    np.testing.assert_allclose(got["porosity_percent"] - base["porosity_percent"],
                               100.0 * lost / scene.design_volume, atol=1e-9)
    _assert_interlock_only_through(base, got, {key})
    _assert_zones_only_near(scene, base, got, [old, new])
    # Nothing else.
    assert got["collisions"] == [] and got["stable"] is True and got["unstable_blocks"] == []
    assert got["blocks"] == base["blocks"] and got["remaining_blocks"] == 0
    pens = {p["name"]: p for p in got["penalties"]}
    assert pens["tolerance"]["amount"] == 1 and pens["tolerance"]["points"] == 5.0
    assert got["finished"]["left_out"] == [key]
    assert all(p["points"] == 0 for name, p in pens.items() if name != "tolerance")
    _assert_score_is_formula(got)
    assert got["score"] < base["score"]


def test_two_blocks_pushed_into_each_other(scene, ref_layout, reference, base):
    layout, (a, b) = push_together(scene, ref_layout)
    got = score(scene, layout.placed(), reference).to_dict()

    # The fault: exactly that pair, deeper than a resting contact.
    assert [(c["a"], c["b"]) for c in got["collisions"]] == [(a, b)]
    assert got["collisions"][0]["depth_m"] > tol.contact_depth
    # Porosity: each block's part inside the design prism, less their overlap
    # counted once, computed here with manifold3d directly.
    block = get_block("shake-4t")
    design = scene.design.polytope
    change = 0.0
    for k in (a, b):
        change += volume_inside(block, _pose(layout, k), design) - volume_inside(block, _pose(ref_layout, k),
                                                                                   design)
    solids = [block.posed_solid(p) for p in (_pose(layout, a), _pose(layout, b))]
    overlap = m3.Manifold.batch_boolean(solids, m3.OpType.Intersect)
    for n, d in zip(design.normals, design.offsets, strict=True):
        overlap = overlap.trim_by_plane(-n, -d)
    assert overlap.volume() > 0
    change -= overlap.volume()
    np.testing.assert_allclose(base["porosity_percent"] - got["porosity_percent"],
                               100.0 * change / scene.design_volume, atol=1e-9)
    _assert_interlock_only_through(base, got, {a, b})
    _assert_zones_only_near(scene, base, got, [_pose(ref_layout, a), _pose(ref_layout, b)])
    # Nothing else.
    assert got["out_of_tolerance"] == [] and got["stable"] is True and got["unstable_blocks"] == []
    assert got["blocks"] == base["blocks"]
    pens = {p["name"]: p for p in got["penalties"]}
    assert pens["collisions"]["amount"] == 1 and pens["collisions"]["points"] == 5.0
    assert got["finished"]["left_out"] == [a, b]
    assert all(p["points"] == 0 for name, p in pens.items() if name != "collisions")
    _assert_score_is_formula(got)
    assert got["score"] < base["score"]


def test_block_on_a_leg_tip_is_the_only_unstable_one(scene, ref_layout, reference, base):
    layout, key = stand_on_leg_tip(scene, ref_layout)
    got = score(scene, layout.placed(), reference).to_dict()
    old, new = _pose(ref_layout, key), _pose(layout, key)
    # Upside down: its single leg (local +z) points down.
    assert (new.rotation @ [0.0, 0.0, 1.0])[2] < -0.99

    # The fault: the settle moves that block, and only it, past the thresholds.
    assert got["stable"] is False and got["unstable_blocks"] == [key]
    moved = next(b for b in got["settle"]["blocks"] if b["id"] == key)
    assert moved["displacement_m"] > 0.05 * get_block("shake-4t").height or moved["rotation_deg"] > 5.0
    # Its consequences: its own volume inside the design prism, and its contacts.
    block = get_block("shake-4t")
    design = scene.design.polytope
    change = volume_inside(block, new, design) - volume_inside(block, old, design)
    # The crane sets the tip down touching its carrier to within the drop's resolution; the
    # union counts that sliver (under a cubic centimetre) once, the sum above twice.
    np.testing.assert_allclose(base["porosity_percent"] - got["porosity_percent"],
                               100.0 * change / scene.design_volume, atol=1e-6)
    _assert_interlock_only_through(base, got, {key})
    _assert_zones_only_near(scene, base, got, [old, new])
    # Nothing else.
    assert got["out_of_tolerance"] == [] and got["collisions"] == []
    assert got["blocks"] == base["blocks"]
    pens = {p["name"]: p for p in got["penalties"]}
    assert pens["stability"]["amount"] == 1 and pens["stability"]["points"] == 5.0
    assert got["finished"]["left_out"] == [key]
    assert all(p["points"] == 0 for name, p in pens.items() if name != "stability")
    _assert_score_is_formula(got)
    assert got["score"] < base["score"]


def test_ten_blocks_removed(scene, ref_layout, reference, base):
    layout, removed = remove_last(ref_layout, 10)
    got = score(scene, layout.placed(), reference).to_dict()

    # The fault: ten fewer blocks, ten remaining.
    assert len(removed) == 10
    assert got["blocks"] == base["blocks"] - 10 and got["remaining_blocks"] == 10
    # Its consequences: their volume inside the design prism is gone ...
    block = get_block("shake-4t")
    gone = sum(volume_inside(block, _pose(ref_layout, k), scene.design.polytope) for k in removed)
    np.testing.assert_allclose(got["porosity_percent"] - base["porosity_percent"],
                               100.0 * gone / scene.design_volume, atol=1e-9)
    # ... and every remaining block lost exactly its contacts with them.
    before, after = _contacts(base), _contacts(got)
    assert set(after) == set(before) - set(removed)
    for k in after:
        assert after[k] == before[k] - set(removed)
    # Nothing else.
    assert got["out_of_tolerance"] == [] and got["collisions"] == []
    assert got["stable"] is True and got["unstable_blocks"] == []
    # Missing blocks cost progress alone: the save finished with the reference's ten is the reference.
    assert got["finished"]["added_reference_blocks"] == removed
    assert all(p["points"] == 0 for p in got["penalties"])
    assert got["progress_percent"] == 100.0 * 65 / 75 and got["quality"] == 100.0
    _assert_score_is_formula(got)
    assert got["score"] < base["score"]


def test_reference_scores_highest(scene, ref_layout, reference, base):
    rng = np.random.default_rng(11)
    for count in (1, 3):
        layout, _ = jitter(ref_layout, rng, count)
        got = score(scene, layout.placed(), reference)
        assert got.score <= base["score"]
    assert base["score"] == 100.0


def test_settled_copy_is_not_out_of_tolerance(scene, ref_layout, reference):
    """A save as a physics engine leaves it: blocks sink a hair into the foundation."""
    from settle import settle

    result = settle(scene, ref_layout.placed(), seed=4)
    placed = [(k, b, result.poses[k]) for k, b, _ in ref_layout.placed()]
    lowest = min(p.apply(b.vertices)[:, 2].min() for _, b, p in placed)
    assert lowest < 0.0  # resting contact pushes into the ground
    got = score(scene, placed, reference)
    assert got.out_of_tolerance == []
    assert got.collisions == []


def _measures(**over) -> Measures:
    args = {"blocks": 75, "required_blocks": 75, "out_of_tolerance": 0, "collisions": 0, "unstable": 0,
            "porosity_percent": 57.0, "reference_porosity_percent": 57.0, "target_porosity_percent": 56.0,
            "flagged": 3, "reference_flagged": 3, "bare_share_percent": 10.0,
            "reference_bare_share_percent": 10.0, "seconds_per_block": None}
    args.update(over)
    return Measures(**args)


@pytest.mark.parametrize(
    "kw, expected",
    [
        ({"out_of_tolerance": 2}, {"tolerance": 10.0}),
        ({"out_of_tolerance": 90}, {"tolerance": 450.0}),  # no cap: every fault counts
        ({"collisions": 1}, {"collisions": 5.0}),
        ({"unstable": 3}, {"stability": 15.0}),
        # porosity beyond the reference's gap to the target: 2.5 a point
        ({"porosity_percent": 60.0}, {"porosity": 2.5 * (4.0 - 1.0)}),
        ({"porosity_percent": 55.5}, {}),  # closer to the target than the reference: no loss
        ({"porosity_percent": 54.0}, {"porosity": 2.5 * (2.0 - 1.0)}),  # denser than the target counts too
        ({"flagged": 5}, {"interlock": 4.0}),  # 3 flagged in the reference
        ({"flagged": 2}, {}),
        ({"bare_share_percent": 12.5}, {"coverage": 2.5}),
        ({"bare_share_percent": 9.0}, {}),
        # time: 0 points by default, however slow
        ({"seconds_per_block": 600.0}, {}),
        # degenerate: nothing placed, nothing required; missing blocks are no penalty
        ({"blocks": 0, "required_blocks": 0}, {}),
        ({"blocks": 0}, {}),
    ],
)
def test_penalty_table(kw, expected):
    got = {p.name: p.points for p in penalties(_measures(**kw))}
    assert set(got) == {"tolerance", "collisions", "stability", "porosity", "interlock", "coverage", "time"}
    for name, points in got.items():
        np.testing.assert_allclose(points, expected.get(name, 0.0), rtol=1e-12, atol=0)


def test_time_costs_only_when_a_trainer_gives_it_weight():
    slow = _measures(seconds_per_block=80.0)
    weights = ScoreWeights(time_per_second=0.5, par_seconds_per_block=50.0)
    (time_penalty,) = [p for p in penalties(slow, weights) if p.name == "time"]
    assert time_penalty.amount == 30.0 and time_penalty.points == 15.0
    fast = penalties(_measures(seconds_per_block=40.0), weights)
    assert [p.points for p in fast if p.name == "time"] == [0.0]


def test_the_formula_for_a_partial_save():
    """30 of 75 blocks laid, one out of tolerance, one pair pushed together, porosity 0.4 points worse."""
    m = _measures(blocks=30, out_of_tolerance=1, collisions=1, porosity_percent=57.4)
    pens = penalties(m)
    points = sum(p.points for p in pens)
    np.testing.assert_allclose(points, 5.0 + 5.0 + 2.5 * 0.4, rtol=1e-12)
    progress, quality = progress_percent(30, 75), quality_percent(points)
    assert progress == 40.0
    np.testing.assert_allclose(quality, 100.0 * 0.99 ** 11.0, rtol=1e-12)
    np.testing.assert_allclose(combined(progress, quality), 40.0 * 0.99 ** 11.0, rtol=1e-12)
    assert f"{combined(progress, quality):.1f}" == "35.8" and f"{quality:.1f}" == "89.5"


def test_many_faults_still_each_cost():
    """No cap: the thousandth fault lowers the score as the first does, by 1 % per point of what is left."""
    for faults in (0, 1, 10, 1000):
        a = quality_percent(sum(p.points for p in penalties(_measures(out_of_tolerance=faults))))
        b = quality_percent(sum(p.points for p in penalties(_measures(out_of_tolerance=faults + 1))))
        assert 0.0 < b < a <= 100.0
        np.testing.assert_allclose(b / a, 0.99 ** 5.0, rtol=1e-9)


def test_weights_must_be_non_negative_numbers():
    assert ScoreWeights(tolerance_per_block=0.0).tolerance_per_block == 0.0
    for bad in (-1.0, float("nan"), float("inf"), "5", True):
        with pytest.raises(InputError):
            ScoreWeights(tolerance_per_block=bad)


def test_interlock_rule_and_degenerate_layouts(scene, shake, cube):
    from tests.conftest import standing

    assert interlock([], scene.foundation).blocks == []
    lone = [(0, shake, standing(shake, 0.0, 6.0))]
    (b,) = interlock(lone, scene.foundation).blocks
    assert b.foundation and b.contacts == () and b.contact_count == 1 and b.flagged
    # Two unit cubes 1 cm apart touch (tol.contact_gap is 2 cm); 5 cm apart
    # they are neighbours only (within 0.25 H = 25 cm). Either side of 2 cm by 0.1 mm
    # (the boundary itself is not representable: 1.02 - 1.0 > 0.02 in binary).
    for gap, touching in ((0.01, True), (tol.contact_gap - 1e-4, True), (tol.contact_gap + 1e-4, False),
                          (0.05, False)):
        pair = [(0, cube, standing(cube, 0.0, 6.0)), (1, cube, standing(cube, 1.0 + gap, 6.0))]
        report = interlock(pair, scene.foundation, InterlockRule(min_contacts=2, min_neighbours=1))
        first, second = report.blocks
        assert (first.contacts == (1,)) is touching and first.neighbours == (1,)
        assert first.flagged is not touching
    with pytest.raises(InputError):
        InterlockRule(min_contacts=-1)


def test_scene_mismatch_is_input_error(reference):
    from geometry.scene import load_scene

    with pytest.raises(InputError):
        score(load_scene("mini-section"), [], reference)


_counts = st.integers(min_value=0, max_value=500)


@settings(max_examples=200, deadline=None)
@given(phi=st.floats(0.0, 100.0), ref_phi=st.floats(0.0, 100.0), blocks=_counts, required=_counts,
       out=_counts, pairs=_counts, unstable=_counts, flagged=_counts, ref_flagged=_counts,
       bare=st.floats(0.0, 100.0), ref_bare=st.floats(0.0, 100.0),
       extra=st.sampled_from(["out_of_tolerance", "collisions", "unstable", "flagged"]))
def test_score_stays_in_range_and_one_more_fault_never_helps(phi, ref_phi, blocks, required, out, pairs,
                                                              unstable, flagged, ref_flagged, bare, ref_bare,
                                                              extra):
    m = Measures(blocks, required, out, pairs, unstable, phi, ref_phi, 56.0, flagged, ref_flagged, bare,
                 ref_bare, None)
    pens = penalties(m)
    assert all(p.points >= 0.0 for p in pens)
    total = sum(p.points for p in pens)
    value = combined(progress_percent(blocks, required), quality_percent(total))
    assert 0.0 <= value <= 100.0
    worse = dataclasses.replace(m, **{extra: getattr(m, extra) + 1})
    assert sum(p.points for p in penalties(worse)) >= total
    if extra != "flagged":  # a rule fault always costs; interlock only beyond the reference's count
        assert sum(p.points for p in penalties(worse)) > total
    more = dataclasses.replace(m, blocks=blocks + 1)
    assert combined(progress_percent(blocks + 1, required), quality_percent(total)) >= value
    assert sum(p.points for p in penalties(more)) == total


@pytest.mark.parametrize("sunk_mm, out", [(3.0, False), (8.0, True)])
def test_score_judges_tolerance_in_the_zone_check_does(scene, ref_layout, reference, sunk_mm, out):
    """A block on the foundation sunk into it: within the 5 mm the zone reaches below the
    foundation it is contact, past it out of tolerance, to ``score`` as to ``shoha check``.
    (The scoring zone once reached 15 mm below, and a block sunk 8 mm was out to one and not
    to the other.)"""
    from geometry.checks import check_layout

    def lowest(p) -> float:
        return float(p.pose.apply(get_block(p.type).vertices)[:, 2].min())

    on_ground = min(ref_layout.blocks, key=lowest)
    assert abs(lowest(on_ground)) < 1e-3  # resting on the flat foundation
    shift = np.array([0.0, 0.0, -lowest(on_ground) - sunk_mm / 1000.0])
    moved = [dataclasses.replace(p, pose=dataclasses.replace(p.pose, position=p.pose.position + shift))
             if p.id == on_ground.id else p for p in ref_layout.blocks]
    layout = dataclasses.replace(ref_layout, blocks=moved)
    checked = {k for k, _ in check_layout(scene, layout.placed()).out_of_tolerance}
    scored = {o["id"] for o in score(scene, layout.placed(), reference).to_dict()["out_of_tolerance"]}
    assert scored == checked
    assert (on_ground.id in scored) is out

"""Placement patterns: the automatic tuner, and the cache that keeps what it found."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import optimizer.search.patterns as patterns
from geometry.blocks import get_block
from optimizer.search import hangings
from optimizer.search.patterns import _lattice_penalty, lattice_for, staggered, tune_lattice


def _params(lat):
    return patterns.lattice_params(lat)


def _ticks():
    """A clock that moves one second each time it is read: the tuner's budget in readings (about
    one a generation), so that what it does is the same on any machine."""
    ticks = itertools.count()
    return lambda: float(next(ticks))


@pytest.mark.parametrize("name, denser", [("box:1x1x1", False), ("tetrapod:2", True)])
def test_the_tuner_finds_a_feasible_lattice_no_looser_than_the_staggered_bond(name, denser):
    """Cubes pack no closer than side by side, which the bond already is; tetrapods interlock."""
    block = get_block(name)
    lat = tune_lattice(block, seconds=80.0, clock=_ticks())
    # Feasible: the penalty adds 20 per metre a block stops short of the ground, so it is the area.
    assert _lattice_penalty(_params(lat), block, (lat.family_a, lat.family_b)) == pytest.approx(
        lat.area_per_block)
    bond = staggered(block).area_per_block
    assert lat.area_per_block < bond if denser else lat.area_per_block <= bond
    assert lat.area_per_block >= 0.999 * block.height**2 if not denser else True


class _Stub:
    """A tuner run whose lattice gets denser by ``rate`` a second it is given (no evolution)."""

    def __init__(self, volume, rate):
        self.volume, self.rate, self.seconds, self.rounds = volume, rate, 0.0, 0

    def go(self, maxiter, seconds, clock, generations=None):
        self.volume -= self.rate * seconds
        self.seconds += seconds
        self.rounds += 1


def test_the_tuner_races_its_runs_and_gives_the_last_round_to_the_densest():
    """Successive halving over stubbed runs: five runs, three go on, two, then one finishes. The
    densest after each round goes on, wherever it stands in the list: the one that starts
    densest but does not improve is overtaken in the third round."""
    runs = [_Stub(10.0, 0.01), _Stub(10.0, 0.02), _Stub(10.0, 0.05), _Stub(9.0, 0.0), _Stub(10.0, 0.04)]
    # 30 generations a round, which no run's maxiter cuts: each round has as many in all.
    patterns._race(runs, maxiter=1000, seconds=80.0, clock=_ticks(), generations=30)
    assert [r.rounds for r in runs] == [1, 1, 4, 3, 2]
    # Each round has an equal share of what is left, split among the runs in it.
    assert runs[2].seconds > runs[3].seconds > runs[4].seconds > runs[0].seconds == runs[1].seconds
    assert min(runs, key=lambda r: r.volume) is runs[2]


def _paced(pace):
    """A clock that moves ``pace`` seconds each time it is read: the same work takes ``pace``
    times as long, as on a machine ``pace`` times slower."""
    ticks = itertools.count()
    return lambda: pace * float(next(ticks))


def test_the_race_is_ended_by_its_generations_so_the_lattice_is_the_same_on_a_slower_machine():
    """Rounds of so many generations, not seconds: a machine three times slower tunes the same
    lattice, as long as it reaches the count within the seconds. (Rounds ended on the clock
    gave the slower machine a third of the generations, and another lattice.) So the cache,
    keyed by the mesh alone, holds one lattice."""
    block = get_block("box:1.3x1.1x0.9")

    def race(clock):
        runs = [patterns._Run(block, pair, 0) for pair in (("rest-1", "rest-1"), ("rest-1", "rest-2"))]
        # About 22 readings a generation: 8 generations take about 180 s on the fast clock and
        # 540 s on the slow one, well within 4000 s.
        patterns._race(runs, maxiter=300, seconds=4000.0, clock=clock, generations=8)
        return runs

    fast, slow = race(_paced(1.0)), race(_paced(3.0))
    # Four each in the first round; the denser goes on by eight more.
    assert sorted(r.generations for r in fast) == [4, 12]
    assert [r.generations for r in slow] == [r.generations for r in fast]
    assert [r.lattice for r in slow] == [r.lattice for r in fast]
    assert not any(r.cut for r in fast + slow)


def test_the_race_shares_its_time_by_the_generations_each_round_has():
    """Two runs, 300 generations a round and 300 a run: the first round has 150 each, the last
    only the 150 its run has left. So the first round gets two thirds of the time (the clock
    split it in halves, and left a run 7.5 s of 30 for its 150 generations on ``mini-mesh``)."""
    assert patterns._plan(2, 300, 300) == [150, 150]
    assert patterns._plan(5, 1000, 30) == [6, 10, 15, 30]
    now = [0.0]

    class Timed(_Stub):
        """A stub that takes all the time it is given."""

        def go(self, maxiter, seconds, clock, generations=None):
            super().go(maxiter, seconds, clock, generations)
            now[0] += seconds

    runs = [Timed(10.0, 0.01), Timed(10.0, 0.02)]
    patterns._race(runs, maxiter=300, seconds=90.0, clock=lambda: now[0], generations=300)
    # 60 s for the first round, 30 each; the denser then has the last 30. (In halves: 22.5 and 67.5.)
    assert sorted(r.seconds for r in runs) == [pytest.approx(30.0), pytest.approx(60.0)]


def test_a_run_the_race_has_no_time_left_for_is_cut():
    """Runs that overrun their share leave the winner no last round: it says it was cut."""
    now = [0.0]

    class Slow(_Stub):
        lattice, cut, generations = "found", False, 0

        def go(self, maxiter, seconds, clock, generations=None):
            super().go(maxiter, seconds, clock, generations)
            self.generations += 1
            now[0] += 2 * seconds  # twice the time it was given

    runs = [Slow(10.0, 0.01), Slow(10.0, 0.02)]
    patterns._race(runs, maxiter=300, seconds=90.0, clock=lambda: now[0], generations=300)
    # The denser won the first round and had no second: it was cut; the other lost the race.
    assert [r.rounds for r in runs] == [1, 1] and [r.cut for r in runs] == [False, True]


def test_a_run_the_clock_stops_within_a_generation_is_cut():
    """The clock may end a round in its last generation, the rest of that population scored
    unlaid: the count was reached in name only, and the run says it was cut."""
    run = patterns._Run(get_block("box:1.3x1.1x0.9"), ("rest-1", "rest-1"), 0)
    # One reading for the end, 21 for the first population, 22 a generation: the end falls in the
    # second generation, which is then finished with the rest of its lattices unlaid.
    run.go(300, 55.0, _ticks(), generations=2)
    assert run.generations == 2 and run.cut is True
    whole = patterns._Run(get_block("box:1.3x1.1x0.9"), ("rest-1", "rest-1"), 0)
    whole.go(300, 1000.0, _ticks(), generations=2)
    assert whole.generations == 2 and whole.cut is False


def test_a_tuning_the_clock_ends_says_so():
    """Where the seconds run out before the generations, the tuning is the machine's: it says so."""
    block = get_block("box:1.3x1.1x0.9")
    _, tuning = patterns.tune(block, seconds=30.0, clock=_ticks())
    assert tuning.source == "tuned" and tuning.clock_cut is True


def test_the_race_test_stub_is_a_fair_stand_in():
    """The real run carries on where it stopped: a second go does not start again."""
    block = get_block("box:1.3x1.1x0.9")
    run = patterns._Run(block, ("rest-1", "rest-2"), 0)
    run.go(10_000, 5.0, _ticks())
    first, generations = run.volume, run.generations
    run.go(10_000, 5.0, _ticks())
    assert run.volume <= first and run.generations > generations and run.rounds == 2


def test_pairs_of_hangings_are_compared_by_volume_so_a_brick_lies_flat():
    """A brick on end takes half the area of one laid flat: by area a lattice mixing the two
    wins, but it is twice as tall, and a mound of it no denser."""
    block = get_block("box:2.0x1.0x1.0")
    assert hangings.families(block)[:2] == ("rest-1", "rest-2")  # rest-2 stands it on end
    lat = tune_lattice(block, seconds=40.0, clock=_ticks())
    assert (lat.family_a, lat.family_b) == ("rest-1", "rest-1")


def test_a_tuned_lattice_is_spread_off_the_edge_of_feasibility(cube):
    """Cubes all but face to face are feasible but jam on a mound; the tuner spreads them a hair."""
    side = cube.height * (1 + 1e-6)  # a micrometre apart, as the tuner left the cube scene's cubes
    tight = patterns.InterlockLattice(p=side, w=2 * side, q=0.0, u=side, v=side / 2, yaw_a=0.0, yaw_b=0.0,
                                      family_a="rest-1", family_b="rest-1")
    assert _lattice_penalty(_params(tight), cube, ("rest-1", "rest-1")) == pytest.approx(tight.area_per_block)
    spread = patterns.with_clearance(tight, cube)
    assert spread.p == pytest.approx(side * (1 + patterns.CLEARANCE))
    assert spread.area_per_block > tight.area_per_block
    assert _lattice_penalty(_params(spread), cube, ("rest-1", "rest-1")) == pytest.approx(
        spread.area_per_block)
    # Nothing is spread looser than the bond the tuner starts from (which leaves 1 %).
    bond = staggered(cube)
    assert patterns.with_clearance(bond, cube) == bond


def test_the_staggered_bond_is_feasible(cube, shake):
    for block in (cube, shake):
        lat = staggered(block)
        assert _lattice_penalty(_params(lat), block, (lat.family_a, lat.family_b)) == pytest.approx(
            lat.area_per_block)


@pytest.mark.parametrize("name", ["shake-4t", "tetrapod:2.0", "box:1.6x1.6x1.6"])
def test_lattice_sites_are_every_lattice_point_in_the_window_and_no_other(name):
    """The sites are enumerated only over the rows that reach the window; checked against
    every point of a grid wide enough to hold them all, for skewed and shifted lattices."""
    lat = lattice_for(get_block(name), name)
    rng = np.random.default_rng(7)
    for q in (lat.q, 0.37 * lat.p, -1.9 * lat.p):
        skewed = replace(lat, q=q, upper=None)
        for _ in range(4):
            origin = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5)))
            xr = tuple(sorted(rng.uniform(-9, 9, 2)))
            yr = tuple(sorted(rng.uniform(-4, 14, 2)))
            every = []
            for fam, yaw, du, dv in ((skewed.family_a, skewed.yaw_a, 0.0, 0.0),
                                     (skewed.family_b, skewed.yaw_b, skewed.u, skewed.v)):
                for j in range(-60, 61):
                    for i in range(-400, 401):
                        x = origin[0] + du + j * skewed.w
                        y = origin[1] + dv + i * skewed.p + j * skewed.q
                        if xr[0] <= x <= xr[1] and yr[0] <= y <= yr[1]:
                            every.append((fam, yaw, x, y))
            assert sorted(skewed.sites(xr, yr, origin)) == sorted(every)


def test_a_lattice_laid_past_the_tuners_end_is_given_up_before_its_drops(cube, monkeypatch):
    """A curved mesh's drops took seconds each, and the tuner laid whole lattices past its
    budget (20 s for --time-limit 6): once ``late``, a lattice is scored as unlaid without a
    drop, and the spread of the winner is skipped."""
    from optimizer.search.drop import DropWorld

    drops = []
    drop = DropWorld.drop
    monkeypatch.setattr(DropWorld, "drop", lambda self, *a, **k: drops.append(1) or drop(self, *a, **k))
    lat = staggered(cube)
    fams = (lat.family_a, lat.family_b)
    assert _lattice_penalty(_params(lat), cube, fams, late=lambda: True) == patterns.PAST_END and not drops
    assert _lattice_penalty(_params(lat), cube, fams) == pytest.approx(lat.area_per_block) and len(drops) == 2
    tight = lat.scaled(0.995)  # feasible, and so is its spread (the bond leaves a 1 % gap)
    assert patterns.with_clearance(tight, cube) != tight
    assert patterns.with_clearance(tight, cube, late=lambda: True) == tight
    assert not patterns.late(None)() and not patterns.late(60.0)() and patterns.late(-patterns.LATE_S - 1)()


def test_a_tuned_lattice_is_cached_and_reused(tmp_path, monkeypatch):
    monkeypatch.setenv("SHOHA_CACHE", str(tmp_path))
    block = get_block("box:1.3x1.1x0.9")
    first, tuning = patterns.pattern_for(block, block.name, tune_seconds=8.0)
    assert tuning.source == "tuned" and tuning.generations > 0
    assert list((tmp_path / "lattices").iterdir()), "nothing was cached"

    def no_tuning(*args, **kwargs):
        raise AssertionError("the cached lattice should have been reused")

    monkeypatch.setattr(patterns, "tune", no_tuning)
    again, cached = patterns.pattern_for(block, block.name, tune_seconds=2.0)
    # How it was tuned is kept with it: a lattice the clock cut is still the machine's.
    assert again == first and cached == replace(tuning, source="cached")
    # Another block is not served from this one's cache.
    other = get_block("box:1.3x1.1x0.95")
    assert lattice_for(other, other.name) == staggered(other)


def test_a_broken_cache_file_is_tuned_again(tmp_path, monkeypatch):
    monkeypatch.setenv("SHOHA_CACHE", str(tmp_path))
    block = get_block("box:1.2x1.2x1.2")
    path = patterns.cache_path(block)
    path.parent.mkdir(parents=True)
    path.write_text("{not json")
    lat = lattice_for(block, block.name, tune_seconds=8.0)
    assert lat == lattice_for(block, block.name)  # tuned, and cached over the broken file


def test_cli_block_tune_tunes_caches_and_reports(tmp_path):
    exe = str(Path(sys.executable).parent / "shoha")

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([exe, *args], capture_output=True, text=True, timeout=120,
                              env={**os.environ, "SHOHA_CACHE": str(tmp_path)})

    first = run("block", "tune", "box:1.1x0.9x0.7", "--seconds", "6", "--json")
    assert first.returncode == 0, first.stderr
    d = json.loads(first.stdout)
    assert d["source"] == "tuned" and Path(d["path"]).is_file() and d["area_per_block_m2"] > 0
    assert d["generations"] > 0 and isinstance(d["clock_cut"], bool)
    again = json.loads(run("block", "tune", "box:1.1x0.9x0.7", "--json").stdout)
    assert again["source"] == "cached" and again["area_per_block_m2"] == d["area_per_block_m2"]
    assert (again["generations"], again["clock_cut"]) == (d["generations"], d["clock_cut"])
    assert json.loads(run("block", "tune", "shake-4t", "--json").stdout)["source"] == "built in"
    bad = run("block", "tune", "box:1x1", "--json")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    # NaN is no time: it was let through and the tuner blamed the block.
    for seconds in ("nan", "0.5", "1e999", "abc"):
        bad = run("block", "tune", "box:1x1x0.5", "--seconds", seconds)
        assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1, bad.stderr
        assert "--seconds" in bad.stderr and "lattice" not in bad.stderr, bad.stderr


def test_optimize_says_how_its_pattern_was_tuned_and_then_that_it_was_cached(tmp_path, monkeypatch):
    """A block with no tuned pattern is tuned inside ``optimize``: its first phase says so, how
    many generations, and whether the clock cut them (the pattern then depends on the machine).
    The next run takes it from the cache; a built-in block has no such phase."""
    from geometry.scene import parse_scene
    from optimizer.api import optimize
    from optimizer.search.beam import BeamSearch

    monkeypatch.setenv("SHOHA_CACHE", str(tmp_path))
    text = ('name = "cubes"\nblock = "box:1.2x1.2x1.2"\ntarget_porosity_percent = 47.0\n'
            '[design]\ncrest_width_m = 3.0\nheight_m = 1.2\nslope_rise_run = [2.0, 3.0]\nlength_m = 3.0\n')
    scene = parse_scene(text, "cubes.toml", None)

    def run(s):
        return optimize(s, seed=1, time_limit=40, strategies=[BeamSearch()], settle_layout=False, cover=False)

    first = run(scene).phases[0]
    assert first["strategy"] == "tune" and first["source"] == "tuned" and first["generations"] > 0
    assert isinstance(first["clock_cut"], bool) and first["area_per_block_m2"] == pytest.approx(
        patterns.cached_lattice(scene.block).area_per_block)
    again = run(scene).phases[0]
    assert again["strategy"] == "tune" and again["source"] == "cached"
    assert (again["generations"], again["clock_cut"]) == (first["generations"], first["clock_cut"])
    builtin = parse_scene(text.replace("box:1.2x1.2x1.2", "shake-4t"), "shake.toml", None)
    assert "tune" not in [p["strategy"] for p in run(builtin).phases]

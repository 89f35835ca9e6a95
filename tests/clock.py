"""A clock for deadline tests: its seconds pass with the work done, not with the wall.

Every candidate a search lowers (``Build.lower``) and every physics settle it
runs advance the clock by a fixed cost. A strategy that keeps working past
its deadline without reading the clock shows up as fake seconds beyond it,
on any machine and under any load, with no wall-clock time asserted.
"""

from __future__ import annotations

import pytest

from optimizer.search.build import Build


class WorkClock:
    """Fake seconds: ``per_drop`` for each lowered candidate, ``per_settle`` for each settle.

    Parameters
    ----------
    per_drop, per_settle : float, fake seconds
    """

    def __init__(self, per_drop: float = 0.01, per_settle: float = 0.05):
        self.t = 0.0
        self.per_drop = per_drop
        self.per_settle = per_settle
        self.drops = 0
        self.settles = 0

    def __call__(self) -> float:
        return self.t

    def install(self, monkeypatch: pytest.MonkeyPatch) -> WorkClock:
        """Charge the work: wrap ``Build.lower`` and the settles the search runs."""
        import optimizer.search.physics as physics

        lower, settle = Build.lower, physics.settle

        def charged_lower(build, *args, **kwargs):
            self.t += self.per_drop
            self.drops += 1
            return lower(build, *args, **kwargs)

        def charged_settle(*args, **kwargs):
            self.t += self.per_settle
            self.settles += 1
            return settle(*args, **kwargs)

        monkeypatch.setattr(Build, "lower", charged_lower)
        monkeypatch.setattr(physics, "settle", charged_settle)
        return self


def with_reserve(problem, reserve: float):
    """``problem`` with settles timed in its run (:class:`SettleMeter`) that call for a settle
    reserve of ``reserve`` seconds (``optimizer.api.settle_reserve``), however far before its
    end its search's deadline was set: a deadline the timed settles have outgrown."""
    from dataclasses import replace

    from optimizer.api import MEASURED_MARGIN, settle_reserve
    from optimizer.search.problem import SETTLE_EXPONENT, SettleMeter

    scene = problem.scene
    meter = SettleMeter(rate=reserve / 2 / MEASURED_MARGIN / scene.required_blocks ** SETTLE_EXPONENT)
    assert settle_reserve(scene, meter=meter) == pytest.approx(reserve)
    return replace(problem, meter=meter)

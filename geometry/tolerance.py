"""The tolerance zone of Table II, and which blocks stick out of it.

Table II of the reference paper (the Irregular Block Finished Shape Management
Standard) allows the finished mound to exceed the design by ``+H/3`` on three
measures, ``H`` being the block height:

* base height (基準高): the crest may be up to ``H/3`` higher;
* top width (天端幅): the crest may be up to ``H/3`` wider;
* base length (法長, the slope length measured along the face): the slope may
  be up to ``H/3`` longer.

Construction used here (see ``docs/tolerance.md`` for the figure):

1. The tolerance crest lies ``crest_rise`` above the design crest.
2. The tolerance crest width is the design width plus ``crest_widening``,
   split evenly between the two sides (``H/6`` each).
3. Each tolerance slope runs from the tolerance crest edge down to the
   foundation with slope length ``s + slope_lengthening``, where
   ``s = h sqrt(1 + m^2)`` is the design slope length. Its horizontal run is
   then ``sqrt((s + H/3)^2 - (h + H/3)^2)``: slightly steeper than the design
   slope, so that all three of Table II's measures hold at once.
4. Table II says nothing of the ends of the prism. Each end moves out by
   ``end_extension`` (``H/3``), so that a block at an end is judged like a
   block at the crest edge.
5. Where the foundation is a rough underlayer, the zone reaches down to its
   lowest point, so that blocks resting in its hollows are not "out". It
   reaches ``tol.contact_depth`` (5 mm) further down in any case: a block
   that a physics settle or the simulator presses a few millimetres into the
   foundation is resting on it, as it would be resting on another block.
6. A wall-backed section (a mound in front of a caisson or seawall,
   ``[design] wall = true``) has a vertical wall face on its landward side,
   at ``x = -crest_width / 2``: the design and the zone both stop at it, and
   the crest, which can only widen seaward, takes the whole ``crest_widening``
   on that side.

The design prism lies inside this zone for any non-negative allowances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .blocks import Block
from .clip import volume_inside
from .constants import tol
from .errors import InputError
from .polytope import ConvexPolytope
from .pose import Pose


@dataclass(frozen=True)
class TrapezoidalPrism:
    """A trapezoidal prism along +y, symmetric about x = 0 unless a wall cuts it.

    Its cross-section in the x-z plane is a trapezoid centred on x = 0, whose
    landward side (-x) is, where ``wall_x`` is set, the vertical face
    ``x = wall_x`` instead of the slope. All in metres, world frame.
    """

    bottom_half_width: float
    top_half_width: float
    z_bottom: float
    z_top: float
    y_start: float
    y_end: float
    wall_x: float | None = None

    @property
    def height(self) -> float:
        return self.z_top - self.z_bottom

    @property
    def length(self) -> float:
        return self.y_end - self.y_start

    @property
    def section_area(self) -> float:
        """Area of the cross-section, m^2 (the shoelace formula over :attr:`section`)."""
        x, z = self.section[:, 0], self.section[:, 1]
        return float(0.5 * abs(np.dot(x, np.roll(z, -1)) - np.dot(z, np.roll(x, -1))))

    @property
    def volume(self) -> float:
        """Volume, m^3."""
        return self.section_area * self.length

    def half_width(self, z: float) -> float:
        """Half width of the cross-section at height ``z`` (the slopes carried on, the wall ignored)."""
        return self.bottom_half_width + (self.top_half_width - self.bottom_half_width) * (
            z - self.z_bottom) / self.height

    def left(self, z: float) -> float:
        """The landward edge of the cross-section at height ``z``: the wall, or the slope."""
        return self.wall_x if self.wall_x is not None else -self.half_width(z)

    def cut(self, slices: int, layers: int) -> list[TrapezoidalPrism]:
        """The prism cut into ``slices`` equal lengths along y and ``layers`` equal heights.

        Each part is again a trapezoidal prism whose half widths follow the
        slopes; slice-major order (part ``i * layers + j``).
        """
        ys = np.linspace(self.y_start, self.y_end, slices + 1)
        zs = np.linspace(self.z_bottom, self.z_top, layers + 1)
        return [TrapezoidalPrism(self.half_width(zs[j]), self.half_width(zs[j + 1]), float(zs[j]),
                                 float(zs[j + 1]), float(ys[i]), float(ys[i + 1]), self.wall_x)
                for i in range(slices) for j in range(layers)]

    @property
    def section(self) -> np.ndarray:
        """(4, 2) float: the cross-section's corners (x, z), counter-clockwise from bottom left."""
        b, t = self.bottom_half_width, self.top_half_width
        return np.array([[self.left(self.z_bottom), self.z_bottom], [b, self.z_bottom], [t, self.z_top],
                         [self.left(self.z_top), self.z_top]])

    @property
    def corners(self) -> np.ndarray:
        """(8, 3) float: the prism's corners, world frame."""
        sec = self.section
        return np.array([[x, y, z] for y in (self.y_start, self.y_end) for x, z in sec])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float: the axis-aligned bounding box."""
        c = self.corners
        return np.stack([c.min(axis=0), c.max(axis=0)])

    @property
    def polytope(self) -> ConvexPolytope:
        return _prism_polytope(self)


_POLYTOPES: dict[TrapezoidalPrism, ConvexPolytope] = {}


def _prism_polytope(prism: TrapezoidalPrism) -> ConvexPolytope:
    # A frozen dataclass of floats hashes by value; cache its hull.
    poly = _POLYTOPES.get(prism)
    if poly is None:
        poly = _POLYTOPES[prism] = ConvexPolytope.from_points(prism.corners, name="prism")
    return poly


@dataclass(frozen=True)
class Allowance:
    """How far the tolerance zone exceeds the design, metres (Table II).

    Each defaults to ``H/3`` of the scene's block.
    """

    crest_rise: float
    crest_widening: float
    slope_lengthening: float
    end_extension: float

    @classmethod
    def table_ii(cls, block_height: float) -> Allowance:
        third = block_height / 3.0
        return cls(third, third, third, third)


def design_prism(crest_width: float, height: float, slope: float, length: float,
                 wall: bool = False) -> TrapezoidalPrism:
    """The design trapezoidal prism.

    Parameters
    ----------
    crest_width : float, m
    height : float, m
        Crest height above the foundation top (z = 0).
    slope : float
        Horizontal run per unit rise of each side slope (4/3 for a 3:4 slope).
    length : float, m
        Length along the crest, from y = 0 to y = length.
    wall : bool
        A wall face on the landward side, at ``x = -crest_width / 2``, instead of a slope.
    """
    return TrapezoidalPrism(crest_width / 2 + slope * height, crest_width / 2, 0.0, height, 0.0, length,
                            -crest_width / 2 if wall else None)


def tolerance_prism(
    design: TrapezoidalPrism, allowance: Allowance, z_bottom: float = 0.0
) -> TrapezoidalPrism:
    """The tolerance prism around ``design``: see the module docstring.

    ``z_bottom`` is the foundation's lowest point; the zone goes
    ``tol.contact_depth`` below it.
    """
    z_bottom = z_bottom - tol.contact_depth
    a = allowance
    h = design.height
    run = design.bottom_half_width - design.top_half_width
    slope_length = np.hypot(h, run)
    new_h = h + a.crest_rise
    new_length = slope_length + a.slope_lengthening
    if new_length <= new_h:
        raise InputError(
            f"tolerance: slope length {new_length:.3f} m does not exceed height {new_h:.3f} m"
        )
    new_run = np.sqrt(new_length**2 - new_h**2)
    # Behind a wall the crest can widen only seaward: it takes the whole widening there.
    top = design.top_half_width + (a.crest_widening if design.wall_x is not None else a.crest_widening / 2)
    z_top = design.z_top + a.crest_rise
    # Extend the slope lines below the foundation top where the zone goes deeper.
    bottom = top + new_run * (z_top - z_bottom) / (z_top - design.z_bottom)
    return TrapezoidalPrism(
        float(bottom), float(top), float(z_bottom), float(z_top),
        design.y_start - a.end_extension, design.y_end + a.end_extension, design.wall_x,
    )


def outside_volume(block: Block, pose: Pose, zone: TrapezoidalPrism) -> float:
    """Volume of a posed block outside the tolerance zone, m^3 (exact)."""
    return max(0.0, block.volume - volume_inside(block, pose, zone.polytope))


def out_of_tolerance(
    placed: list[tuple[int, Block, Pose]], zone: TrapezoidalPrism
) -> list[tuple[int, float]]:
    """Blocks with any volume outside the tolerance zone.

    Returns
    -------
    list of (id, outside volume m^3), in layout order.
    """
    out = []
    for key, block, pose in placed:
        v = outside_volume(block, pose, zone)
        if v > tol.volume:
            out.append((key, v))
    return out

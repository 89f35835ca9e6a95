"""Numerical tolerances and physical constants, in one place.

Every comparison against a small number in shoha goes through ``tol``, in the
way trimesh keeps its ``tol`` object: no scattered ``1e-8`` literals.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """Tolerances used across the package (SI units).

    Attributes
    ----------
    quaternion_norm : float
        A file quaternion whose norm is within this of 1 is normalised; any
        other norm is an input error (docs/contract.md, layout file).
    distance : float, metres
        Two points closer than this are the same point. Used when testing
        whether a vertex lies inside a half-space.
    volume : float, cubic metres
        Volumes below this are zero: a block "sticks out" of a prism only when
        more than this much of it lies outside (a 0.1 mm cube).
    contact_depth : float, metres
        Blocks that interpenetrate by no more than this are in contact, not in
        collision. Concrete blocks resting on each other in a physics engine,
        or in a simulator save, overlap by a few millimetres (PhysX's default
        contact offset is 1 cm); 5 mm keeps those out of the collision report
        while any push of one block into another is caught.
    drop_resolution : float, metres
        How close a lowered block comes to what it rests on.
    rest_speed : float, m/s
        A block is at rest in a physics settle if over the last
        ``rest_time`` no point of it strayed more than ``rest_speed *
        rest_time / 2`` (0.1 mm) from where it was (settle.base.RestMonitor).
    rest_time : float, seconds
        A settle stops early once every block is at rest over this window.
        A block that starts from rest with a constant acceleration ``a``
        moves ``a rest_time^2 / 2`` in it, so it counts as at rest only if
        ``a < rest_speed / rest_time`` (0.005 m/s^2); stopping can then hide
        at most ``a T^2 / 2`` = 1 cm of motion in a 2 s settle, a fifth of
        the 0.05 H stability threshold of a 1 m block.
    plane_angle : float, radians
        In a section scene a block may turn only about y; its local y axis may
        be off world y by this much (float noise of a file's quaternion).
    contact_gap : float, metres
        Two blocks, or a block and the foundation, are in contact (the
        interlock count of ``shoha score``, optimizer/interlock.py) when FCL's
        distance between their convex pieces is at most this, or they
        overlap. A simulator save records blocks where PhysX left them, within
        Unity's default contact offset (1 cm) of what they rest on, and a pile
        settles by millimetres more; 2 cm is 1.2 % of the 4-ton Shake Block's
        height and a small part of a leg's thickness, so a block this close
        bears on its neighbour once the pile settles, while a block a leg's
        width away is a neighbour, not a contact.
    relative : float, dimensionless
        Relative slack for a float that should be a whole number before it is
        rounded up or down: the required block count ``ceil((1 - target) V /
        V_block)`` (scene.py), a voxel count ``ceil(extent / size)``
        (porosity.py), and the lattice tuner's check that its penalty is the
        bare area (patterns.py). Products and quotients of a few floats are
        off by ~1e-15 relative; 1e-9 keeps 75.0000000000001 from becoming 76
        and is far below any real fraction of a block or voxel.
    time_slack : float, dimensionless
        Relative slack on the settle's rest window: simulated times are sums
        of float time steps (settle.base.RestMonitor).
    facet_rounding : float, dimensionless
        Coplanar triangles of one hull facet have equations that agree to
        ~1e-15 of the part's size, distinct facets differ by far more: plane
        keys are rounded to 1e-9 of the size (polytope.py).
    length_floor : float, metres
        A size below this is taken as zero, to keep a division by a part's
        size defined (polytope.py).
    orientation : float, dimensionless
        A face counts as facing up or down when the z part of its normal
        exceeds this fraction of the normal's length (drop.py); vertical faces
        (rounding noise of ~1e-16) count as neither.
    parallel : float, square metres
        Two projected edges are parallel, and have no single crossing, when
        the cross product of their directions is below this (drop.py): edges
        are decimetres to metres long, so 1e-12 m^2 is rounding noise.
    grid_edge : float, dimensionless
        Fraction of a cell by which a point on the far edge of a height field
        is kept inside its last cell (scene.Foundation.height_at).
    energy : float, energy units
        An annealing move improves the best build only by more than this:
        the energy sums porosity points and counts, and rounding in the
        incremental update is ~1e-13.
    objective_volume : float, cubic metres
        The CP-SAT bound's selection beats the heuristic's ground layer only
        by more than this; its objective is rounded to 1e-6 m^3, and 1e-9
        m^3 separates a real gain from that rounding.
    fit : float, circumradii
        Convergence tolerance of the fit of the Shake Block's leg length
        (brentq, blocks.shake_fit): the block's shape to 1e-12 of its size.
    tuning : float, dimensionless
        Convergence tolerance of the lattice tuner's differential evolution
        (relative spread of its population's energies, patterns.py).
    prism_rtol : float, dimensionless
        Relative difference between a piece's volume and (outline area) x (y
        extent) tolerated for it to count as a prism along y (settle/section.py):
        a prism meets it to float precision, a chamfer of a thousandth of the
        piece's size does not.
    """

    quaternion_norm: float = 1e-6
    distance: float = 1e-9
    volume: float = 1e-12
    contact_depth: float = 5e-3
    drop_resolution: float = 1e-3
    rest_speed: float = 1e-3
    rest_time: float = 0.2
    plane_angle: float = 1e-6
    contact_gap: float = 2e-2
    relative: float = 1e-9
    time_slack: float = 1e-9
    facet_rounding: float = 1e-9
    length_floor: float = 1e-12
    orientation: float = 1e-9
    parallel: float = 1e-12
    grid_edge: float = 1e-6
    energy: float = 1e-12
    objective_volume: float = 1e-9
    fit: float = 1e-12
    tuning: float = 1e-8
    prism_rtol: float = 1e-6


tol = Tolerances()

#: Density of the concrete of wave-dissipating blocks, kg/m^3. With Table I's
#: volume of 1.735 m^3 it gives the 3.991 t of the 4-ton Shake Block.
CONCRETE_DENSITY = 2300.0

#: Standard gravity, m/s^2.
GRAVITY = 9.81

#: Largest number of blocks a layout file may hold. A full-scale breakwater
#: holds a few thousand; a file asking for more is a mistake or an attack.
MAX_BLOCKS = 100_000

#: Largest voxel grid the voxel porosity methods build (voxels). 200^3 voxels
#: of the paper's finest setting is 8e6; this admits about 500^3.
MAX_VOXELS = 130_000_000

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
        other norm is an input error (CONTRACT.md, layout file).
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

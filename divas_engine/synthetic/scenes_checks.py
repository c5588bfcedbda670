"""Synthetic scenes of two hard cases of interactive 3D selection (world z up, metres).

* ``wheel`` — a thin spoked wheel (rim, hub, 12 spokes) standing upright on the floor a
  short distance (0.12, three rim diameters of tube) in front of a textured wall; the
  wall shows through between the spokes. Forward-facing: 30 training cameras on a
  jittered 6×5 grid, 8 test cameras between and in front of them.
* ``pedestal`` — a statue (a body, shoulders, a head and a base disc) standing on a
  pedestal of another material (a stone block with a cornice) on a floor, a wall half
  around it; 360°-like half ring of training cameras (60), 8 test cameras.

Both carry the target at ``TARGET_DENSITY``× the background's surfels per area, as
the other scenes do (2DGS densifies detail).
"""

from __future__ import annotations

import math

import numpy as np

from .builder import SceneSpec, rng_for
from .rigs import Intrinsics, forward_facing_rig, half_ring_rigs
from .surfaces import Cylinder, Disc, Frame, Rect, Sphere, Surface, Torus, box

__all__ = ["wheel_spec", "pedestal_spec", "CHECK_SCENE_BUILDERS"]

X, Y, Z = np.eye(3)
TARGET_DENSITY = 4.0


def wheel_spec(seed: int, size: int) -> SceneSpec:
    rim_R, rim_r, hub_r, spoke_r = 0.40, 0.014, 0.035, 0.005
    cz = rim_R + rim_r  # the rim rests on the floor
    centre = np.array([0.0, 0.0, cz])
    gap = 0.12  # wheel plane to the wall
    metal = dict(target=True, palette="ceramic", tex_scale=0.05, density=TARGET_DENSITY)
    s: list[Surface] = []
    # the wheel in the x-z plane, its axle along y
    s.append(Torus("rim", Frame.make(centre, Y, X), rim_R, rim_r, part="rim", **metal))
    s.append(Cylinder("hub", Frame.make(centre - 0.03 * Y, Y, X), hub_r, 0.0, 0.06, **metal))
    s.append(Disc("hub_cap", Frame.make(centre - 0.03 * Y, -Y, X), hub_r, **metal))
    for i in range(12):
        a = 2.0 * math.pi * i / 12 + 0.13
        d = math.cos(a) * X + math.sin(a) * Z
        s.append(
            Cylinder(
                f"spoke_{i}",
                Frame.make(centre + hub_r * d, d, Y),
                spoke_r,
                0.0,
                rim_R - rim_r - hub_r,
                part="spokes",
                **metal,
            )
        )
    wall = dict(palette="wood", tex_scale=0.12)
    s.append(Rect("wall", Frame.make((0.0, gap + rim_r, 0.75), -Y, X), 1.2, 0.75, **wall))
    s.append(
        Disc("floor", Frame.make((0, 0, 0), Z, X), 1.6, palette="stone", tex_scale=0.3, density=0.4)
    )
    intr = Intrinsics()
    rng = rng_for(seed, "wheel", "cameras")
    eye = np.array([0.0, -2.4, 0.75])
    look = np.array([0.0, 0.0, cz])
    train = forward_facing_rig(
        rng,
        intr,
        center=eye,
        look_at=look,
        rows=5,
        cols=6,
        step=(0.16, 0.1),
        jitter=0.3,
        aim_jitter=0.02,
        prefix="train_",
    )
    test = forward_facing_rig(
        rng,
        intr,
        center=eye,
        look_at=look,
        rows=2,
        cols=4,
        step=(0.24, 0.2),
        jitter=0.2,
        aim_jitter=0.02,
        prefix="test_",
        depth_offset=0.3,
    )
    return SceneSpec(
        "wheel",
        s,
        train,
        test,
        centre,
        True,
        "spoked wheel: rim, hub and 12 thin spokes, standing 0.12 in front of a textured "
        "wall (wall and floor are background)",
        extra={"wall_gap": gap, "spoke_radius": spoke_r},
    )


def pedestal_spec(seed: int, size: int) -> SceneSpec:
    ped_h, ped_half = 0.7, 0.2
    top = ped_h + 0.02  # the cornice's top
    stat = dict(target=True, palette="terracotta", tex_scale=0.06, density=TARGET_DENSITY)
    s: list[Surface] = []
    s += box(
        "pedestal",
        (0, 0, ped_h / 2),
        (ped_half, ped_half, ped_h / 2),
        top=False,
        palette="stone",
        tex_scale=0.15,
    )
    s += box(
        "cornice",
        (0, 0, ped_h + 0.01),
        (ped_half + 0.03, ped_half + 0.03, 0.01),
        bottom=True,
        palette="stone",
        tex_scale=0.15,
    )
    # the statue: a base disc, a tapering body, shoulders, a neck and a head
    s.append(Cylinder("statue_base", Frame.make((0, 0, top), Z, X), 0.12, 0.0, 0.03, **stat))
    s.append(Disc("statue_base_top", Frame.make((0, 0, top + 0.03), Z, X), 0.12, 0.07, **stat))
    s.append(Cylinder("statue_body", Frame.make((0, 0, top + 0.03), Z, X), 0.07, 0.0, 0.32, **stat))
    s.append(
        Sphere(
            "statue_shoulders",
            Frame.make((0, 0, top + 0.35), Z, X),
            0.1,
            0.0,
            math.radians(80),
            **stat,
        )
    )
    s.append(Cylinder("statue_neck", Frame.make((0, 0, top + 0.44), Z, X), 0.03, 0.0, 0.05, **stat))
    s.append(Sphere("statue_head", Frame.make((0, 0, top + 0.56), Z, X), 0.075, **stat))
    s.append(
        Disc("floor", Frame.make((0, 0, 0), Z, X), 2.4, palette="wood", tex_scale=0.4, density=0.3)
    )
    s.append(
        Cylinder(
            "back_wall",
            Frame.make((0, 0, 0), Z, X),
            2.3,
            0.0,
            2.2,
            0.0,
            math.pi,
            inward=True,
            palette="plaster",
            tex_scale=0.5,
            density=0.3,
        )
    )
    centre = np.array([0.0, 0.0, 0.75])
    intr = Intrinsics()
    crng = rng_for(seed, "pedestal", "cameras")
    train, test = half_ring_rigs(
        crng, intr, center=centre, radius=2.0, elevations_deg=[8, 25], test_elevation_deg=15
    )
    return SceneSpec(
        "pedestal",
        s,
        train,
        test,
        centre,
        False,
        "statue (base, body, shoulders, neck, head) on a stone pedestal with a cornice "
        "(pedestal, floor and wall are background)",
    )


CHECK_SCENE_BUILDERS = {"wheel": wheel_spec, "pedestal": pedestal_spec}

"""The named synthetic scenes (world z up, units ≈ metres).

* ``ribs`` — Trex-like skeleton: a spine with 7 thin parallel curved ribs
  (partial tori with hemispherical end caps), a skull and a tail cap, on a
  background display stand, turned 35° to the cameras and standing 0.3 object
  heights in front of a textured staircase (same palette as the bones). 30
  LLFF-like forward-facing training cameras on a jittered 6×5 grid, 8 test
  cameras between and in front of them. The rib tube radius is ``RIB_VOXELS`` ×
  the NOTES occupancy voxel ``h_v`` predicted (pilot sample) for the requested
  size — it shrinks as the size grows — clamped to ``RIB_R_MAX`` so neighbouring
  ribs never touch (below ~12k surfels that clamp makes them < 1 h_v). The
  skeleton carries ``BONE_DENSITY``× the background's surfels per area, so it
  holds the majority and the median scale (hence h_v) follows it. Also a NeRF
  density grid (``grid.py``) over everything but the floor in front of the stand.
* ``plant`` — a potted plant (pot, rim, soil, thin stems, curved leaves) on a
  table with a mug and a book, a floor disc and a background dome at 60× the
  scene radius; 104 training cameras on three 360° rings.
* ``occluded`` — a vase with a handle on a plinth, partly hidden behind a
  pillar and a low plank fence between it and the camera half ring, extra
  floaters between the cameras and the vase.
"""

from __future__ import annotations

import math

import numpy as np

from .builder import SceneSpec, allocate_counts, notes_grid_params, rng_for, surfel_scales
from .rigs import Intrinsics, forward_facing_rig, half_ring_rigs, ring_rig
from .scenes_checks import CHECK_SCENE_BUILDERS
from .surfaces import Cylinder, Disc, Frame, Rect, Sphere, Surface, Torus, box

__all__ = ["SCENE_BUILDERS", "SUITE_SCENES", "RIB_VOXELS", "predict_hv", "bounding_radius"]

#: Rib tube radius in units of the predicted occupancy voxel h_v.
RIB_VOXELS = 1.2
RIB_PITCH = 0.2
RIB_R_MAX = 0.07  # keeps a 6 cm gap between neighbouring ribs
RIB_R_MIN = 0.002
DOME_FACTOR = 60.0
#: Relative surfel density (per area) of the plant and the vase (2DGS densifies detail).
TARGET_DENSITY = 4.0
PILOT = 20_000
SKELETON_YAW = math.radians(35.0)
#: Surfels per area on the skeleton relative to the background (2DGS densifies detail):
#: makes the skeleton the majority, so the NOTES median scale (and h_v) follows it.
BONE_DENSITY = 12.0

X, Y, Z = np.eye(3)


def predict_hv(spec: SceneSpec, size: int, seed: int) -> float:
    """NOTES h_v of the surfels the builder will produce, from a pilot sample.

    The pilot draws ``PILOT`` centres with the final per-surface proportions and
    the final per-surface spacing (floaters and needles, ~2.5 %, are left out)."""
    n_surf = size - int(round(spec.floater_share * size))
    counts = allocate_counts(spec.surfaces, n_surf)
    areas = np.array([s.area() for s in spec.surfaces])
    spacing = np.sqrt(areas / np.maximum(counts, 1))
    m = np.floor(PILOT * counts / counts.sum()).astype(int)
    pts, sc = [], []
    for j, s in enumerate(spec.surfaces):
        if m[j] == 0:
            continue
        rng = rng_for(seed, spec.name, "pilot", s.name)
        smp = s.sample(rng, int(m[j]))
        su, sv, _ = surfel_scales(rng, int(m[j]), float(spacing[j]), smp.curvature_radius)
        pts.append(smp.points)
        sc.append(np.stack([su, sv], 1))
    return notes_grid_params(np.concatenate(pts), np.concatenate(sc), spec.forward_facing)["h_v"]


def bounding_radius(surfaces: list[Surface], center: np.ndarray, n: int = 4000) -> float:
    """Radius around ``center`` enclosing the surfaces (dense sample + 1 % margin)."""
    rng = np.random.default_rng(0)
    r = 0.0
    for s in surfaces:
        p = s.sample(rng, n).points
        r = max(r, float(np.linalg.norm(p - center, axis=1).max()))
    return 1.01 * r


# --------------------------------------------------------------------------- ribs
def _ribs_spec(seed: int, rib_r: float) -> SceneSpec:
    z_sp, r_sp, R_rib = 0.80, 0.08, 0.32
    x_tail, x_head = -0.80, 0.82
    rib_x = RIB_PITCH * (np.arange(7) - 3)
    # the skeleton is built along its own x axis, then turned by SKELETON_YAW about z so the
    # cameras see the rib arcs obliquely (front and back halves at different depths)
    c, s_ = math.cos(SKELETON_YAW), math.sin(SKELETON_YAW)
    yaw = np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])

    def fr(o, zax, xh) -> Frame:
        return Frame.make(yaw @ np.asarray(o, float), yaw @ zax, yaw @ xh)

    bone = dict(target=True, palette="stone", tex_scale=0.2, solid=True, density=BONE_DENSITY)
    s: list[Surface] = []
    s.append(
        Cylinder(
            "spine", fr((x_tail, 0, z_sp), X, Z), r_sp, 0.0, x_head - x_tail, part="spine", **bone
        )
    )
    s.append(
        Sphere(
            "tail_cap", fr((x_tail, 0, z_sp), -X, Z), r_sp, 0.0, math.pi / 2, part="spine", **bone
        )
    )
    s.append(Sphere("skull", fr((0.92, 0, z_sp + 0.04), X, Z), 0.15, part="skull", **bone))
    psi_end = math.radians(150)
    for i, x in enumerate(rib_x):
        rib = Torus(
            f"rib_{i}",
            fr((x, 0, z_sp - R_rib), X, Z),
            R_rib,
            rib_r,
            -psi_end,
            psi_end,
            part="ribs",
            **bone,
        )
        s.append(rib)
        for k, pe in enumerate((-psi_end, psi_end)):  # hemispherical caps close the tube ends
            c = rib.frame.to_world(np.array([[R_rib * math.cos(pe), R_rib * math.sin(pe), 0]]))[0]
            t = rib.frame.vec_to_world(np.array([[-math.sin(pe), math.cos(pe), 0.0]]))[0]
            s.append(
                Sphere(
                    f"rib_{i}_cap{k}",
                    Frame.make(c, t if k else -t, Z),
                    rib_r,
                    0.0,
                    math.pi / 2,
                    part="ribs",
                    **bone,
                )
            )
    # background: display stand, floor, staircase, back wall
    post_x = 0.5 * RIB_PITCH
    s.append(
        Cylinder(
            "stand_post",
            fr((post_x, 0, 0.03), Z, X),
            0.025,
            0.0,
            z_sp - r_sp + 0.01 - 0.03,
            palette="wood",
            tex_scale=0.1,
            solid=True,
        )
    )
    s.append(
        Cylinder(
            "stand_base",
            fr((post_x, 0, 0), Z, X),
            0.2,
            0.0,
            0.03,
            palette="wood",
            tex_scale=0.1,
            solid=True,
        )
    )
    s.append(Disc("stand_top", fr((post_x, 0, 0.03), Z, X), 0.2, palette="wood", tex_scale=0.1))
    height = z_sp + 0.04 + 0.15  # object height (top of the skull)
    # the skeleton's back with the thickest ribs (depth along +y, analytic over the rib arcs)
    psi = np.radians(np.linspace(-150, 150, 601))
    back = max(
        float(
            np.max(
                (
                    yaw
                    @ np.stack(
                        [
                            np.full_like(psi, x),
                            -(R_rib + RIB_R_MAX) * np.sin(psi),
                            np.zeros_like(psi),
                        ]
                    )
                )[1]
            )
        )
        for x in rib_x
    )
    back = max(
        back, float((yaw @ [x_head + 0.1, 0, 0])[1]) + 0.15, float((yaw @ [x_tail, 0, 0])[1]) + r_sp
    )
    y_s = back + 0.3 * height  # first riser: 0.3 object heights behind
    half_w, rise, run, steps = 1.5, 0.2, 0.26, 6
    s.append(
        Rect(
            "floor",
            Frame.make((0, (y_s - 1.5) / 2, 0), Z, X),
            half_w,
            (y_s + 1.5) / 2,
            palette="plaster",
            tex_scale=0.4,
        )
    )
    for k in range(steps):
        y0 = y_s + k * run
        s.append(
            Rect(
                f"stairs/riser_{k}",
                Frame.make((0, y0, (k + 0.5) * rise), -Y, X),
                half_w,
                rise / 2,
                palette="stone",
                tex_scale=0.3,
            )
        )
        s.append(
            Rect(
                f"stairs/tread_{k}",
                Frame.make((0, y0 + run / 2, (k + 1) * rise), Z, X),
                half_w,
                run / 2,
                palette="stone",
                tex_scale=0.3,
            )
        )
    y_top, z_top = y_s + steps * run, steps * rise
    s.append(
        Rect(
            "back_wall",
            Frame.make((0, y_top, z_top + 0.6), -Y, X),
            half_w,
            0.6,
            palette="plaster",
            tex_scale=0.4,
        )
    )

    center = np.array([0.05, 0.0, 0.55])
    intr = Intrinsics()
    rng = rng_for(seed, "ribs", "cameras")
    eye = np.array([0.05, -2.9, 0.78])
    train = forward_facing_rig(
        rng,
        intr,
        center=eye,
        look_at=center,
        rows=5,
        cols=6,
        step=(0.14, 0.09),
        jitter=0.3,
        aim_jitter=0.03,
        prefix="train_",
    )
    test = forward_facing_rig(
        rng,
        intr,
        center=eye,
        look_at=center,
        rows=2,
        cols=4,
        step=(0.21, 0.18),
        jitter=0.2,
        aim_jitter=0.03,
        prefix="test_",
        depth_offset=0.3,
    )
    extra = {
        "rib_radius": rib_r,
        "rib_count": len(rib_x),
        "rib_pitch": RIB_PITCH,
        "rib_cage_radius": R_rib,
        "spine_radius": r_sp,
        "object_height": height,
        "staircase_gap": y_s - back,
        "skeleton_yaw_deg": math.degrees(SKELETON_YAW),
        "rib_voxels_target": RIB_VOXELS,
    }
    return SceneSpec(
        "ribs",
        s,
        train,
        test,
        center,
        True,
        "skeleton: spine, tail cap, skull and 7 thin parallel curved ribs "
        "(the display stand is background)",
        extra=extra,
    )


def ribs_spec(seed: int, size: int) -> SceneSpec:
    r = 0.05
    for _ in range(3):  # fixed point: the rib area changes the spacing a little
        hv = predict_hv(_ribs_spec(seed, r), size, seed)
        r = float(np.clip(RIB_VOXELS * hv, RIB_R_MIN, RIB_R_MAX))
    spec = _ribs_spec(seed, r)
    spec.extra["h_v_predicted"] = hv
    return spec


# --------------------------------------------------------------------------- plant
def plant_spec(seed: int, size: int) -> SceneSpec:
    center = np.array([0.0, 0.0, 0.95])
    s: list[Surface] = []
    wood = dict(palette="wood", tex_scale=0.3)
    s += box("table", (0, 0, 0.735), (0.6, 0.4, 0.015), bottom=True, **wood)
    for i, (lx, ly) in enumerate([(0.55, 0.35), (-0.55, 0.35), (-0.55, -0.35), (0.55, -0.35)]):
        s.append(
            Cylinder(f"table_leg_{i}", Frame.make((lx, ly, 0), Z, X), 0.025, 0.0, 0.72, **wood)
        )
    # the plant (target)
    # 2DGS densifies detailed geometry: the plant carries TARGET_DENSITY× surfels per area
    pot = dict(
        target=True, palette="terracotta", tex_scale=0.08, part="pot", density=TARGET_DENSITY
    )
    s.append(Cylinder("pot_outer", Frame.make((0, 0, 0.75), Z, X), 0.09, 0.0, 0.15, **pot))
    s.append(
        Cylinder("pot_inner", Frame.make((0, 0, 0.75), Z, X), 0.082, 0.11, 0.15, inward=True, **pot)
    )
    s.append(Torus("pot_rim", Frame.make((0, 0, 0.90), Z, X), 0.086, 0.004, **pot))
    s.append(
        Disc(
            "soil",
            Frame.make((0, 0, 0.86), Z, X),
            0.082,
            target=True,
            palette="wood",
            tex_scale=0.03,
            part="pot",
            density=TARGET_DENSITY,
        )
    )
    rng = rng_for(seed, "plant", "layout")
    leaf_kw = dict(
        target=True, palette="foliage", tex_scale=0.05, part="leaves", density=TARGET_DENSITY
    )
    n_stems = 6
    for i in range(n_stems):
        a = 2 * math.pi * i / n_stems + rng.uniform(-0.3, 0.3)
        tilt = math.radians(rng.uniform(12, 30))
        base = np.array([0.035 * math.cos(a), 0.035 * math.sin(a), 0.86])
        d = np.array([math.sin(tilt) * math.cos(a), math.sin(tilt) * math.sin(a), math.cos(tilt)])
        length = rng.uniform(0.22, 0.38)
        s.append(
            Cylinder(
                f"stem_{i}",
                Frame.make(base, d, X),
                rng.uniform(0.0045, 0.006),
                0.0,
                length,
                target=True,
                palette="foliage",
                tex_scale=0.05,
                part="stems",
                density=TARGET_DENSITY,
            )
        )
        for j, (f, daz) in enumerate([(0.55, 1.2), (0.8, -1.2), (1.0, 0.0)]):
            b = base + d * f * length
            az = a + daz + rng.uniform(-0.3, 0.3)
            el = math.radians(rng.uniform(15, 40))
            dl = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
            n0 = Z - (Z @ dl) * dl
            n0 /= np.linalg.norm(n0)
            w = np.cross(n0, dl)
            rc, ll, hw = rng.uniform(0.09, 0.16), rng.uniform(0.09, 0.15), rng.uniform(0.022, 0.035)
            s.append(
                Cylinder(
                    f"leaf_{i}_{j}",
                    Frame.make(b - rc * n0, w, n0),
                    rc,
                    -hw,
                    hw,
                    0.0,
                    ll / rc,
                    leaf=True,
                    **leaf_kw,
                )
            )
    # distractors sharing the target's palettes
    mug = dict(palette="terracotta", tex_scale=0.08)
    mx, my = 0.32, 0.12
    s.append(Cylinder("mug_outer", Frame.make((mx, my, 0.75), Z, X), 0.04, 0.0, 0.10, **mug))
    s.append(
        Cylinder(
            "mug_inner", Frame.make((mx, my, 0.75), Z, X), 0.036, 0.01, 0.10, inward=True, **mug
        )
    )
    s.append(Disc("mug_bottom", Frame.make((mx, my, 0.76), Z, X), 0.036, **mug))
    s.append(Torus("mug_rim", Frame.make((mx, my, 0.85), Z, X), 0.038, 0.002, **mug))
    s.append(
        Torus(
            "mug_handle",
            Frame.make((mx + 0.045, my, 0.80), Y, X),
            0.028,
            0.006,
            math.radians(-100),
            math.radians(100),
            **mug,
        )
    )
    s += box("book", (-0.3, -0.15, 0.765), (0.11, 0.075, 0.015), palette="foliage", tex_scale=0.05)
    s.append(
        Disc("floor", Frame.make((0, 0, 0), Z, X), 2.2, palette="wood", tex_scale=0.5, density=0.3)
    )
    radius = bounding_radius(s, center)
    dome_r = DOME_FACTOR * radius
    s.append(
        Sphere(
            "dome",
            Frame.make(center, Z, X),
            dome_r,
            inward=True,
            palette="sky",
            tex_scale=0.08 * dome_r,
            share=0.008,
        )
    )

    intr = Intrinsics()
    crng = rng_for(seed, "plant", "cameras")
    train = ring_rig(
        crng,
        intr,
        center=center,
        radius=1.5,
        elevations_deg=[8, 28, 50],
        counts=[40, 36, 28],
        prefix="train_",
        radius_jitter=0.03,
        angle_jitter_deg=1.5,
        aim_jitter=0.02,
    )
    test = ring_rig(
        crng,
        intr,
        center=center,
        radius=1.5,
        elevations_deg=[18, 40],
        counts=[5, 5],
        prefix="test_",
        az_offset=0.5,
        aim_jitter=0.02,
    )
    spec = SceneSpec(
        "plant",
        s,
        train,
        test,
        center,
        False,
        "potted plant: pot, rim, soil, 6 thin stems and 18 curved leaves "
        "(table, mug, book, floor and dome are background)",
        extra={"dome_radius": dome_r, "radius": radius},
    )
    return spec


# --------------------------------------------------------------------------- occluded
def occluded_spec(seed: int, size: int) -> SceneSpec:
    center = np.array([0.0, 0.0, 0.62])
    s: list[Surface] = []
    s.append(
        Disc("floor", Frame.make((0, 0, 0), Z, X), 2.7, palette="wood", tex_scale=0.4, density=0.3)
    )
    s.append(
        Cylinder(
            "back_wall",
            Frame.make((0, 0, 0), Z, X),
            2.6,
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
    s += box("plinth", (0, 0, 0.2), (0.2, 0.2, 0.2), palette="stone", tex_scale=0.2)
    vase = dict(target=True, palette="ceramic", tex_scale=0.1, density=TARGET_DENSITY)
    s.append(Cylinder("vase_foot", Frame.make((0, 0, 0.40), Z, X), 0.085, 0.0, 0.043, **vase))
    s.append(
        Sphere(
            "vase_body",
            Frame.make((0, 0, 0.59), Z, X),
            0.17,
            math.radians(25),
            math.radians(150),
            **vase,
        )
    )
    top = 0.59 + 0.17 * math.cos(math.radians(25))
    neck_r = 0.17 * math.sin(math.radians(25))
    s.append(Cylinder("vase_neck", Frame.make((0, 0, top), Z, X), neck_r, 0.0, 0.86 - top, **vase))
    s.append(Torus("vase_lip", Frame.make((0, 0, 0.86), Z, X), neck_r + 0.012, 0.012, **vase))
    s.append(
        Torus(
            "vase_handle",
            Frame.make((0.07, 0, 0.62), Y, X),
            0.13,
            0.012,
            math.radians(-60),
            math.radians(60),
            **vase,
        )
    )
    occ = dict(palette="ceramic", tex_scale=0.1)  # the pillar shares the vase's palette
    s += box("pillar", (0.04, -0.62, 0.8), (0.07, 0.07, 0.8), **occ)
    fence = dict(palette="wood", tex_scale=0.15)
    s += box("plank", (0, -0.5, 0.48), (0.5, 0.02, 0.05), bottom=True, **fence)
    for i, x in enumerate((-0.48, 0.48)):
        s += box(f"fence_post_{i}", (x, -0.5, 0.215), (0.02, 0.02, 0.215), top=False, **fence)

    intr = Intrinsics()
    crng = rng_for(seed, "occluded", "cameras")
    train, test = half_ring_rigs(
        crng, intr, center=center, radius=2.2, elevations_deg=[6, 20], test_elevation_deg=13
    )
    return SceneSpec(
        "occluded",
        s,
        train,
        test,
        center,
        False,
        "vase (foot, body, neck, lip, handle) on a plinth, partly hidden behind a "
        "pillar and a plank fence (plinth, pillar, fence, floor, wall are background)",
        focus_floater_share=0.005,
        focus=(center, 0.25),
        extra={"occluders": ["pillar", "plank", "fence_post_0", "fence_post_1"]},
    )


#: The paper-style suite (``divas eval``'s default scenes).
SUITE_SCENES = ("ribs", "plant", "occluded")
SCENE_BUILDERS = {
    "ribs": ribs_spec,
    "plant": plant_spec,
    "occluded": occluded_spec,
    **CHECK_SCENE_BUILDERS,
}

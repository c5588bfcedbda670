"""The synthetic scenes as *trained 3DGS*: volumetric Gaussians with exact ground truth.

Same scene specification as the 2DGS variant (``scenes.py``), but 3D Gaussians drawn from what
trained 3DGS captures look like (:mod:`.splat_stats`: measured quantile tables and bands of
the real captures in ``tests/data``). Four classes (:class:`GaussianClass`), counts exact in
``size``: ``SURFACE`` (on the analytic surfaces, with measured thickness and needles, shrunk at
curvatures and patch edges), ``INTERIOR`` (inside the solids of :mod:`.solids`, the Gaussians
no view sees), ``HAZE`` (large faint flat Gaussians over the surfaces) and ``FLOATER``.

Ground truth by construction: a Gaussian belongs to the object whose surface or solid it was
generated for; floaters are background. Rows are shuffled; the PLY is the reference trainer's
layout, and :func:`scene_from_rows3d` turns it into the engine's scene exactly as
:func:`~divas_engine.io.ply.read_gaussian_ply` does. Per-class rules: docs/design-notes.md.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from ..geometry import quat_to_rotmat, rotmat_to_quat
from ..io.gaussians import sigmoid, surfels_from_arrays
from ..kinds import SceneKind
from ..scene import SH_C0, SurfelScene, sh_coeff_count
from .builder import (
    SCALE_FACTOR,
    BuiltScene,
    SceneSpec,
    allocate_counts,
    rng_for,
    scene_floaters,
)
from .edges import edge_distance
from .solids import Solid, scene_solids
from .splat_stats import NEEDLE_RATIO, sample_shapes
from .surfaces import Sphere, Surface
from .texture import surface_colors

__all__ = [
    "GaussianClass",
    "Built3D",
    "build_gaussians3d",
    "scene_from_rows3d",
    "INTERIOR_SPACING",
    "HAZE_SHARE",
]


class GaussianClass(IntEnum):
    """What a generated 3DGS Gaussian is (``classes.npy``)."""

    SURFACE = 0
    INTERIOR = 1
    HAZE = 2
    FLOATER = 3


#: Median ``s_max`` of surface Gaussians in units of their surface's sample spacing.
SURFACE_SCALE = 1.6
#: The surface Gaussians' measured ``log s_max`` deviations are scaled by this factor ...
LOG_SMAX_SPREAD = 1.05
#: ... and above the median by this one too. Calibrated together (with ``HAZE_SHARE``) so
#: the generated targets' ``log s_max`` percentiles and large shares sit inside the
#: captures' bands although the edge and curvature limits add small Gaussians and the
#: surfaces carry fewer large ones than a draw from the table would. Measured, the
#: captures' large Gaussians sit inside the objects 3–4× more often than
#: the others (biker: 25 % of those > 3× the median are hidden in every orbit view
#: against 7 % of all; guitar 18 % / 8 %; playbot 5.7 % / 1.3 %), so the surfaces carry
#: fewer of them — the interior and the haze the rest. Large opaque Gaussians on a
#: surface would bleed past every silhouette (the label render's 0.1-halo), which a
#: trainer does not let happen.
SURFACE_UPPER_TAIL = 0.85
#: On cylinders and tubes whose radius is below this many median ``s_max`` the long axis
#: follows the straight direction (a stem, a rib); on wider ones (a wall) it is random.
STRAIGHT_AXIS_CURVATURE = 10.0
#: Near a patch edge a surface Gaussian's ``s_max`` is at most the distance to the edge,
#: but not below this many spacings.
EDGE_FLOOR = 0.5
#: Tilt of the surface Gaussians' frames (radians, standard deviation).
TILT = 0.12
#: Interior Gaussians fill the solids at this many owner surface spacings apart ...
INTERIOR_SPACING = 2.5
#: ... but never more than this share of all Gaussians.
INTERIOR_MAX_SHARE = 0.15
#: Interior centres lie at least this many owner spacings below the boundary.
INTERIOR_MARGIN = 1.5
#: Median interior ``s_max`` in units of the solid's interior spacing ``(V / n)^⅓``.
INTERIOR_PACKING = 0.6
#: Interior colour = palette colour × this.
INTERIOR_SHADE = 0.7
#: Fraction of all Gaussians that are large translucent haze over the surfaces ...
HAZE_SHARE = 0.02
#: ... with ``s_max`` this many surface medians (log-uniform).
HAZE_SIZE = (3.0, 8.0)
#: SH rest noise: band ``l`` coefficients ~ N(0, SH_REST_SIGMA / l).
SH_REST_SIGMA = 0.04
#: Opacities are kept in [OPACITY_MIN, OPACITY_MAX] (finite logits).
OPACITY_MIN, OPACITY_MAX = 1e-3, 0.999


@dataclass(eq=False)
class Built3D:
    """A generated 3DGS scene: stored PLY rows, the engine's scene and ground truth
    (arrays in row order)."""

    rows: np.ndarray  # structured, the PLY vertex rows
    scene: SurfelScene  # as the loader builds it from ``rows``
    labels: np.ndarray  # [N] bool
    surface_ids: np.ndarray  # [N] int32, −1 floaters
    classes: np.ndarray  # [N] uint8 GaussianClass
    needles: np.ndarray  # [N] bool
    centers64: np.ndarray  # [N,3] float64 centres before float32 storage
    anchors64: np.ndarray  # [N,3] the surface point a surface/haze Gaussian was made for
    normals64: np.ndarray  # [N,3] the surface normal there (others: the smallest axis)
    scales3: np.ndarray  # [N,3] float64 activated (s_max, s_mid, s_min)
    counts: np.ndarray  # [S] surface-class Gaussians per surface
    spacing: np.ndarray  # [S]
    base_spacing: float
    solids: list[Solid]
    solid_counts: np.ndarray  # [len(solids)] interior Gaussians per solid

    def for_clicks(self) -> BuiltScene:
        """The view :func:`~.builder.choose_clicks` reads: only surface-class target
        Gaussians are click candidates, at their surface points."""
        surf = self.classes == GaussianClass.SURFACE
        return BuiltScene(
            self.scene,
            self.labels & surf,
            self.surface_ids,
            self.needles,
            self.classes == GaussianClass.FLOATER,
            self.anchors64,
            self.normals64,
            self.counts,
            self.spacing,
            self.base_spacing,
        )


def _frames(normals: np.ndarray, major: np.ndarray) -> np.ndarray:
    """``[n,3,3]`` rotations with columns (major, mid, normal); ``major`` ⟂-ised."""
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    a = major - n * np.sum(major * n, axis=1, keepdims=True)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return np.stack([a, np.cross(n, a), n], axis=2)


def _axis_angle(axes: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Rodrigues rotations ``[n,3,3]`` about unit ``axes`` by ``ang``."""
    k = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    K = np.zeros((len(k), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = np.sin(ang)[:, None, None], np.cos(ang)[:, None, None]
    return np.eye(3)[None] + s * K + (1 - c) * (K @ K)


def _random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return quat_to_rotmat(q.astype(np.float32)).astype(np.float64)


def _concat(parts: list[dict], shapes: dict) -> dict:
    """Concatenate dict parts (an empty list gives empty arrays of the given trailing shape)."""
    if parts:
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out = {}
    for k, sh in shapes.items():
        tail = () if sh == 0 else ((sh,) if isinstance(sh, int) else sh)
        out[k] = np.zeros((0, *tail), np.int64 if k == "solid" else np.float64)
    return out


def _surface_gaussians(rng, s: Surface, n: int, spacing: float, haze: bool = False) -> dict:
    """Surface Gaussians of one surface (module docstring); ``haze``: the large faint ones
    (``s_max`` × ``HAZE_SIZE``, opacity U(0.01, 0.2), the same shape rules otherwise)."""
    smp = s.sample(rng, n)
    shp = sample_shapes(rng, n)
    dev = LOG_SMAX_SPREAD * shp["log_smax"]
    dev = np.where(dev > 0, SURFACE_UPPER_TAIL * dev, dev)
    smax = SURFACE_SCALE * spacing * np.exp(dev)
    if haze:
        smax = SURFACE_SCALE * spacing * np.exp(rng.uniform(*np.log(HAZE_SIZE), n))
        shp["opacity"] = rng.uniform(0.01, 0.2, n)
    needle = shp["mid_max"] < NEEDLE_RATIO
    smid = smax * shp["mid_max"]
    smin = smid * shp["min_mid"]
    nrm, tu = smp.normals, smp.tangents
    tv = np.cross(nrm, tu)
    rc = smp.curvature_radius
    ang = rng.uniform(0, 2 * math.pi, n)
    curved = rc < STRAIGHT_AXIS_CURVATURE * SURFACE_SCALE * spacing
    if curved and not isinstance(s, Sphere):
        major = tv  # thin cylinders, tubes, leaves: the long axis along the straight direction
        smid = np.minimum(smid, 0.45 * rc)
    else:
        major = np.cos(ang)[:, None] * tu + np.sin(ang)[:, None] * tv
        if math.isfinite(rc):  # spheres: curved both ways
            smax = np.minimum(smax, 0.45 * rc)
            smid = np.minimum(smid, smax)
    if math.isfinite(rc):
        smin = np.minimum(smin, 0.45 * rc)
    smin = np.minimum(smin, smid)
    # near the patch's edge the Gaussian shrinks (all axes alike) so it stays on the patch
    lim = np.maximum(edge_distance(s, smp.points), EDGE_FLOOR * spacing)
    f = np.minimum(1.0, lim / smax)
    smax, smid, smin = smax * f, smid * f, smin * f
    rot = _frames(nrm, major)
    tilt = _axis_angle(rng.normal(size=(n, 3)), rng.normal(0.0, TILT, n))
    rot = tilt @ rot
    centers = smp.points + nrm * (rng.normal(0.0, 0.5, n) * smin)[:, None]
    opac = shp["opacity"]
    return {
        "centers": centers,
        "anchors": smp.points,
        "normals": nrm,
        "rot": rot,
        "scales": np.stack([smax, smid, smin], 1),
        "opac": opac,
        "needle": needle,
    }


def interior_plan(
    solids: list[Solid], spacing: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(natural counts, margins, deep volumes)`` per solid: the deep part (depth ≥
    ``INTERIOR_MARGIN`` owner spacings) filled at ``INTERIOR_SPACING`` owner spacings."""
    sp = np.array([spacing[so.surface] for so in solids])
    margins = INTERIOR_MARGIN * sp
    vol = np.array([so.deep_volume(m, rng) for so, m in zip(solids, margins)])
    return vol / (INTERIOR_SPACING * sp) ** 3, margins, vol


def _interior(rng, solids: list[Solid], counts: np.ndarray, margins, vol):
    """Interior Gaussians: ``counts[k]`` in solid ``k``; returns the parts."""
    parts = []
    for k, so in enumerate(solids):
        c = int(counts[k])
        if c == 0:
            continue
        other = [t for t in solids if t.label != so.label]
        pts, have = [], 0
        for _ in range(40):
            p = so.sample(rng, 2 * (c - have) + 16, margins[k])
            if len(p) == 0:
                break
            ok = np.ones(len(p), bool)
            for t in other:
                ok &= t.depth(p) <= 0.0
            pts.append(p[ok])
            have += int(ok.sum())
            if have >= c:
                break
        p = np.concatenate(pts)[:c] if pts else np.zeros((0, 3))
        if len(p) < c:
            raise RuntimeError(f"could not place {c} interior Gaussians in solid {so.name}")
        h = (vol[k] / c) ** (1.0 / 3.0)
        shp = sample_shapes(rng, c)
        r1, r2 = shp["mid_max"], shp["min_mid"]
        smax = INTERIOR_PACKING * h * np.exp(shp["log_smax"])
        smax = np.minimum(smax, so.depth(p))  # the 1σ ellipsoid stays inside
        rot = _random_rotations(rng, c)
        parts.append(
            {
                "solid": np.full(c, k),
                "centers": p,
                "rot": rot,
                "scales": np.stack([smax, smax * r1, smax * r1 * r2], 1),
                "opac": shp["opacity"],
            }
        )
    return parts


def _largest_remainder(w: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros(len(w), np.int64)
    if n <= 0 or w.sum() <= 0:
        return out
    exact = n * w / w.sum()
    out = np.floor(exact).astype(np.int64)
    out[np.argsort(-(exact - out), kind="stable")[: n - int(out.sum())]] += 1
    return out


def gs3d_rows(
    centers: np.ndarray, rot: np.ndarray, scales: np.ndarray, opac: np.ndarray, sh: np.ndarray
) -> np.ndarray:
    """Stored-space rows of the reference 3DGS PLY layout (float32, normals zero)."""
    n, k = len(centers), sh.shape[1]
    fields = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    fields += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    fields += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    rows = np.zeros(n, dtype=[(f, "<f4") for f in fields])
    for i, a in enumerate("xyz"):
        rows[a] = centers[:, i]
    for ch in range(3):
        rows[f"f_dc_{ch}"] = sh[:, 0, ch]
        for j in range(k - 1):
            rows[f"f_rest_{ch * (k - 1) + j}"] = sh[:, j + 1, ch]
    o = np.clip(opac, OPACITY_MIN, OPACITY_MAX)
    rows["opacity"] = np.log(o / (1 - o))
    for i in range(3):
        rows[f"scale_{i}"] = np.log(scales[:, i])
    q = rotmat_to_quat(rot)
    for i in range(4):
        rows[f"rot_{i}"] = q[:, i]
    return rows


def scene_from_rows3d(rows: np.ndarray, sh_degree: int) -> SurfelScene:
    """The engine's scene of 3DGS rows, computed as the PLY reader computes it."""
    k = sh_coeff_count(sh_degree)
    means = np.stack([rows[a] for a in "xyz"], 1).astype(np.float32)
    q = np.stack([rows[f"rot_{i}"] for i in range(4)], 1).astype(np.float32)
    s = np.stack([rows[f"scale_{i}"] for i in range(3)], 1).astype(np.float32)
    s_act = np.exp(np.clip(s, -80.0, 80.0)).astype(np.float32)
    q2, s2 = surfels_from_arrays(q, s_act)
    sh = np.empty((len(rows), k, 3), np.float32)
    for ch in range(3):
        sh[:, 0, ch] = rows[f"f_dc_{ch}"]
        for j in range(k - 1):
            sh[:, j + 1, ch] = rows[f"f_rest_{ch * (k - 1) + j}"]
    opac = sigmoid(rows["opacity"].astype(np.float32))
    return SurfelScene(means, q2, s2, opac, sh, sh_degree, SceneKind.GS3D, scale_n=s_act.min(1))


def build_gaussians3d(spec: SceneSpec, size: int, seed: int, sh_degree: int = 3) -> Built3D:
    """Generate the 3DGS variant of ``spec`` with ``size`` Gaussians (module docstring)."""
    surfaces = spec.surfaces
    key = (seed, spec.name, "3dgs")
    n_float = int(round(spec.floater_share * size))
    n_focus = int(round(spec.focus_floater_share * size)) if spec.focus is not None else 0
    n_haze = int(round(HAZE_SHARE * size))
    rest = size - n_float - n_focus - n_haze
    solids = scene_solids(spec.name, surfaces)
    areas = np.array([s.area() for s in surfaces])
    # interior count: the solids filled at INTERIOR_SPACING surface spacings, which depend
    # on how many Gaussians are left for the surfaces (a fixed point; contracting fast)
    n_int = 0
    for _ in range(12):
        counts = allocate_counts(surfaces, rest - n_int)
        spacing = np.sqrt(areas / np.maximum(counts, 1))
        natural, margins, vol = interior_plan(solids, spacing, rng_for(*key, "interior plan"))
        new = int(min(round(float(natural.sum())), round(INTERIOR_MAX_SHARE * size)))
        if new == n_int:
            break
        n_int = new
    counts = allocate_counts(surfaces, rest - n_int)
    spacing = np.sqrt(areas / np.maximum(counts, 1))
    natural, margins, vol = interior_plan(solids, spacing, rng_for(*key, "interior plan"))
    solid_counts = _largest_remainder(natural, n_int)
    dens = [j for j, s in enumerate(surfaces) if s.share is None]
    base_spacing = float(
        math.sqrt(
            sum(surfaces[j].density * areas[j] for j in dens) / max(1, sum(counts[j] for j in dens))
        )
    )

    # surface Gaussians
    parts, sid = [], []
    for j, s in enumerate(surfaces):
        if counts[j]:
            rng = rng_for(*key, "surface", s.name)
            parts.append(_surface_gaussians(rng, s, int(counts[j]), float(spacing[j])))
            sid.append(np.full(int(counts[j]), j, np.int32))
    surf = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    surf_sid = np.concatenate(sid)

    # haze over the surfaces (∝ their counts), the far dome left out
    near_counts = np.array([c if s.share is None else 0 for c, s in zip(counts, surfaces)])
    hparts, hsid = [], []
    for j, c in enumerate(_largest_remainder(near_counts.astype(np.float64), n_haze)):
        if c:
            rng = rng_for(*key, "haze", surfaces[j].name)
            hparts.append(_surface_gaussians(rng, surfaces[j], int(c), float(spacing[j]), True))
            hsid.append(np.full(int(c), j, np.int32))
    haze = {k: np.concatenate([p[k] for p in hparts]) for k in hparts[0]}
    haze_sid = np.concatenate(hsid)

    # interior Gaussians in the solids
    iparts = _interior(rng_for(*key, "interior"), solids, solid_counts, margins, vol)
    inner = _concat(iparts, {"solid": 0, "centers": 3, "rot": (3, 3), "scales": 3, "opac": 0})
    inner_sid = np.array([solids[k].surface for k in inner["solid"]], np.int32)

    # floaters (the 2DGS rule)
    rng = rng_for(*key, "floaters")
    margin = 3.0 * base_spacing
    fpts = scene_floaters(rng, spec, n_float, n_focus, surfaces, margin)
    nf = len(fpts)
    fshp = sample_shapes(rng, nf)
    r1, r2 = fshp["mid_max"], fshp["min_mid"]
    fsmax = SCALE_FACTOR * base_spacing * rng.uniform(1.0, 4.0, nf)
    frot = _random_rotations(rng, nf)

    # assemble
    centers = np.concatenate([surf["centers"], haze["centers"], inner["centers"], fpts])
    rot = np.concatenate([surf["rot"], haze["rot"], inner["rot"], frot])
    scales = np.concatenate(
        [
            surf["scales"],
            haze["scales"],
            inner["scales"],
            np.stack([fsmax, fsmax * r1, fsmax * r1 * r2], 1),
        ]
    )
    opac = np.concatenate([surf["opac"], haze["opac"], inner["opac"], rng.uniform(0.05, 0.2, nf)])
    surface_ids = np.concatenate([surf_sid, haze_sid, inner_sid, np.full(nf, -1, np.int32)])
    classes = np.concatenate(
        [
            np.full(len(surf_sid), GaussianClass.SURFACE, np.uint8),
            np.full(n_haze, GaussianClass.HAZE, np.uint8),
            np.full(len(inner_sid), GaussianClass.INTERIOR, np.uint8),
            np.full(nf, GaussianClass.FLOATER, np.uint8),
        ]
    )
    needles = np.concatenate([surf["needle"], np.zeros(len(centers) - len(surf_sid), bool)])
    is_target = np.array([s.target for s in surfaces] + [False])
    labels = is_target[surface_ids]
    anchors = np.concatenate([surf["anchors"], haze["anchors"], inner["centers"], fpts])
    normals = np.concatenate(
        [surf["normals"], haze["normals"], inner["rot"][:, :, 2], frot[:, :, 2]]
    )

    # colour: the palette at the surface point (interior: at the centre, shaded)
    rgb = np.empty((len(centers), 3), np.float32)
    noise_seed = zlib.crc32(f"{spec.name}:{seed}".encode())
    owned = surface_ids >= 0
    groups: dict[tuple[str, float], list[int]] = {}
    for j, s in enumerate(surfaces):
        groups.setdefault((s.palette, s.tex_scale), []).append(j)
    for (pal, scale), js in groups.items():
        sel = np.flatnonzero(owned & np.isin(surface_ids, js))
        rgb[sel] = surface_colors(anchors[sel], pal, scale, noise_seed)
    rgb[classes == GaussianClass.INTERIOR] *= INTERIOR_SHADE
    flo = classes == GaussianClass.FLOATER
    rgb[flo] = surface_colors(anchors[flo], "floater", 0.1, noise_seed)
    k = sh_coeff_count(sh_degree)
    sh = np.empty((len(centers), k, 3), np.float32)
    sh[:, 0] = (rgb - 0.5) / SH_C0
    rng = rng_for(*key, "sh")
    for band in range(1, sh_degree + 1):
        lo, hi = band * band, (band + 1) * (band + 1)
        sh[:, lo:hi] = rng.normal(0.0, SH_REST_SIGMA / band, (len(centers), hi - lo, 3))

    perm = rng_for(*key, "order").permutation(len(centers))
    rows = gs3d_rows(centers[perm], rot[perm], scales[perm], opac[perm], sh[perm])
    return Built3D(
        rows,
        scene_from_rows3d(rows, sh_degree),
        labels[perm],
        surface_ids[perm],
        classes[perm],
        needles[perm],
        centers[perm],
        anchors[perm],
        normals[perm],
        scales[perm],
        counts,
        spacing,
        base_spacing,
        solids,
        solid_counts,
    )

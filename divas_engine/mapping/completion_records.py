"""The per-view records of the 3DGS completion and the per-pixel and
per-point helpers they are made with.

A view's record holds integers only (fixed-point contribution sums, visibility and depth
evidence of Gaussians, evidence flags of active voxels), so adding and subtracting records
is exact in any order. With the sparse gather a record holds the Gaussians *and* the
active voxels of a *cover* (coarse cells, :class:`.completion_gather.CoarseCells`) only;
its values for them are those a record over the whole scene would hold (every value is a
function of its own Gaussian or voxel and the view alone), so a record widened by the
cells it lacked (:meth:`_ViewRecord.merged`) equals one made for the wider cover at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera

__all__ = [
    "QSCALE",
    "edge_distance",
    "fill_holes",
    "chord_depth",
    "gaussian_evidence",
    "gaussian_geometry",
    "seen_by_weight",
    "voxel_evidence",
    "project_points",
]

#: fixed-point scale of the contribution accumulators (2⁻²⁴ pixel)
QSCALE = float(1 << 24)

# per-view voxel evidence: seen on the surface inside the mask / hidden behind a
# mask-positive surface within the object's depth / inconsistent
SURFACE, INCONSISTENT, HIDDEN = np.uint8(1), np.uint8(2), np.uint8(3)


@dataclass(eq=False)
class _ViewRecord:
    gauss: np.ndarray  # [k] int32 Gaussians with a non-zero weight
    q1: np.ndarray  # [k] int64 A₁ · QSCALE
    q0: np.ndarray
    seen: np.ndarray  # [k] bool: weight ≥ min_visibility × unoccluded footprint weight
    deep: np.ndarray  # [k] int8: +1 centre within the solid depth, −1 beyond it, 0 none
    voxels: np.ndarray  # [m] int32 active voxels with evidence
    flags: np.ndarray  # [m] uint8 SURFACE / HIDDEN / INCONSISTENT
    # [C+1] bool coarse cells whose Gaussians and active voxels the record holds exactly
    # (the sentinel's Gaussians always); None: all of them (the full pass)
    cover: np.ndarray | None = None
    # the view's (positive mask, edge distance) kept until its first gather
    mask: tuple[np.ndarray, np.ndarray] | None = None

    def merged(self, more: _ViewRecord) -> _ViewRecord:
        """This record and ``more`` (a record of cells this one does not cover: disjoint
        Gaussians and voxels) as one record of the union of their covers."""
        cover = None if self.cover is None or more.cover is None else self.cover | more.cover
        cat = np.concatenate
        return _ViewRecord(
            cat([self.gauss, more.gauss]),
            cat([self.q1, more.q1]),
            cat([self.q0, more.q0]),
            cat([self.seen, more.seen]),
            cat([self.deep, more.deep]),
            cat([self.voxels, more.voxels]),
            cat([self.flags, more.flags]),
            cover,
            self.mask,
        )


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.binary_fill_holes(mask)`` (its default 4-connectivity): the mask
    plus every background component (4-connected) that touches no image border — one
    labelling pass instead of growing the outside by repeated dilation (cheaper per
    update; equal, ``tests/test_completion_records.py``)."""
    from scipy.ndimage import label

    m = np.asarray(mask, bool)
    if m.size == 0:
        return m.copy()
    lab, k = label(~m)
    outside = np.zeros(k + 1, bool)
    outside[0] = True  # the mask itself
    for edge in (lab[0], lab[-1], lab[:, 0], lab[:, -1]):
        outside[edge] = True
    return ~outside[lab] | m


def edge_distance(mask: np.ndarray) -> np.ndarray:
    """``[H,W]`` float64 distance (pixels) of each pixel of the mask, its holes filled,
    to the silhouette's edge (0 outside; the image border counts as outside). Holes are
    filled because a hole is usually an occluder in front of the object (a hand in front
    of a helmet), not an edge of its silhouette.

    Computed on the mask's bounding box grown by one pixel (clipped to the image), padded
    by one background pixel: the same values as on the whole image — every background
    pixel outside the box is joined to the image border by a straight background line
    (so a hole of the box is a hole of the image and vice versa), and the nearest
    background pixel of a pixel of the box is never outside it (the box's own ring of
    background, or the padding where the image border is, lies closer on the straight
    line towards any pixel beyond it). The distance is the exact Euclidean one
    (SciPy's, the square root of an integer), rounded to float32 as OpenCV's precise
    transform used before gives it — OpenCV's own rounding depends on the image's size
    (its vectorised square root), off by one float32 step at some pixels, so it cannot
    be computed on a part of the image (``tests/test_completion_records.py``)."""
    from scipy.ndimage import distance_transform_edt

    m = np.asarray(mask, bool)
    out = np.zeros(m.shape, np.float64)
    rows = np.flatnonzero(m.any(axis=1))
    if len(rows) == 0:
        return out
    cols = np.flatnonzero(m.any(axis=0))
    y0, y1 = max(int(rows[0]) - 1, 0), min(int(rows[-1]) + 2, m.shape[0])
    x0, x1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, m.shape[1])
    box = np.pad(fill_holes(m[y0:y1, x0:x1]), 1)
    d = distance_transform_edt(box)[1:-1, 1:-1]
    out[y0:y1, x0:x1] = d.astype(np.float32)
    return out


def chord_depth(rho: np.ndarray, y: np.ndarray, x: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """The depth (pixels) a solid of the silhouette can have behind pixels ``(y, x)``:
    the chord ``2 √(ρ (2R − ρ))`` of a ball of the mask's inscribed radius R at the
    pixel's distance ρ (+ ``extra`` pixels, capped at R) from the silhouette's edge
    (``rho``: :func:`edge_distance` of the mask)."""
    big_r = float(rho.max()) if rho.size else 0.0
    r_p = np.minimum(rho[y, x] + extra, big_r)
    return 2.0 * np.sqrt(np.maximum(r_p * (2.0 * big_r - r_p), 0.0))


def project_points(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Camera.project` evaluated point by point (elementwise float64 products and
    sums in a fixed order, no matrix product): a point's pixel and depth do not depend on
    which other points are projected with it (a BLAS product may round a row differently
    by its position in the block), so the evidence of a cover's voxels and Gaussians is
    the whole scene's bit for bit."""
    p = np.asarray(points, np.float64)
    w2c = np.asarray(camera.w2c, np.float64)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    pc = [x * w2c[k, 0] + y * w2c[k, 1] + z * w2c[k, 2] + w2c[k, 3] for k in range(3)]
    zc = pc[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([camera.fx * pc[0] / zc + camera.cx, camera.fy * pc[1] / zc + camera.cy], -1)
    return uv, zc


def gaussian_geometry(
    comp, view, pos: np.ndarray, rho: np.ndarray, g: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`gaussian_evidence` needs of Gaussians ``g`` besides their weights (so
    it can be made while the contribution walk runs): ``(in_front, full, deep)`` — centre
    in front of the camera, unoccluded footprint weight, depth evidence. Elementwise:
    each Gaussian's values depend on itself and the view alone."""
    cfg = comp.config
    cam = view.camera
    if len(g) == 0:
        return np.zeros(0, bool), np.zeros(0), np.zeros(0, np.int8)
    mu = comp.means[g]
    uv, z = project_points(cam, mu)
    ray = mu - np.asarray(cam.c2w, np.float64)[:3, 3]
    dist = np.linalg.norm(ray, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs((comp.normals[g] * ray).sum(axis=1)) / dist
        full = comp.footprint[g] * cos * float(cam.fx) * float(cam.fy) / (z * z)
    inside = cam.in_image(uv, z)
    deep = np.zeros(len(g), np.int8)
    idx = np.flatnonzero(inside)
    x = np.minimum(np.floor(uv[idx, 0]).astype(np.int64), cam.width - 1)
    y = np.minimum(np.floor(uv[idx, 1]).astype(np.int64), cam.height - 1)
    d = np.asarray(view.d_ref)[y, x].astype(np.float64)
    zz = z[idx]
    ok = pos[y, x] & (d > 0)
    cap = (
        cfg.depth_factor * chord_depth(rho, y, x, np.zeros(len(idx))) * zz / float(cam.fx)
        + cfg.surface_margin * comp.h
    )
    deep[idx[ok & (zz - d <= cap)]] = 1
    if cfg.deep_is_inconsistent:  # else deeper says nothing, as for the voxels
        deep[idx[ok & (zz - d > cap)]] = -1
    return z > 0, full, deep


def seen_by_weight(comp, geometry, weight: np.ndarray) -> np.ndarray:
    """*seen*: the weight is ≥ ``min_visibility`` × the unoccluded footprint weight (of
    :func:`gaussian_geometry`); τ_vis = 0: every Gaussian with a weight is seen."""
    min_vis = comp.config.min_visibility
    front, full = geometry[0], geometry[1]
    with np.errstate(invalid="ignore"):
        return np.asarray(front & ((min_vis <= 0) | (weight >= min_vis * full)), bool)


def gaussian_evidence(
    comp, view, pos: np.ndarray, rho: np.ndarray, g: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per Gaussian ``g`` of the completion ``comp`` (its config, centres, normals and
    footprint weights) with blending weight ``weight`` in ``view``: *seen* (the
    weight is ≥ ``min_visibility`` × its unoccluded footprint weight) and the depth
    evidence of its centre (+1 on a mask-positive pixel within the solid depth
    behind the surface, −1 beyond it when ``deep_is_inconsistent``, 0 otherwise)."""
    geo = gaussian_geometry(comp, view, pos, rho, g)
    return seen_by_weight(comp, geo, weight), geo[2]


def point_flags(
    comp, view, pos: np.ndarray, rho: np.ndarray, points: np.ndarray, half_extent: float
) -> tuple[np.ndarray, np.ndarray]:
    """Evidence flags of ``points`` in ``view`` (``SURFACE`` / ``HIDDEN`` /
    ``INCONSISTENT``): ``(indices, flags)`` of the points with evidence. A point stands
    for a body of half diagonal ``half_extent`` (world units; a voxel: ``√3/2 h_v``, a
    Gaussian's centre: 0) — the solid depth may reach that much further in."""
    cfg = comp.config
    cam = view.camera
    uv, z = project_points(cam, points)
    inside = cam.in_image(uv, z, cam.clip_near(comp.render_config.near))
    idx = np.flatnonzero(inside)
    x = np.minimum(np.floor(uv[idx, 0]).astype(np.int64), cam.width - 1)
    y = np.minimum(np.floor(uv[idx, 1]).astype(np.int64), cam.height - 1)
    d = np.asarray(view.d_ref)[y, x].astype(np.float64)  # D_med (2DGS D_ref)
    p = pos[y, x]
    zz = z[idx]
    margin = cfg.surface_margin * comp.h
    # the depth a solid of this silhouette can have behind the pixel: the chord of a
    # ball of the mask's inscribed radius R at the pixel's distance ρ from the
    # silhouette's edge, 2 √(ρ (2R − ρ)) (pixels → world units at the voxel's depth)
    # a voxel is a cube, not a point: its centre may sit half a diagonal off the solid
    half_diag = half_extent * float(cam.fx) / zz
    chord = chord_depth(rho, y, x, half_diag)
    depth_cap = cfg.depth_factor * chord * zz / float(cam.fx) + margin
    surf = d > 0
    off = zz - d
    visible = ~surf | (off <= margin)
    on_surf = p & surf & (off >= -margin) & (off <= margin)
    hidden = p & surf & (off > margin) & (off <= depth_cap)
    too_deep = p & surf & (off > depth_cap)
    incons = (~p & visible) | (p & surf & (off < -margin))
    if cfg.deep_is_inconsistent:
        incons |= too_deep
    flags = np.select([on_surf, hidden, incons], [SURFACE, HIDDEN, INCONSISTENT], np.uint8(0))
    keep = flags != 0
    return idx[keep], flags[keep].astype(np.uint8)


def voxel_evidence(
    comp, view, pos: np.ndarray, rho: np.ndarray, subset: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Evidence flags of the active voxels (``subset``: of these only; each voxel's
    flag depends on its own centre and the view alone): ``(voxels, flags)`` of the
    voxels with evidence (:func:`point_flags` of the voxel centres)."""
    if comp.a == 0 or (subset is not None and len(subset) == 0):
        return np.zeros(0, np.int32), np.zeros(0, np.uint8)
    centres = comp.voxel_centers if subset is None else comp.voxel_centers[subset]
    idx, flags = point_flags(comp, view, pos, rho, centres, 0.5 * np.sqrt(3.0) * comp.h)
    idx = idx if subset is None else np.asarray(subset)[idx]
    return idx.astype(np.int32), flags


def centre_evidence(comp, views, points: np.ndarray) -> np.ndarray:
    """``[K] bool``: the fill's test at the points themselves — each point is on the
    surface of or hidden within the solid depth behind a mask-positive pixel in some
    view of ``views`` (``(view, pos, rho)``) and inconsistent in none
    (:func:`point_flags` with no extent)."""
    good = np.zeros(len(points), bool)
    bad = np.zeros(len(points), bool)
    if len(points) == 0:
        return good
    for view, pos, rho in views:
        idx, flags = point_flags(comp, view, pos, rho, points, 0.0)
        good[idx[flags != INCONSISTENT]] = True
        bad[idx[flags == INCONSISTENT]] = True
    return good & ~bad

"""Every click as a 3D constraint on its object — beyond the paper.

In the paper (Sec. 3.3–3.4) a positive click on an anchor prompts only the centroid view
it spawns. Here every click — on an anchor, on a centroid view, through any camera, or
a world point — is one :class:`~.records.Correction` of its object:

1. a 3D point ``P`` (back-projected with the clicked image's depth) and its surface
   patch (the backend's ``click_patch``; optionally, on Gaussians, grown to hold the
   clicked pixel, :func:`pixel_patch`);
2. a prompt of every view of the object where ``P`` is visible and whose mask disagrees
   with the click (:func:`prompt_plan`): re-segmented and re-fused in its own slot;
3. a constraint on the selection: after the mapping the patches are forced in or out,
   in click order (:func:`constrain`), before the manual edits compose.

Corrections are object and view fields, so undo / redo and save / load are exact.
Each step in full: docs/design-notes.md.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Sequence

import numpy as np

from ..camera import Camera
from ..geometry import quat_to_rotmat
from ..kinds import ViewStatus
from ..scene import DensityGrid, SurfelScene
from ..segment.context import ObjectClicks
from .records import Correction, SessionView

__all__ = [
    "constrain",
    "surfel_patch",
    "pixel_patch",
    "grid_patch",
    "visible_pixels",
    "patch_radius",
    "view_masks",
    "disagrees",
    "prompt_plan",
    "missing_prompts",
    "with_prompt",
    "flat_mask",
]

#: two prompt points closer than this (pixels) are the same point
_SAME_POINT_PX = 1.0


def constrain(
    semantic: np.ndarray, corrections: Sequence[Correction], accepted: Collection[str] = ()
) -> np.ndarray:
    """``semantic`` with each correction's patch forced in (positive) or out (negative),
    in click order (a later click over an earlier one wins); a click that spawned a
    view holds only while that view is among the ``accepted`` view ids (fused, or
    refused at accept: the user asked for it, and the click stands when its mask could
    not be fused). ``semantic`` itself when none holds (never written)."""
    held = [c for c in corrections if c.spawned is None or c.spawned in accepted]
    if not held:
        return semantic
    out = np.array(semantic, dtype=bool, copy=True)
    flat = out.reshape(-1)
    for c in held:
        flat[c.patch] = bool(c.positive)
    return out


def flat_mask(indices: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A bool mask of ``shape`` holding the flat ``indices``."""
    m = np.zeros(int(np.prod(shape)), bool)
    m[np.asarray(indices, np.int64)] = True
    return m.reshape(shape)


def visible_pixels(
    camera: Camera, d_ref: np.ndarray, points: np.ndarray, occlusion_tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """``([K,2] pixels, [K] visible)`` of 3D ``points`` in a view: a point is visible when
    it projects into the image, in front of the camera, onto the surface the view
    shows there: its depth within ``occlusion_tol`` of ``D_ref`` (not hidden behind it,
    and not floating before it — at a silhouette the pixel shows what lies behind)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    uv, z = camera.project(p)
    h, w = d_ref.shape
    with np.errstate(invalid="ignore"):
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    idx = np.flatnonzero(ok)
    d = np.asarray(d_ref)[uv[idx, 1].astype(np.int64), uv[idx, 0].astype(np.int64)]
    zi = z[idx]
    ok[idx] = (d > 0) & (zi <= (1.0 + occlusion_tol) * d) & (zi >= (1.0 - occlusion_tol) * d)
    return uv, ok


def patch_radius(camera: Camera, depth: float, patch_px: float) -> float:
    """World size of ``patch_px`` pixels of ``camera`` at planar ``depth``."""
    return float(patch_px) * float(depth) / (0.5 * (camera.fx + camera.fy))


def view_masks(v: SessionView) -> tuple[np.ndarray, np.ndarray] | None:
    """What ``v`` says now, ``(raw, weighted)``: the segmenter's mask and the depth-
    weighted one it fused (a fused view) or would fuse (a previewed one; zeros when the
    preview was rejected); None when it has none (pending, or never previewed)."""
    prev = v.preview
    if v.status == ViewStatus.FUSED:
        if prev is not None and prev.mask is v.mask:
            return prev.selection.mask, v.mask
        return (v.mask if v.raw_mask is None else v.raw_mask), v.mask
    if v.status == ViewStatus.OPEN and prev is not None:
        zeros = np.zeros(prev.masks.shape[1:], np.float32)
        raw = prev.selection.mask
        return (zeros if raw is None else raw), (zeros if prev.mask is None else prev.mask)
    return None


def disagrees(
    masks: tuple[np.ndarray, np.ndarray], xy, positive: bool, weight_reads_prompts: bool
) -> bool:
    """Whether a view's ``(raw, weighted)`` masks say the opposite of a click at pixel
    ``xy``: a negative click where the segmenter's mask holds the spot; a positive one
    where it does not — or, when the depth weighting reads the prompts (2DGS: the band of
    the positive prompts' depths), where the weighting left it out."""
    x, y = int(xy[0]), int(xy[1])
    raw, weighted = masks
    inside = float(raw[y, x]) >= 0.5
    if not positive:
        return inside
    return not inside or (weight_reads_prompts and float(weighted[y, x]) < 0.5)


def _has_point(points: np.ndarray | None, xy: np.ndarray) -> bool:
    if points is None or not len(points):
        return False
    return bool(np.any(np.linalg.norm(np.asarray(points) - xy, axis=1) <= _SAME_POINT_PX))


def prompt_plan(
    views: Iterable[SessionView],
    point: np.ndarray,
    positive: bool,
    occlusion_tol: float,
    reads: bool,
    *,
    own: SessionView | None = None,
) -> list[tuple[SessionView, tuple[float, float]]]:
    """The views a click at ``point`` prompts, with its pixel in each (docs/design-notes.md,
    step 2): fused, pending and previewed views where it is visible and their mask
    disagrees with it (:func:`disagrees`; ``reads``: the backend's depth weighting reads
    the prompts); ``own``, the clicked view, when it is open
    (the click refines its preview, as a prompt point does). Rendered views only (a
    fused, pending or previewed view is)."""
    out = []
    for v in views:
        if v.status == ViewStatus.REJECTED or v.buffers is None:
            continue
        refine = v is own and v.status == ViewStatus.OPEN
        masks = view_masks(v)
        if v.status == ViewStatus.OPEN and masks is None and not refine:
            continue  # its first preview will read the click (missing_prompts)
        uv, ok = visible_pixels(v.camera, v.buffers.D_ref, point[None], occlusion_tol)
        if not (ok[0] or v is own):
            continue
        xy = np.clip(uv[0], 0.0, np.array([v.camera.width, v.camera.height]) - 1e-6)
        if _has_point(v.points, xy):
            continue
        if masks is not None and not refine and not disagrees(masks, xy, positive, reads):
            continue  # it agrees already
        out.append((v, (float(xy[0]), float(xy[1]))))
    return out


def missing_prompts(
    v: SessionView,
    clicks: ObjectClicks,
    points: np.ndarray,
    occlusion_tol: float,
    weight_reads_prompts: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The object's clicks the first preview of ``v`` disagrees with (:func:`disagrees`),
    visible in ``v`` and not among its prompt ``points``: ``([K,2] pixels, [K] labels)``."""
    masks = view_masks(v)
    if not len(clicks.points) or masks is None:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    uv, ok = visible_pixels(v.camera, v.buffers.D_ref, clicks.points, occlusion_tol)
    pts, labs = [], []
    for xy, vis, pos in zip(uv, ok, clicks.positive):
        if not vis or _has_point(points, xy) or _has_point(np.asarray(pts).reshape(-1, 2), xy):
            continue
        if disagrees(masks, xy, bool(pos), weight_reads_prompts):
            pts.append(xy)
            labs.append(int(bool(pos)))
    return np.asarray(pts, np.float64).reshape(-1, 2), np.asarray(labs, np.int64)


def with_prompt(
    points: np.ndarray | None, labels: np.ndarray | None, xy: tuple[float, float], positive: bool
) -> tuple[np.ndarray, np.ndarray]:
    """A view's prompt set with one more point."""
    p = np.zeros((0, 2)) if points is None else np.asarray(points, np.float64).reshape(-1, 2)
    lab = np.zeros(0, np.int64) if labels is None else np.asarray(labels, np.int64)
    return np.concatenate([p, [xy]]), np.concatenate([lab, [int(bool(positive))]])


def surfel_patch(
    scene: SurfelScene,
    point: np.ndarray,
    radius: float,
    sigmas: float,
    reach: np.ndarray | None = None,
) -> np.ndarray:
    """The surfels (Gaussians) whose ellipsoid, each axis ``s + radius`` (the normal axis
    ``s_3`` of a 3DGS Gaussian, 0 for a surfel), holds ``point`` within ``sigmas``
    standard deviations: everything that draws the clicked spot. Sorted row indices.
    ``reach``: each primitive's largest ``s`` (computed when None)."""
    if reach is None:
        reach = np.max(scene.scales, axis=1)
        if scene.scale_n is not None:
            reach = np.maximum(reach, scene.scale_n)
    p = np.asarray(point, np.float32)
    lim = np.float32(sigmas) * (np.asarray(reach, np.float32) + np.float32(radius))
    d = scene.means - p
    cand = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= lim * lim)  # a bound of the test
    if not len(cand):
        return cand.astype(np.int64)
    rot = quat_to_rotmat(scene.quats[cand]).astype(np.float64)
    local = np.einsum("kji,kj->ki", rot, -d[cand].astype(np.float64))  # Rᵀ (p − μ)
    sn = np.zeros(len(cand)) if scene.scale_n is None else scene.scale_n[cand]
    s = np.column_stack([scene.scales[cand].astype(np.float64), sn]) + float(radius)
    inside = np.einsum("ki,ki->k", local / s, local / s) <= float(sigmas) ** 2
    return cand[inside].astype(np.int64)


def pixel_patch(
    patch: np.ndarray,
    rows: np.ndarray,
    weights: np.ndarray,
    distances: np.ndarray,
    share: float,
    positive: bool = True,
) -> np.ndarray:
    """A click's ``patch`` grown until it settles the clicked pixel at ``share``.

    The primitives that draw the pixel (``rows``, blending weights ``weights`` there,
    ``distances`` of their centres from the click's point) join nearest first, until
    the patch draws at least ``share`` of the pixel (``positive``), or until what it
    leaves draws less than ``share`` (negative); all of them when that takes all. With
    ``share`` 0.5, the threshold of the selection's indicator, the selection's render
    shows the clicked pixel selected after a positive click and unselected after a
    negative one, whatever else is selected: a click never leaves the spot it was
    made on as it was. The ellipsoid test alone (:func:`surfel_patch`) can miss the
    surfel that draws most of the pixel on a slanted surface, or a second layer of the
    object seen through the first. Sorted flat indices."""
    patch = np.asarray(patch, np.int64)
    rows = np.asarray(rows, np.int64)
    w = np.asarray(weights, np.float64)
    have = float(w[np.isin(rows, patch)].sum())
    # settled when the patch draws ``need`` (positive: at least; negative: more than)
    need = float(share) if positive else float(w.sum()) - float(share)
    if not len(rows) or (have >= need if positive else have > need):
        return patch
    order = np.argsort(np.asarray(distances, np.float64), kind="stable")
    order = order[~np.isin(rows[order], patch)]
    reach = have + np.cumsum(w[order])
    side = "left" if positive else "right"
    k = int(np.searchsorted(reach, need, side=side)) + 1  # the first that settles it, with it
    return np.union1d(patch, rows[order[:k]])


def grid_patch(grid: DensityGrid, point: np.ndarray, radius: float, sigmas: float) -> np.ndarray:
    """The voxels with some density whose centre lies within ``sigmas · radius`` of
    ``point`` (at least half a voxel diagonal: the voxel holding it); sorted flat
    indices into ``[D,H,W]``."""
    vs = grid.voxel_size
    r = max(float(sigmas) * float(radius), 0.5 * float(np.linalg.norm(vs)))
    p = np.asarray(point, np.float64)
    top = np.array(grid.shape_xyz) - 1
    lo = np.clip(np.floor((p - r - grid.aabb[0]) / vs - 0.5), 0, top).astype(np.int64)
    hi = np.clip(np.ceil((p + r - grid.aabb[0]) / vs - 0.5), 0, top).astype(np.int64)
    ix, iy, iz = (np.arange(a, b + 1) for a, b in zip(lo, hi))
    zz, yy, xx = np.meshgrid(iz, iy, ix, indexing="ij")
    centres = grid.aabb[0] + (np.stack([xx, yy, zz], -1) + 0.5) * vs
    near = np.sum((centres - p) ** 2, axis=-1) <= r * r
    near &= grid.density[zz, yy, xx] > 0
    return np.sort(np.ravel_multi_index((zz[near], yy[near], xx[near]), grid.density.shape))

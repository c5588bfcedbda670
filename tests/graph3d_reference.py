"""The 3D graph segmenter's per-prompt graph as it was before issue 20's lean
primitives: every feature stored for every primitive (colour, normal, κ, σ), the
voxel aggregates taken from float64 copies of them, the supports' per-primitive test
from the primitives' rows. The tests of :mod:`tests.test_graph3d_lean` compare the
lean code with it bit for bit (a reference, not used by the engine)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_engine.kinds import SceneKind
from divas_engine.scene import SurfelScene
from divas_engine.segment.graph3d.config import Graph3DConfig
from divas_engine.segment.graph3d.primitives import _REACH_SIGMAS, ScenePrimitives, _lab
from divas_engine.segment.graph3d.voxel_graph import _OFFSETS, VoxelGraph, _affinity

__all__ = ["ReferenceFeatures", "reference_voxel_graph", "reference_support_primitives"]


@dataclass(eq=False)
class ReferenceFeatures:
    """Every primitive's features as whole arrays, computed from the whole scene."""

    points: np.ndarray
    lab: np.ndarray
    normals: np.ndarray
    kappa: np.ndarray
    mass: np.ndarray
    index: np.ndarray
    sigma: np.ndarray | None
    reach: np.ndarray
    scene: object
    up: np.ndarray | None
    cell: float
    prims: ScenePrimitives

    @classmethod
    def of(cls, prims: ScenePrimitives) -> ReferenceFeatures:
        scene = prims.scene
        if not isinstance(scene, SurfelScene):
            return cls(
                prims.points,
                prims.lab,
                prims.normals,
                prims.kappa,
                prims.mass,
                prims.index,
                None,
                prims.reach,
                scene,
                prims.up,
                prims.cell,
                prims,
            )
        keep = np.arange(len(scene)) if prims.index is None else prims.index
        normals = scene.normals()[keep].astype(np.float32)
        if scene.scale_n is None:
            kappa = np.ones(len(keep), np.float32)
        else:
            s_min = np.maximum(scene.scales[keep].min(axis=1), 1e-12)
            kappa = np.clip(1.0 - scene.scale_n[keep] / s_min, 0.0, 1.0).astype(np.float32)
        sigma = scene.scales[keep].max(axis=1)
        if scene.scale_n is not None:
            sigma = np.maximum(sigma, scene.scale_n[keep])
        return cls(
            np.asarray(scene.means[keep], np.float32),
            _lab(scene.base_colors()[keep]),
            normals,
            kappa,
            np.asarray(scene.opacities[keep], np.float32),
            keep,
            sigma.astype(np.float32),
            (_REACH_SIGMAS * sigma).astype(np.float32),
            scene,
            prims.up,
            prims.cell,
            prims,
        )

    def in_box(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return self.prims.in_box(lo, hi)

    def extent_axes(self, rows: np.ndarray) -> np.ndarray:
        return self.prims.extent_axes(rows)


def reference_voxel_graph(
    ref: ReferenceFeatures, center: np.ndarray, radius: float, config: Graph3DConfig
) -> VoxelGraph:
    g = int(config.grid_cells)
    if ref.cell > 0.0:
        g = max(4, min(g, int(2.0 * float(radius) / ref.cell)))
    h = 2.0 * float(radius) / g
    lo = np.asarray(center, np.float64) - radius - h  # one rim layer on each side
    cells = g + 2
    sel = ref.in_box(lo, lo + cells * h)
    p = ref.points[sel].astype(np.float64)
    cell = np.clip(np.floor((p - lo) / h).astype(np.int64), 0, cells - 1)
    key = cell[:, 0] + cells * (cell[:, 1] + cells * cell[:, 2])
    n_prim = len(sel)
    # a primitive wider than its voxel also occupies the voxels its extent covers, with
    # the opacity it has there (entries after the first n_prim: row, position, key)
    ext_row, ext_p, ext_key, ext_g = _reference_extents(ref, sel, p, key, lo, h, cells, config)
    a = ref.mass[sel].astype(np.float64)
    rows = np.r_[np.arange(n_prim), ext_row]
    p = np.concatenate([p, ext_p])
    key = np.r_[key, ext_key]
    a = np.r_[a, a[ext_row] * ext_g]
    # the occupied cells by a dense table over the cube (np.unique's sorted keys and
    # inverse, without its sort; the table also finds the neighbours below)
    occupied = np.zeros(cells**3, bool)
    occupied[key] = True
    uniq = np.flatnonzero(occupied)
    v = len(uniq)
    node = np.empty(cells**3, np.int64)
    node[uniq] = np.arange(v)
    inv = node[key]
    m = np.bincount(inv, a, v)
    msafe = np.maximum(m, 1e-12)

    def wmean(x: np.ndarray) -> np.ndarray:
        return (
            np.stack([np.bincount(inv, a * x[:, k], v) for k in range(x.shape[1])], 1)
            / (msafe[:, None])
        )

    centroid = wmean(p)
    lab = wmean(ref.lab[sel][rows].astype(np.float64))
    n = ref.normals[sel][rows].astype(np.float64)
    ak = a * ref.kappa[sel][rows]
    tensor = np.zeros((v, 3, 3))
    for r in range(3):
        for s in range(r, 3):
            t = np.bincount(inv, ak * n[:, r] * n[:, s], v)
            tensor[:, r, s] = t
            tensor[:, s, r] = t
    evals, evecs = np.linalg.eigh(tensor)  # ascending
    normal = evecs[:, :, 2]
    trace = np.trace(tensor, axis1=1, axis2=2)
    kappa = np.clip(trace / msafe, 0.0, 1.0)  # ν: confident share of the voxel's mass
    tensor /= np.maximum(trace, 1e-12)[:, None, None]
    vcell = np.stack([uniq % cells, (uniq // cells) % cells, uniq // (cells * cells)], 1)
    rim = np.any((vcell == 0) | (vcell == cells - 1), axis=1)

    # neighbours: 13 half-offsets, looked up in the table
    src, dst = [], []
    for off in _OFFSETS:
        nc = vcell + off
        ok = np.all((nc >= 0) & (nc < cells), axis=1)
        step = int(off[0] + cells * (off[1] + cells * off[2]))  # key of vcell + off
        ok[ok] = occupied[uniq[ok] + step]
        src.append(np.flatnonzero(ok))
        dst.append(node[uniq[ok] + step])
    i0 = np.concatenate(src) if src else np.zeros(0, np.int64)
    i1 = np.concatenate(dst) if dst else np.zeros(0, np.int64)
    # the mass scale of a_m: the median over the voxels that hold a primitive's centre
    # (the extents' faint tails would lower it, and then thin haze would link strongly)
    if len(inv) > n_prim:
        centre_voxels = np.bincount(inv[:n_prim], minlength=v) > 0
        typical = float(np.median(m[centre_voxels])) if n_prim else 0.0
    else:
        typical = float(np.median(m)) if v else 0.0
    weights = _affinity(i0, i1, centroid, lab, normal, tensor, kappa, m, typical, h, config)
    return VoxelGraph(
        prim=sel,
        voxel_of=inv[:n_prim],
        centroid=centroid,
        lab=lab,
        normal=normal,
        kappa=kappa,
        mass=m,
        cell=vcell,
        rim=rim,
        edges=np.stack([i0, i1], 1),
        weights=weights,
        lo=lo,
        h=h,
        cells=cells,
    )


def _reference_extents(
    ref: ReferenceFeatures,
    sel: np.ndarray,
    p: np.ndarray,
    key: np.ndarray,
    lo: np.ndarray,
    h: float,
    cells: int,
    config: Graph3DConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    empty = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0))
    k = float(config.extent_sigmas)
    if ref.sigma is None or k <= 0.0 or len(sel) == 0:
        return empty
    if config.extent_gs3d_only and getattr(ref.scene, "kind", None) != SceneKind.GS3D:
        return empty  # 2DGS: an isolated centre is a sparse surface (config docstring)
    big = np.flatnonzero(ref.sigma[sel].astype(np.float64) > config.extent_min_sigma * h)
    if len(big) == 0:
        return empty
    # only where the centres leave a primitive unlinked: its voxel has no occupied
    # neighbour (a densely sampled surface is already connected by its centres)
    occupied = np.zeros(cells**3, bool)
    occupied[key] = True
    cb = np.stack([key[big] % cells, (key[big] // cells) % cells, key[big] // cells**2], 1)
    linked = np.zeros(len(big), bool)
    for off in np.r_[_OFFSETS, -_OFFSETS]:
        nc = cb + off
        ok = np.all((nc >= 0) & (nc < cells), axis=1)
        nk = nc[:, 0] + cells * (nc[:, 1] + cells * nc[:, 2])
        linked |= ok & occupied[np.where(ok, nk, 0)]
    big = big[~linked]
    if len(big) == 0:
        return empty
    axes = ref.extent_axes(sel[big])  # [n,3,3]: σ-scaled principal axes as rows
    sig = np.linalg.norm(axes, axis=2)  # [n,3]
    steps = np.minimum(np.ceil(k * sig / h - 1e-9), config.extent_max_steps).astype(np.int64)
    # σ units per step along each axis: the whole extent in ``steps`` steps, never more
    # than a voxel apart (a truncated extent for a Gaussian wider than the steps reach)
    per = np.where(steps > 0, np.minimum(k * sig / np.maximum(steps, 1), h), 0.0)
    per /= np.maximum(sig, 1e-12)
    out_row, out_p, out_g = [], [], []
    combos, group = np.unique(steps, axis=0, return_inverse=True)
    for gi, m in enumerate(combos):
        members = np.flatnonzero(group.ravel() == gi)
        j = np.stack(np.meshgrid(*[np.arange(-mi, mi + 1) for mi in m], indexing="ij"), -1).reshape(
            -1, 3
        )
        j = j[np.any(j != 0, axis=1)].astype(np.float64)
        if len(j) == 0:
            continue
        u = j[None, :, :] * per[members][:, None, :]  # [n,L,3] σ units
        r2 = np.sum(u * u, axis=2)
        keep = r2 <= k * k + 1e-9
        rows = big[members]
        pts = p[rows][:, None, :] + np.einsum("nlk,nkc->nlc", u, axes[members])
        out_row.append(np.broadcast_to(rows[:, None], r2.shape)[keep])
        out_p.append(pts[keep])
        out_g.append(np.exp(-0.5 * r2[keep]))
    if not out_row:
        return empty
    row, pts, g = np.concatenate(out_row), np.concatenate(out_p), np.concatenate(out_g)
    c = np.floor((pts - lo) / h).astype(np.int64)
    inside = np.all((c >= 0) & (c < cells), axis=1)
    kk = c[:, 0] + cells * (c[:, 1] + cells * c[:, 2])
    inside &= kk != key[row]  # the centre voxel holds the primitive itself
    row, pts, g, kk = row[inside], pts[inside], g[inside], kk[inside]
    # one entry per (primitive, voxel): its sample of largest G
    order = np.lexsort((-g, kk, row))
    pair = row[order] * (cells**3) + kk[order]
    first = np.r_[True, pair[1:] != pair[:-1]]
    pick = order[first]
    return row[pick], pts[pick], kk[pick], g[pick]


def reference_support_primitives(
    graph: VoxelGraph, ref: ReferenceFeatures, planes: np.ndarray, config: Graph3DConfig
) -> np.ndarray:
    out = np.zeros(len(graph.prim), bool)
    if ref.up is None or not planes.any():
        return out
    up = ref.up
    h = graph.h
    levels = np.unique(np.round((graph.centroid[planes] @ up) / h))
    idx = graph.prim
    height = ref.points[idx].astype(np.float64) @ up / h
    j = np.clip(np.searchsorted(levels, height), 1, len(levels) - 1) if len(levels) > 1 else 0
    near = np.abs(height - levels[j]) <= 1.0
    if len(levels) > 1:
        near |= np.abs(height - levels[j - 1]) <= 1.0
    cos_min = np.cos(np.radians(config.ground_normal_deg))
    along = np.abs(ref.normals[idx].astype(np.float64) @ up) >= cos_min
    return near & along

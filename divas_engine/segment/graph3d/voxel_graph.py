"""The local neighbourhood graph of one prompt: active voxels around the seeds.

The primitives inside the cube ``c ± R`` (plus one rim layer of cells) are binned into
``G³`` voxels of edge ``h = 2R / G``; every occupied voxel is a node with the
opacity-weighted aggregates of its primitives (mass, centroid, Lab colour, principal
normal and its confidence ``ν``). Edges join voxels that touch (26-neighbourhood) with
the affinity ``w_ij = a_d · a_c · a_n · a_m`` (:class:`~.config.Graph3DConfig`):
centroid distance, contrast-normalised colour difference, normal agreement and the
smaller mass — Golovinskiy & Funkhouser's (2009) neighbourhood graph over voxels rather
than points, so one prompt stays cheap at a million primitives (no k-NN search).
Voxels in the rim layer are the region's outside: the walk of :mod:`.cut` drains there.
The node aggregates and the affinity terms in full: docs/design-notes.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...kinds import SceneKind
from ...scene import SurfelScene
from .config import Graph3DConfig
from .primitives import ScenePrimitives

__all__ = ["VoxelGraph", "build_voxel_graph", "other_material"]

# half of the 26-neighbourhood: every undirected edge once
_OFFSETS = np.array(
    [
        (dx, dy, dz)
        for dz in (-1, 0, 1)
        for dy in (-1, 0, 1)
        for dx in (-1, 0, 1)
        if (dz, dy, dx) > (0, 0, 0)
    ],
    dtype=np.int64,
)


@dataclass(eq=False)
class VoxelGraph:
    """One prompt's local graph (docs/design-notes.md).

    Attributes:
        prim: ``[P]`` indices into :class:`ScenePrimitives` of the region's primitives.
        voxel_of: ``[P]`` node of each of them.
        centroid, lab, normal: ``[V,3]`` node aggregates; kappa, mass: ``[V]``.
        cell: ``[V,3]`` int cell coordinates (0 … G+1; 0 and G+1 are the rim).
        rim: ``[V]`` bool, node in the rim layer.
        edges: ``[E,2]`` int node pairs; weights: ``[E]`` affinities.
        lo, h, cells: cube corner (rim included), voxel edge, cells per side (G + 2).
        up_height, up_dot: ``[P]`` float64 ``p · up`` and ``n · up`` of the region's
            primitives (position, normal) when the scene's up is known, for
            :func:`~.supports.support_primitives` (which drops them: transient).
    """

    prim: np.ndarray
    voxel_of: np.ndarray
    centroid: np.ndarray
    lab: np.ndarray
    normal: np.ndarray
    kappa: np.ndarray
    mass: np.ndarray
    cell: np.ndarray
    rim: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    lo: np.ndarray
    h: float
    cells: int
    up_height: np.ndarray | None = None
    up_dot: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.mass)

    def node_of_points(self, points: np.ndarray) -> np.ndarray:
        """Node of each 3D point: the occupied voxel holding it, else the node whose
        centroid is nearest (``-1`` when farther than 2 voxels)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        out = np.full(len(pts), -1, np.int64)
        if len(self) == 0:
            return out
        c = np.floor((pts - self.lo) / self.h).astype(np.int64)
        key = self._key(c)
        keys = self._key(self.cell)
        order = np.argsort(keys)
        j = np.searchsorted(keys[order], key)
        j = np.minimum(j, len(keys) - 1)
        inside = np.all((c >= 0) & (c < self.cells), axis=1)
        hit = (keys[order][j] == key) & inside
        out[hit] = order[j[hit]]
        for i in np.flatnonzero(~hit):
            d = np.linalg.norm(self.centroid - pts[i], axis=1)
            k = int(np.argmin(d))
            if d[k] <= 2.0 * self.h:
                out[i] = k
        return out

    def _key(self, cell: np.ndarray) -> np.ndarray:
        n = self.cells + 2  # room for a neighbour one step outside
        c = cell + 1
        return c[:, 0] + n * (c[:, 1] + n * c[:, 2])


def build_voxel_graph(
    prims: ScenePrimitives, center: np.ndarray, radius: float, config: Graph3DConfig
) -> VoxelGraph:
    """The voxel graph of the cube ``center ± radius`` (docs/design-notes.md). On a density
    grid the voxels are at least one grid cell wide (fewer than ``grid_cells`` a side when
    the region is small), else the occupied cells would not touch."""
    g = int(config.grid_cells)
    if prims.cell > 0.0:
        g = max(4, min(g, int(2.0 * float(radius) / prims.cell)))
    h = 2.0 * float(radius) / g
    lo = np.asarray(center, np.float64) - radius - h  # one rim layer on each side
    cells = g + 2
    sel = prims.in_box(lo, lo + cells * h)
    p = prims.points[sel].astype(np.float64)
    n_prim = len(sel)
    # each point's cell key c_0 + cells · (c_1 + cells · c_2), c = clip(floor((p − lo) / h)),
    # a coordinate at a time in two scratch columns: the same operations as on the whole
    # [n,3] array (at millions of splats every large temporary is a fresh mapping whose
    # pages fault in, in Blender's fixed-threshold heap)
    key = np.zeros(n_prim, np.int64)
    tf = np.empty(n_prim)
    ci = np.empty(n_prim, np.int64)
    for k in (2, 1, 0):
        np.subtract(p[:, k], lo[k], out=tf)
        tf /= h
        np.floor(tf, out=tf)
        np.copyto(ci, tf, casting="unsafe")  # astype(int64)'s cast
        np.clip(ci, 0, cells - 1, out=ci)
        key *= cells
        key += ci
    del tf, ci
    up_height = None if prims.up is None else p @ np.asarray(prims.up, np.float64)
    # a primitive wider than its voxel also occupies the voxels its extent covers, with
    # the opacity it has there (entries after the first n_prim: row, position, key)
    ext_row, ext_p, ext_key, ext_g = _extent_entries(prims, sel, p, key, lo, h, cells, config)
    a = prims.mass[sel].astype(np.float64)
    src = sel  # the primitive of every entry (its centre's, then its extents')
    if len(ext_row):
        src = sel[np.r_[np.arange(n_prim), ext_row]]
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

    buf = np.empty(len(inv))  # one scratch weight column for every sum below

    def wmean(x: np.ndarray) -> np.ndarray:
        # a float32 x: ``a * x[:, k]`` takes x's float64 value exactly (as astype would)
        out = np.empty((v, x.shape[1]))
        for k in range(x.shape[1]):
            np.multiply(a, x[:, k], out=buf)
            out[:, k] = np.bincount(inv, buf, v)
        return out / msafe[:, None]

    centroid = wmean(p)
    del p
    lab = wmean(prims.lab_of(src))
    n = prims.normals_of(src)  # float32; its products below are taken in float64
    kap = prims.kappa_of(src)
    ak = a if kap is None else a * kap  # κ = 1 (None): a · 1 is a
    up_dot = None
    if up_height is not None:
        up_dot = n[:n_prim].astype(np.float64) @ np.asarray(prims.up, np.float64)
    tensor = np.zeros((v, 3, 3))
    akr = np.empty(len(inv))
    for r in range(3):
        np.multiply(ak, n[:, r], out=akr)  # (ak · n_r) · n_s, the order of the sum
        for s in range(r, 3):
            np.multiply(akr, n[:, s], out=buf)
            t = np.bincount(inv, buf, v)
            tensor[:, r, s] = t
            tensor[:, s, r] = t
    del akr, n
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
        up_height=up_height,
        up_dot=up_dot,
    )


def _extent_entries(
    prims: ScenePrimitives,
    sel: np.ndarray,
    p: np.ndarray,
    key: np.ndarray,
    lo: np.ndarray,
    h: float,
    cells: int,
    config: Graph3DConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The voxels the extent of a primitive wider than its voxel covers, besides its own.

    A Gaussian with ``σ_max > extent_min_sigma · h`` (a narrower one reaches only its
    voxel's neighbours, which the 26-neighbourhood links already) whose centre's voxel
    has no occupied neighbour (the centres leave it unlinked; a densely sampled surface
    is connected by its centres, and keeps its graph) is sampled on a lattice over its
    ellipsoid ``|u| ≤ k`` in σ units (``k = extent_sigmas``): along each principal axis
    ``m_i = min(⌈k s_i / h⌉, extent_max_steps)`` steps each way, ``min(k s_i / m_i, h)``
    apart — neighbouring samples at most a voxel apart, so the covered voxels are
    connected to the centre's; a Gaussian wider than the steps reach is truncated to
    ``extent_max_steps`` voxels around its centre (bounded cost). Each sample carries
    the Gaussian's falloff ``G = exp(−|u|² / 2)`` there, and a voxel it reaches gets
    the largest ``G`` of its samples in it (the opacity ``α G`` the primitive has in
    that voxel). The centre voxel keeps the primitive itself. Returns
    ``(row [E], position [E,3], key [E], G [E])`` with ``row`` indexing ``sel``: the
    voxel graph links such a primitive's centre voxel to what its footprint overlaps,
    not only to what its centre happens to touch.
    """
    empty = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0))
    k = float(config.extent_sigmas)
    if not isinstance(prims.scene, SurfelScene) or k <= 0.0 or len(sel) == 0:
        return empty  # a grid cell has no extent beyond its voxel-sized cell
    if config.extent_gs3d_only and getattr(prims.scene, "kind", None) != SceneKind.GS3D:
        return empty  # 2DGS: an isolated centre is a sparse surface (config docstring)
    sigma = prims.sigma_of(sel)
    big = np.flatnonzero(sigma.astype(np.float64) > config.extent_min_sigma * h)
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
    axes = prims.extent_axes(sel[big])  # [n,3,3]: σ-scaled principal axes as rows
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


def other_material(lab: np.ndarray, ref_lab: np.ndarray) -> bool:
    """Voxels of colours ``lab [n,3]`` are another material than those of ``ref_lab``:
    their mean colour differs from the reference's by more than their own colour spread
    (their texture: the RMS deviation over the Lab channels)."""
    if len(lab) < 2 or len(ref_lab) == 0:
        return False
    spread = float(np.sqrt(np.sum(np.var(lab, axis=0))))
    return float(np.linalg.norm(lab.mean(axis=0) - ref_lab.mean(axis=0))) > spread


def _affinity(
    i0, i1, centroid, lab, normal, tensor, kappa, mass, typical, h, config: Graph3DConfig
) -> np.ndarray:
    if len(i0) == 0:
        return np.zeros(0)
    d2 = np.sum((centroid[i0] - centroid[i1]) ** 2, axis=1)
    a_d = np.exp(-d2 / (2.0 * (config.sigma_d * h) ** 2))
    dc2 = np.sum((lab[i0] - lab[i1]) ** 2, axis=1)
    beta = config.colour_contrast / max(float(np.mean(dc2)), 1e-6)
    a_c = np.exp(-beta * dc2)
    # how much of j's normal mass lies along i's principal normal, and back
    c01 = np.einsum("ea,eab,eb->e", normal[i0], tensor[i1], normal[i0])
    c10 = np.einsum("ea,eab,eb->e", normal[i1], tensor[i0], normal[i1])
    agree = np.sqrt(np.clip(c01, 0.0, 1.0) * np.clip(c10, 0.0, 1.0))
    a_n = np.exp(-kappa[i0] * kappa[i1] * (1.0 - agree) / config.normal_sigma)
    mm = np.minimum(mass[i0], mass[i1])
    floor = config.mass_floor * typical
    a_m = mm / (mm + max(floor, 1e-12))
    return a_d * a_c * a_n * a_m

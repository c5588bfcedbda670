"""Supporting surfaces of a prompt's region: what an object rests on is not the object.

A click on a pot standing on a table must not select the table: Golovinskiy &
Funkhouser (2009) remove the ground plane before their cut; here the voxels of every
supporting surface become sinks of the walk (:mod:`.cut`):

* **the scene's ground planes** (:class:`.primitives.ScenePrimitives`), unless a
  positive seed is on the plane (the user clicked the floor);
* **local supports** below the seeds (a table top, a plinth, a stand's base — not in
  the paper): flat, wide, up-facing patches below the highest positive seed with no
  positive seed on them. A scene without a ground plane has no up, and no local supports.

The rules in full (bands, sizes, flatness, hole filling): docs/design-notes.md.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.ndimage import binary_closing, binary_erosion, binary_fill_holes
from scipy.sparse.csgraph import connected_components

from .config import Graph3DConfig
from .primitives import ScenePrimitives
from .voxel_graph import VoxelGraph, other_material

__all__ = ["support_nodes", "support_primitives"]


def support_nodes(
    graph: VoxelGraph,
    prims: ScenePrimitives,
    positive: np.ndarray,
    config: Graph3DConfig,
    negative: np.ndarray | None = None,
) -> np.ndarray:
    """Bool ``[V]``: voxels of a supporting surface (docs/design-notes.md). A connected
    part of them that holds a negative seed stays in the graph: the user's negative
    click must be able to push back what touches it."""
    out = np.zeros(len(graph), bool)
    if len(graph) == 0:
        return out
    band = config.ground_band * prims.radius
    cos_min = np.cos(np.radians(config.ground_normal_deg))
    for g in prims.grounds:
        inband = np.abs(g.height(graph.centroid)) <= band
        if (inband & positive).any():
            continue  # the user clicked the plane itself
        along = np.abs(graph.normal @ g.normal) >= cos_min
        out |= inband & (along | (graph.kappa < 0.3))
    if prims.up is not None:
        out |= _local_supports(graph, prims.up, positive, config)
    if negative is not None and (out & negative).any():
        for part in _components(graph, out):
            if negative[part].any():
                out[part] = False
    return out


def _local_supports(
    graph: VoxelGraph, up: np.ndarray, positive: np.ndarray, config: Graph3DConfig
) -> np.ndarray:
    out = np.zeros(len(graph), bool)
    h = graph.h
    height = graph.centroid @ up
    cos_min = np.cos(np.radians(config.ground_normal_deg))
    flat = (np.abs(graph.normal @ up) >= cos_min) & (graph.kappa >= 0.5)
    if not (flat & ~positive).any():
        return out
    top = float(height[positive].max())
    base = float(height.min())
    bins = np.floor((height - base) / h).astype(np.int64)
    counts = np.bincount(bins[flat], minlength=int(bins.max()) + 1)
    need = max(config.support_min_voxels, config.support_min_share * len(graph))
    for b in np.flatnonzero(counts >= need):
        level = base + (b + 0.5) * h
        layer = flat & (np.abs(height - level) <= 1.5 * h)
        if level > top - 2.0 * h:
            continue  # nothing clicked stands on it
        for part in _components(graph, layer):
            if len(part) < need:
                continue
            # the plane itself: a step of another flat surface beside it (the top of a
            # statue's base a voxel above the cornice it stands on) is not the plane
            z0 = float(np.median(height[part]))
            part = part[np.abs(height[part] - z0) <= 0.75 * h]
            if len(part) < need or positive[part].any():
                continue  # small, or the user clicked the surface itself
            fill = other_material(graph.lab[part], graph.lab[positive])
            if _is_plane(graph.centroid[part], up, h, config.support_min_width, fill):
                out[part] = True
    return out


def _components(graph: VoxelGraph, nodes: np.ndarray) -> list[np.ndarray]:
    """Connected parts (26-neighbourhood) of a node subset, as index arrays."""
    idx = np.flatnonzero(nodes)
    if len(idx) == 0:
        return []
    local = np.full(len(graph), -1)
    local[idx] = np.arange(len(idx))
    e = graph.edges
    keep = nodes[e[:, 0]] & nodes[e[:, 1]]
    a, b = local[e[keep, 0]], local[e[keep, 1]]
    adj = sparse.csr_matrix((np.ones(len(a)), (a, b)), shape=(len(idx), len(idx)))
    n, lab = connected_components(adj, directed=False)
    order = np.argsort(lab, kind="stable")
    cuts = np.flatnonzero(np.diff(lab[order])) + 1
    return [idx[g] for g in np.split(order, cuts)]


def _is_plane(
    points: np.ndarray, up: np.ndarray, h: float, width: float, fill_holes: bool = False
) -> bool:
    """A flat patch (heights within ``h / 3`` RMS) that holds a disc ``width`` voxels
    across: its footprint, rasterised at ``h`` (``fill_holes``: its holes filled),
    survives an erosion by ``width / 2``."""
    height = points @ up
    if float(np.std(height)) > h / 3.0:
        return False
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    uv = np.floor(np.stack([points @ e1, points @ e2], 1) / h).astype(np.int64)
    uv -= uv.min(axis=0)
    r = max(1, int(round(width / 2.0)))
    img = np.zeros(tuple(uv.max(axis=0) + 1 + 2 * r), bool)
    img[uv[:, 0] + r, uv[:, 1] + r] = True
    img = binary_closing(img, iterations=1)  # voxel-sized holes of a sparse sampling
    if fill_holes:  # what stands on a surface hides its footprint there: a hole
        img = binary_fill_holes(img)
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = yy * yy + xx * xx <= r * r
    return bool(binary_erosion(img, structure=disc).any())


def support_primitives(
    graph: VoxelGraph, prims: ScenePrimitives, planes: np.ndarray, config: Graph3DConfig
) -> np.ndarray:
    """Bool ``[P]`` over the region's primitives: those that belong to a support
    although their voxel was kept — facing along the up and within one voxel of the
    height of a support voxel. A voxel where a pot stands on a table holds both; the cut
    keeps the voxel, this drops its table surfels (the up-facing ring a render shows)."""
    out = np.zeros(len(graph.prim), bool)
    if prims.up is None or not planes.any():
        return out
    up = prims.up
    h = graph.h
    levels = np.unique(np.round((graph.centroid[planes] @ up) / h))
    cos_min = np.cos(np.radians(config.ground_normal_deg))
    # the graph's n · up and p · up of its primitives (the same float64 products as
    # from the primitives' rows); the height test only where the normal is along up
    if graph.up_dot is not None and graph.up_height is not None:
        up_dot, up_height = graph.up_dot, graph.up_height
    else:
        idx = graph.prim
        up_dot = prims.normals_of(idx).astype(np.float64) @ up
        up_height = prims.points[idx].astype(np.float64) @ up
    rows = np.flatnonzero(np.abs(up_dot) >= cos_min)
    height = up_height[rows] / h
    j = np.clip(np.searchsorted(levels, height), 1, len(levels) - 1) if len(levels) > 1 else 0
    near = np.abs(height - levels[j]) <= 1.0
    if len(levels) > 1:
        near |= np.abs(height - levels[j - 1]) <= 1.0
    out[rows[near]] = True
    return out

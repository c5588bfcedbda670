"""instant-ngp snapshots of generated density grids (tests and the synthetic NeRF suite).

No trained snapshot is at hand, so a generated :class:`~divas_engine.scene.DensityGrid`
is written as one: the training frame is fitted into instant-ngp's unit cube and each 128³
cell holds the optical thickness ``σ·STEPSIZE`` of the largest density among 3³ points of
the cell (instant-ngp keeps the maximum of its samples per cell). With ``network=True`` the
snapshot also carries a radiance network in tiny-cuda-nn's layout, built rather than
trained: a dense finest grid level holds ``log σ`` and the colour logits at its vertices and
the MLPs pass them through, so the network reproduces the grid exactly where it is sampled
and interpolates between vertices trilinearly. Construction in full: docs/design-notes.md.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from scipy.ndimage import map_coordinates

from ..camera import Camera
from ..io.instant_ngp import STEPSIZE, NgpFrame
from ..io.instant_ngp_writer import BASE_CONFIG, cascade_centres, snapshot_document
from ..io.ngp_network import HashGridSpec, NgpNetwork, grid_level_sizes
from ..scene import DensityGrid

__all__ = ["fit_frame", "snapshot_of_grid", "sample_grid"]

LOG_SIGMA_MIN = -10.0
VIEW_TERM = 0.3


def fit_frame(aabb: np.ndarray, fill: float = 0.8) -> NgpFrame:
    """A frame that maps ``aabb`` into the middle ``fill`` of instant-ngp's unit cube."""
    lo, hi = np.asarray(aabb, np.float64)
    s = fill / float((hi - lo).max())
    c = 0.5 * (lo + hi)
    return NgpFrame(s, tuple(float(v) for v in 0.5 - s * c), False)


def sample_grid(grid: DensityGrid, points: np.ndarray, values: np.ndarray, order: int = 1):
    """Values on ``grid``'s lattice (``[D,H,W]`` or ``[D,H,W,C]``) at world ``points``,
    trilinear (cell-centred, clamped to the edge)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    f = (p - grid.aabb[0]) / grid.voxel_size - 0.5
    coords = np.stack([f[:, 2], f[:, 1], f[:, 0]])
    v = np.asarray(values, np.float32)
    if v.ndim == 3:
        return map_coordinates(v, coords, order=order, mode="nearest")
    return np.stack(
        [
            map_coordinates(v[..., c], coords, order=order, mode="nearest")
            for c in range(v.shape[3])
        ],
        -1,
    )


def _cascade_thickness(grid: DensityGrid, frame: NgpFrame) -> np.ndarray:
    """``[1, 128, 128, 128]``: per cell, the largest σ of the grid's samples inside it (its
    centre's trilinear value where no sample falls in it), as optical thickness."""
    lay, cen = cascade_centres(1)
    R = lay.resolution
    w = frame.to_world(cen.reshape(-1, 3))
    inside = np.all((w >= grid.aabb[0]) & (w <= grid.aabb[1]), 1)
    best = np.where(inside, sample_grid(grid, w, grid.density), 0).astype(np.float32)
    iz, iy, ix = np.nonzero(grid.density > 0)
    centres = grid.aabb[0] + (np.stack([ix, iy, iz], 1) + 0.5) * grid.voxel_size
    c = np.floor((frame.to_ngp(centres) - lay.lo(0)) / lay.cell(0)).astype(np.int64)
    ok = np.all((c >= 0) & (c < R), 1)
    flat = (c[ok, 0] * R + c[ok, 1]) * R + c[ok, 2]
    np.maximum.at(best, flat, grid.density[iz[ok], iy[ok], ix[ok]])
    return (best / np.float32(frame.scale) * np.float32(STEPSIZE)).reshape(1, R, R, R)


def _network(grid: DensityGrid, frame: NgpFrame, res: int) -> tuple[NgpNetwork, dict]:
    cfg = copy.deepcopy(BASE_CONFIG)
    base = 16
    pls = (res + 1) / base
    cfg["encoding"] = {
        "otype": "HashGrid",
        "n_levels": 2,
        "n_features_per_level": 8,
        "log2_hashmap_size": max(19, math.ceil(math.log2((res + 1) ** 3))),
        "base_resolution": base,
        "per_level_scale": pls,
    }
    for k in ("network", "rgb_network"):
        cfg[k].update(n_neurons=16, n_hidden_layers=1)
    spec_d = {k: cfg["encoding"][k] for k in ("n_levels", "log2_hashmap_size", "base_resolution")}
    spec_d.update(per_level_scale=pls, grid_type="Hash")
    sizes = grid_level_sizes(spec_d)
    spec = HashGridSpec(
        2, 8, spec_d["log2_hashmap_size"], base, pls, "Hash", (0, sizes[0], sum(sizes))
    )
    lv = 1
    scale = float(spec.level_scale(lv))
    r = spec.level_resolution(lv)
    if r**3 > sizes[1]:
        raise ValueError("the finest level must be dense")
    i = (np.arange(r) - 0.5) / scale
    X, Y, Z = np.meshgrid(i, i, i, indexing="ij")  # dense index x + y·r + z·r²: x fastest
    u = np.stack([X, Y, Z], -1).transpose(2, 1, 0, 3).reshape(-1, 3)
    world = frame.to_world(u)
    sig = sample_grid(grid, world, grid.density) / frame.scale
    inside = np.all((world >= grid.aabb[0]) & (world <= grid.aabb[1]), 1)
    a = np.where(inside, np.log(np.maximum(sig, math.exp(LOG_SIGMA_MIN))), LOG_SIGMA_MIN)
    rgb = grid.rgb if grid.rgb is not None else np.full(grid.density.shape + (3,), 0.8, np.float32)
    col = np.clip(sample_grid(grid, world, rgb), 0.02, 0.98)
    logit = np.log(col / (1 - col))
    vals = np.concatenate([a[:, None], logit], 1)  # [N, 4]
    feats = np.stack([np.maximum(vals, 0), np.maximum(-vals, 0)], -1).reshape(-1, 8)
    table = np.zeros((sizes[0] + sizes[1], 8), np.float32)
    table[sizes[0] : sizes[0] + len(feats)] = feats
    d1, d2 = np.zeros((16, 16), np.float32), np.zeros((16, 16), np.float32)
    for k in range(8):
        d1[k, 8 + k] = 1.0  # hidden k = ReLU(level-1 feature k)
    for c in range(4):
        d2[c, 2 * c], d2[c, 2 * c + 1] = 1.0, -1.0
    r1, r2 = np.zeros((16, 32), np.float32), np.zeros((16, 16), np.float32)
    for c in range(3):
        r1[2 * c, 1 + c], r1[2 * c + 1, 1 + c] = 1.0, -1.0
        r2[c, 2 * c], r2[c, 2 * c + 1] = 1.0, -1.0
        r2[c, 6], r2[c, 7] = VIEW_TERM, -VIEW_TERM
    r1[6, 16 + 1], r1[7, 16 + 1] = 1.0, -1.0  # the first degree-1 SH of the direction
    half = 0.5
    net = NgpNetwork(
        spec,
        table,
        [d1, d2],
        [r1, r2],
        16,
        32,
        np.array([[0.5 - half] * 3, [0.5 + half] * 3]),
    )
    return net, cfg


def snapshot_of_grid(
    grid: DensityGrid,
    cameras: list[Camera] | None = None,
    *,
    network: bool = True,
    network_resolution: int = 128,
    frame: NgpFrame | None = None,
) -> dict:
    """The msgpack document of an instant-ngp snapshot of ``grid`` (module docstring)."""
    frame = frame or fit_frame(grid.aabb)
    ot = _cascade_thickness(grid, frame)
    net, cfg = _network(grid, frame, network_resolution) if network else (None, None)
    return snapshot_document(ot, frame, 1, cameras=cameras, network=net, config=cfg)

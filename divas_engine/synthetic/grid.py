"""Analytic NeRF-style density grid of a synthetic scene (the ``ribs`` NeRF version).

Each surface is thickened to a thin shell: at a cell centre at distance ``d``
from the surface, ``σ = σ_max · smoothstep((w_out − d) / (w_out − w_in))`` with
``w_in = ¼`` voxel (full density) and ``w_out = ¾`` voxel (zero). Along any
line through a sheet some sample lies within ½ voxel of it (≥ ½ σ_max), so
sheets are closed, while two surfaces 1½ voxels apart stay separated by
empty cells. Surfaces flagged ``solid`` (the bones) also fill their interior
(``d = 0`` inside). ``σ_max = sigma_voxels / voxel``: one voxel of it is
practically opaque. Floaters inside the box become single low-density cells whose opacity
over one voxel equals the surfel's. Colour is the texture of the surface that
dominates the cell; the label is that surface's target flag.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene import DensityGrid
from .surfaces import Surface
from .texture import surface_colors

__all__ = ["voxelize"]


def voxelize(
    surfaces: list[Surface],
    aabb: np.ndarray,
    resolution: int,
    noise_seed: int,
    *,
    floater_points: np.ndarray | None = None,
    floater_opacity: np.ndarray | None = None,
    floater_rgb: np.ndarray | None = None,
    sigma_voxels: float = 8.0,
) -> tuple[DensityGrid, np.ndarray]:
    """Density grid ``[D,H,W]`` over ``aabb`` with ``resolution`` cells on its longest
    side (cubic cells; the box max is moved out to a whole number of cells).

    Returns ``(grid, labels)`` with ``labels`` bool ``[D,H,W]``.
    """
    lo = np.asarray(aabb[0], np.float64)
    ext = np.asarray(aabb[1], np.float64) - lo
    vox = float(ext.max()) / int(resolution)
    dims = np.maximum(1, np.ceil(ext / vox - 1e-9).astype(int))  # (nx, ny, nz)
    hi = lo + dims * vox
    sig_max = sigma_voxels / vox
    w_in, w_out = 0.25 * vox, 0.75 * vox
    nx, ny, nz = (int(v) for v in dims)
    density = np.zeros((nz, ny, nx), np.float32)
    owner = np.full((nz, ny, nx), -1, np.int32)

    for j, s in enumerate(surfaces):
        blo, bhi = s.bounds()
        i0 = np.clip(np.floor((blo - w_out - lo) / vox - 0.5).astype(int), 0, dims)
        i1 = np.clip(np.ceil((bhi + w_out - lo) / vox + 0.5).astype(int), 0, dims)
        if np.any(i1 <= i0):
            continue
        xs = lo[0] + (np.arange(i0[0], i1[0]) + 0.5) * vox
        ys = lo[1] + (np.arange(i0[1], i1[1]) + 0.5) * vox
        zs = lo[2] + (np.arange(i0[2], i1[2]) + 0.5) * vox
        Z, Y, X = np.meshgrid(zs, ys, xs, indexing="ij")
        pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
        d = s.distance(pts)
        if s.solid:
            d[s.inside(pts)] = 0.0
        d = d.reshape(X.shape)
        t = np.clip((w_out - d) / (w_out - w_in), 0.0, 1.0)
        sig = (sig_max * t * t * (3 - 2 * t)).astype(np.float32)
        blk = (slice(i0[2], i1[2]), slice(i0[1], i1[1]), slice(i0[0], i1[0]))
        cur = density[blk]
        win = sig > cur
        cur[win] = sig[win]
        owner[blk][win] = j

    rgb = np.zeros((nz, ny, nx, 3), np.float32)
    is_target = np.array([s.target for s in surfaces] + [False])
    labels = is_target[owner] & (density > 0)
    groups: dict[tuple[str, float], list[int]] = {}
    for j, s in enumerate(surfaces):
        groups.setdefault((s.palette, s.tex_scale), []).append(j)
    for (pal, scale), js in groups.items():
        iz, iy, ix = np.nonzero(np.isin(owner, js))
        if len(iz):
            pts = lo + (np.stack([ix, iy, iz], 1) + 0.5) * vox
            rgb[iz, iy, ix] = surface_colors(pts, pal, scale, noise_seed)

    if floater_points is not None and len(floater_points):
        idx = np.floor((floater_points - lo) / vox).astype(int)
        inside = np.all((idx >= 0) & (idx < dims), axis=1)
        idx, a = idx[inside], np.asarray(floater_opacity)[inside]
        sf = (-np.log1p(-np.clip(a, 0, 0.999)) / vox).astype(np.float32)
        upd = sf > density[idx[:, 2], idx[:, 1], idx[:, 0]]
        idx, sf = idx[upd], sf[upd]
        density[idx[:, 2], idx[:, 1], idx[:, 0]] = sf
        labels[idx[:, 2], idx[:, 1], idx[:, 0]] = False
        if floater_rgb is not None:
            rgb[idx[:, 2], idx[:, 1], idx[:, 0]] = np.asarray(floater_rgb)[inside][upd]

    aabb_out = np.stack([lo, hi]).astype(np.float64)
    grid = DensityGrid(density, aabb_out, rgb)
    grid.extras.update({"sigma_max": sig_max, "voxel_size": vox, "shell_half_width": [w_in, w_out]})
    assert math.isclose(grid.voxel_size[0], vox, rel_tol=1e-9)
    return grid, labels

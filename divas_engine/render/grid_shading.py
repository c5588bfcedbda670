"""Colour for a density grid that has none, so rendered views still show its shape.

A grid read without colour (instant-ngp without its network, torch-ngp, a bare ``.vdb``)
would render as one flat colour: a 2D segmenter then sees only the silhouette against the
background, no edge between two touching objects or between an object and what lies
behind it. Here every voxel gets the colour of its surface orientation instead: the
normal ``n = −∇σ̃ / |∇σ̃|`` of the density smoothed by a Gaussian of one voxel, shown as
``0.5 + 0.5 n`` (a normal map: each orientation its own hue) times a Lambert term
``0.35 + 0.65 max(0, n·l)`` for a fixed key light ``l``. Creases, occlusion boundaries
and objects facing differently get different colours; the colour is view-independent, so
fused masks stay consistent between views.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from ..scene import DensityGrid

__all__ = ["shaded_rgb", "UNCOLOURED_FORMATS", "wants_shading"]

#: formats whose grids carry no colour of their own
UNCOLOURED_FORMATS = ("ingp", "msgpack", "torch_ngp", "vdb")
KEY_LIGHT = np.array([0.4, -0.5, 0.77])


def wants_shading(grid: DensityGrid, shade: bool | None) -> bool:
    """Whether the renderer colours ``grid`` by :func:`shaded_rgb` (``shade`` None: auto)."""
    if grid.rgb is not None:
        return False
    if shade is not None:
        return bool(shade)
    return grid.source is not None and grid.source.format in UNCOLOURED_FORMATS


def shaded_rgb(grid: DensityGrid) -> np.ndarray:
    """``[D,H,W,3]`` float32 normal-map × Lambert colour of ``grid`` (module docstring)."""
    d = np.log1p(np.maximum(np.asarray(grid.density, np.float32), 0))
    s = gaussian_filter(d, sigma=1.0, mode="nearest")
    vox = grid.voxel_size  # (x, y, z)
    gz, gy, gx = np.gradient(s, vox[2], vox[1], vox[0])
    n = -np.stack([gx, gy, gz], -1)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(norm > 0, n / np.maximum(norm, 1e-12), 0.0)
    light = KEY_LIGHT / np.linalg.norm(KEY_LIGHT)
    lam = 0.35 + 0.65 * np.maximum(n @ light, 0.0)
    return np.clip((0.5 + 0.5 * n) * lam[..., None], 0.0, 1.0).astype(np.float32)

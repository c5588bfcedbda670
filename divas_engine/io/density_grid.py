"""NeRF density grids stored as ``.npz`` (paper App. A; the NeRF backbone's scene).

Keys: ``density [D,H,W]`` (σ ≥ 0 per world unit, indexed ``[iz, iy, ix]``),
optional ``rgb [D,H,W,3]`` in [0,1], ``aabb [2,3]`` (min, max corners). Samples
are cell-centred (see :class:`~divas_engine.scene.DensityGrid`).
"""

from __future__ import annotations

import zipfile
from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..output_paths import save_npz_atomic
from ..scene import DensityGrid, SourceInfo

__all__ = ["read_density_grid", "write_density_grid", "GRID_KEYS"]

GRID_KEYS = ("density", "rgb", "aabb")


def read_density_grid(path: str | PathLike) -> DensityGrid:
    """Load and validate a density grid; NaN/Inf densities become 0 and are counted."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            if "density" not in keys or "aabb" not in keys:
                raise DivasInputError(
                    path, f"density grid needs keys 'density' and 'aabb', has {sorted(keys)}"
                )
            density = np.asarray(z["density"], dtype=np.float32)
            aabb = np.asarray(z["aabb"], dtype=np.float64)
            rgb = np.asarray(z["rgb"], dtype=np.float32) if "rgb" in keys else None
    except DivasInputError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise DivasInputError(path, f"not a readable .npz density grid ({e})") from None
    if density.ndim != 3 or min(density.shape) < 2:
        raise DivasInputError(
            path, f"'density' must be [D,H,W] with every side ≥ 2, got {density.shape}"
        )
    if aabb.shape != (2, 3) or not np.all(np.isfinite(aabb)) or np.any(aabb[1] <= aabb[0]):
        raise DivasInputError(
            path, f"'aabb' must be finite [2,3] with max > min, got {aabb.tolist()}"
        )
    if rgb is not None and rgb.shape != density.shape + (3,):
        raise DivasInputError(path, f"'rgb' must be {density.shape + (3,)}, got {rgb.shape}")
    bad = ~np.isfinite(density)
    n_bad = int(bad.sum())
    if n_bad:
        density[bad] = 0.0
    if np.any(density < 0):
        raise DivasInputError(path, f"'density' has {int((density < 0).sum())} negative values")
    if not np.any(density > 0):
        raise DivasInputError(path, "empty scene: the density grid is zero everywhere")
    if rgb is not None:
        rgb = np.nan_to_num(np.clip(rgb, 0.0, 1.0))
    src = SourceInfo(path, "npz", int(density.size), np.arange(density.size, dtype=np.int64), n_bad)
    return DensityGrid(density, aabb, rgb, src)


def write_density_grid(path: str | PathLike, grid: DensityGrid, **extra: np.ndarray) -> None:
    """Write a grid in the same schema (plus any ``extra`` arrays, e.g. a ``mask``)."""
    arrays = {"density": grid.density.astype(np.float32), "aabb": np.asarray(grid.aabb, np.float64)}
    if grid.rgb is not None:
        arrays["rgb"] = grid.rgb.astype(np.float32)
    arrays.update(extra)
    save_npz_atomic(path, **arrays)

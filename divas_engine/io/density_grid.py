"""NeRF density grids stored as ``.npz`` (paper App. A; the NeRF backbone's scene).

Keys: ``density [D,H,W]`` (σ ≥ 0 per world unit, indexed ``[iz, iy, ix]``),
optional ``rgb [D,H,W,3]`` in [0,1], ``aabb [2,3]`` (min, max corners). Samples
are cell-centred (see :class:`~divas_engine.scene.DensityGrid`).
"""

from __future__ import annotations

import math
import struct
import tokenize
import zipfile
import zlib
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.lib import format as npformat

from ..errors import DivasInputError
from ..output_paths import save_npz_atomic
from ..scene import DensityGrid, SourceInfo
from .limits import inflate_budget, limits, require_input_file

__all__ = ["read_density_grid", "write_density_grid", "GRID_KEYS"]

GRID_KEYS = ("density", "rgb", "aabb")


def _member(zf: zipfile.ZipFile, name: str, path: Path, budget: int) -> np.ndarray:
    """One ``.npy`` member, its declared size and shape checked before any allocation.

    Reads at most what the header declares (never more than the member's declared
    uncompressed size, itself within ``budget``); plain numeric dtypes only.
    """
    info = zf.getinfo(name)
    where = f"{path}:{name}"
    if info.flag_bits & 0x1:
        raise DivasInputError(where, "encrypted ZIP member")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise DivasInputError(where, f"unsupported ZIP compression method {info.compress_type}")
    if info.file_size > budget:
        raise DivasInputError(
            where, f"declares {info.file_size} bytes uncompressed, over the {budget}-byte limit"
        )
    with zf.open(info) as f:
        try:
            version = npformat.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = npformat.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = npformat.read_array_header_2_0(f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
        except (ValueError, SyntaxError, TypeError, tokenize.TokenError) as e:
            raise DivasInputError(where, f"bad .npy header ({e})") from None
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
            raise DivasInputError(where, f"dtype {dtype} is not a plain numeric type")
        if dtype.kind not in "biuf":
            raise DivasInputError(where, f"dtype {dtype} is not a number type")
        if not all(isinstance(d, int) and d >= 0 for d in shape):
            raise DivasInputError(where, f"bad array shape {shape}")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > info.file_size:
            raise DivasInputError(
                where, f"shape {shape} needs {nbytes} bytes, the member holds {info.file_size}"
            )
        data = bytearray(nbytes)  # writable, filled in place: no second copy
        view, got = memoryview(data), 0
        while got < nbytes:
            k = f.readinto(view[got:])
            if not k:
                raise DivasInputError(where, f"truncated: {got} of {nbytes} bytes")
            got += k
    arr = np.frombuffer(data, dtype)
    return arr.reshape(shape, order="F" if fortran else "C")


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    size = path.stat().st_size
    budget = inflate_budget(size)
    with zipfile.ZipFile(path) as zf:
        names = {n[:-4]: n for n in zf.namelist() if n.endswith(".npy")}
        if "density" not in names or "aabb" not in names:
            raise DivasInputError(
                path, f"density grid needs keys 'density' and 'aabb', has {sorted(names)}"
            )
        want = [k for k in GRID_KEYS if k in names]
        total = sum(zf.getinfo(names[k]).file_size for k in want)
        if total > budget:
            raise DivasInputError(
                path,
                f"arrays declare {total} bytes uncompressed, over the {budget}-byte limit "
                "for a file of this size (LoadLimits)",
            )
        return {k: _member(zf, names[k], path, budget) for k in want}


def read_density_grid(path: str | PathLike) -> DensityGrid:
    """Load and validate a density grid; NaN/Inf densities become 0 and are counted.

    The ``.npz`` is read member by member with every declared size checked first
    (:class:`~divas_engine.io.limits.LoadLimits`), never through ``np.load``.
    """
    path = require_input_file(path, "density grid")
    try:
        arrays = _read_arrays(path)
        density = np.asarray(arrays["density"], dtype=np.float32)
        aabb = np.asarray(arrays["aabb"], dtype=np.float64)
        rgb = np.asarray(arrays["rgb"], dtype=np.float32) if "rgb" in arrays else None
    except DivasInputError:
        raise
    except (
        OSError,
        ValueError,
        zipfile.BadZipFile,
        EOFError,
        zlib.error,
        NotImplementedError,
        RuntimeError,
        struct.error,
    ) as e:
        raise DivasInputError(path, f"not a readable .npz density grid ({e})") from None
    if density.size > limits().max_rows:
        raise DivasInputError(path, f"{density.size} cells, over the {limits().max_rows} limit")
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
    # every cell is kept, in order: no per-cell row index is held (SourceInfo.kept None)
    src = SourceInfo(path, "npz", int(density.size), None, n_bad)
    return DensityGrid(density, aabb, rgb, src)


def write_density_grid(path: str | PathLike, grid: DensityGrid, **extra: np.ndarray) -> None:
    """Write a grid in the same schema (plus any ``extra`` arrays, e.g. a ``mask``)."""
    arrays = {"density": grid.density.astype(np.float32), "aabb": np.asarray(grid.aabb, np.float64)}
    if grid.rgb is not None:
        arrays["rgb"] = grid.rgb.astype(np.float32)
    arrays.update(extra)
    save_npz_atomic(path, **arrays)

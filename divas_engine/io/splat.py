"""antimatter15 ``.splat``: decoder and byte-exact subset writer.

The file is a headerless array of 32-byte little-endian records, one per
Gaussian (SH degree 0):

=======  ======  =====================================================
bytes    type    meaning
=======  ======  =====================================================
0..11    3×f32   position x, y, z
12..23   3×f32   scale (linear standard deviations, already ``exp``'d)
24..27   4×u8    r, g, b = ``(0.5 + SH_C0 * f_dc) * 255``; a = ``opacity * 255``
28..31   4×u8    rotation w, x, y, z = ``q * 128 + 128`` (clipped to 0..255)
=======  ======  =====================================================

Decoding: ``f_dc = (c/255 - 0.5) / SH_C0``, ``opacity = a / 255``,
``q = (b - 128) / 128`` then normalised. A rotation whose four bytes are all
128 (a zero quaternion) is treated like a non-finite row and dropped, as the
PLY loader does. Coordinates are those of the PLY it was converted from (no
axis change).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from ..errors import DivasInputError
from ..kinds import SceneKind
from ..output_paths import atomic_file, same_file
from ..scene import SH_C0, SourceInfo, SurfelScene
from .gaussians import check_file_rows, scene_from_rows, surfels_from_arrays

__all__ = ["SPLAT_DTYPE", "read_splat", "write_splat_subset"]

#: One ``.splat`` record.
SPLAT_DTYPE = np.dtype(
    [("pos", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))]
)
assert SPLAT_DTYPE.itemsize == 32

_BLOCK = 1 << 20


def _row_count(path: Path) -> int:
    try:
        size = path.stat().st_size
    except OSError as e:
        raise DivasInputError(path, f"cannot read .splat file ({e})") from None
    if size == 0:
        raise DivasInputError(path, "empty scene: the .splat file has 0 bytes")
    if size % SPLAT_DTYPE.itemsize:
        raise DivasInputError(
            path,
            f".splat size {size} is not a multiple of 32 bytes (truncated or not a .splat file)",
        )
    return size // SPLAT_DTYPE.itemsize


def read_splat(path: str | PathLike) -> SurfelScene:
    """Load a ``.splat`` file into a :class:`SurfelScene` (3DGS flattened to surfels)."""
    path = Path(path)
    total = _row_count(path)
    means = np.empty((total, 3), np.float32)
    quats = np.empty((total, 4), np.float32)
    scales = np.empty((total, 2), np.float32)
    scale_n = np.empty(total, np.float32)
    opac = np.empty(total, np.float32)
    sh = np.empty((total, 1, 3), np.float32)
    finite = np.empty(total, bool)
    with open(path, "rb") as f:
        for start in range(0, total, _BLOCK):
            rows = np.fromfile(f, dtype=SPLAT_DTYPE, count=min(_BLOCK, total - start))
            n = len(rows)
            if n == 0:
                raise DivasInputError(path, "truncated .splat file")
            sl = slice(start, start + n)
            q = (rows["rot"].astype(np.float32) - 128.0) / 128.0
            s = rows["scale"]
            ok = np.isfinite(rows["pos"]).all(1) & np.isfinite(s).all(1) & (np.abs(q).sum(1) > 0)
            s = np.where(ok[:, None], s, np.float32(1.0))
            q2, s2 = surfels_from_arrays(np.where(ok[:, None], q, np.float32(1.0)), s)
            scale_n[sl] = s.min(1)
            means[sl] = rows["pos"]
            quats[sl], scales[sl] = q2, s2
            rgba = rows["rgba"].astype(np.float32)
            opac[sl] = rgba[:, 3] / 255.0
            sh[sl, 0, :] = (rgba[:, :3] / 255.0 - 0.5) / SH_C0
            finite[sl] = ok
    return scene_from_rows(
        path,
        "splat",
        (means, quats, scales, opac, sh),
        finite,
        0,
        SceneKind.GS3D,
        invalid_what="NaN/Inf values or zero rotations",
        scale_n=scale_n,
    )


def write_splat_subset(source: SourceInfo, file_rows: np.ndarray, out_path: str | PathLike) -> None:
    """Copy the 32-byte records ``file_rows`` (in that order) of ``source`` to ``out_path``."""
    path = Path(source.path)
    if same_file(path, out_path):
        raise DivasInputError(out_path, "the output is the input; refusing to overwrite the input")
    total = _row_count(path)
    rows = check_file_rows(path, file_rows, total)
    if rows.size == 0:
        raise ValueError("nothing to write: file_rows is empty")
    mm = np.memmap(path, dtype=SPLAT_DTYPE, mode="r", shape=(total,))
    with atomic_file(out_path) as f:
        for start in range(0, len(rows), _BLOCK):
            np.asarray(mm[rows[start : start + _BLOCK]]).tofile(f)

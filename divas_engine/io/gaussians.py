"""Turn raw (stored) Gaussian parameters into the engine's activated surfels.

Shared by every splat format (PLY, compressed PLY, .splat, .spz): each decoder
produces stored-space or activated arrays and calls :func:`surfels_from_arrays`.
"""

from __future__ import annotations

import numpy as np

from ..errors import DivasInputError
from ..geometry import normalize_quats, quat_rotation_entries, rotation_entries_to_quat
from ..kinds import SceneKind
from ..scene import SourceInfo, SurfelScene

__all__ = [
    "sigmoid",
    "flatten_to_surfels",
    "surfels_from_arrays",
    "scene_from_rows",
    "check_file_rows",
    "sane_rows",
]


def sigmoid(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    return (1.0 / (1.0 + np.exp(-np.clip(x, -88.0, 88.0)))).astype(np.float32)


def flatten_to_surfels(quats: np.ndarray, scales3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3DGS → 2DGS (NOTES "Conventions"): keep the two largest scale axes.

    Args:
        quats: ``[N,4]`` unit quaternions (w, x, y, z) of the 3D Gaussians.
        scales3: ``[N,3]`` activated standard deviations.

    Returns:
        ``(quats2, scales2)``: quaternions whose rotation columns 0/1 are the two
        largest axes (largest first) and column 2 their cross product (the
        dropped, smallest axis up to sign), and ``[N,2]`` the matching scales.
    """
    # the arithmetic of quat_to_rotmat → columns a, b → np.cross → rotmat_to_quat, on
    # [N] entry arrays instead of [N,3,3] matrices (bit-identical, ~3x faster on load)
    m = quat_rotation_entries(quats.astype(np.float32))
    order = np.argsort(-scales3, axis=1, kind="stable")
    a, b = order[:, 0], order[:, 1]
    tu = [np.choose(a, row) for row in m]  # column a of each rotation
    tv = [np.choose(b, row) for row in m]
    n = [  # np.cross(tu, tv) (float32, same operation order)
        tu[1] * tv[2] - tu[2] * tv[1],
        tu[2] * tv[0] - tu[0] * tv[2],
        tu[0] * tv[1] - tu[1] * tv[0],
    ]
    q2 = rotation_entries_to_quat([[tu[i], tv[i], n[i]] for i in range(3)]).astype(np.float32)
    idx = np.arange(len(quats))
    s2 = np.stack([scales3[idx, a], scales3[idx, b]], axis=1).astype(np.float32)
    return q2, s2


def surfels_from_arrays(quats_raw: np.ndarray, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalise quaternions and flatten 3-axis scales; 2-axis scales pass through.

    ``scales`` must already be activated (``exp`` of the stored log-scales).
    """
    q = normalize_quats(quats_raw)
    if scales.shape[1] == 3:
        return flatten_to_surfels(q, scales)
    return q, np.ascontiguousarray(scales, dtype=np.float32)


def scene_from_rows(
    path,
    fmt: str,
    arrays: tuple[np.ndarray, ...],
    valid: np.ndarray,
    sh_degree: int,
    kind: SceneKind,
    extras: dict | None = None,
    invalid_what: str = "NaN/Inf values (or out-of-range scales, rotations, opacities)",
    scale_n: np.ndarray | None = None,
    file_sh_degree: int | None = None,
) -> SurfelScene:
    """The scene of every decoder: drop the rows where ``valid`` is False, count them.

    ``arrays`` = ``(means, quats, scales, opacities, sh)`` over all file rows, in file order;
    ``scale_n`` the dropped normal-axis scale of 3DGS rows (:attr:`SurfelScene.scale_n`);
    ``file_sh_degree`` the file's SH degree when ``sh`` keeps fewer bands.
    Whatever the decoder checked, rows whose decoded values are unusable are dropped
    too (:func:`sane_rows`): so every format drops-and-counts the same things.

    Raises:
        DivasInputError: no valid row is left.
    """
    total = len(valid)
    valid = np.asarray(valid, bool) & sane_rows(arrays, scale_n)
    kept = np.flatnonzero(valid)
    n_bad = total - len(kept)
    if len(kept) == 0:
        raise DivasInputError(path, f"empty scene: all {total} rows hold {invalid_what}")
    if n_bad:
        arrays = tuple(a[kept] for a in arrays)
        scale_n = None if scale_n is None else scale_n[kept]
    src = SourceInfo(path, fmt, total, kept.astype(np.int64), n_bad, file_sh_degree)
    return SurfelScene(*arrays, sh_degree, kind, src, dict(extras or {}), scale_n)


def sane_rows(arrays: tuple[np.ndarray, ...], scale_n: np.ndarray | None = None) -> np.ndarray:
    """Rows whose activated values are usable: every value finite (as stored, float32),
    scales > 0, unit quaternions (a zero quaternion normalises to garbage), opacity in
    [0, 1]. Checked in row blocks to bound the temporaries."""
    means, quats, scales, opac, sh = arrays[:5]
    n = len(means)
    ok = np.empty(n, bool)
    step = 1 << 18
    for a in range(0, n, step):
        b = min(n, a + step)
        q = quats[a:b]
        with np.errstate(invalid="ignore", over="ignore"):
            # one float64 row sum per array: finite iff every value is (float32 values
            # cannot overflow a float64 sum), cheaper than isfinite(...).all(1) on each
            total = np.add.reduce(sh[a:b].reshape(b - a, -1), axis=1, dtype=np.float64)
            total += np.add.reduce(means[a:b], axis=1, dtype=np.float64)
            total += np.add.reduce(scales[a:b], axis=1, dtype=np.float64)
            total += opac[a:b]
            qn = np.einsum("ij,ij->i", q, q, dtype=np.float64)  # NaN/Inf in q make it so
            r = (
                np.isfinite(total)
                & (np.abs(qn - 1.0) < 1e-3)
                & (scales[a:b].min(1) > 0)
                & (opac[a:b] >= 0)
                & (opac[a:b] <= 1)
            )
            if scale_n is not None:
                r &= np.isfinite(scale_n[a:b]) & (scale_n[a:b] > 0)
        ok[a:b] = r
    return ok


def check_file_rows(path, file_rows: np.ndarray, n: int) -> np.ndarray:
    """``file_rows`` as an int64 array of indices into the ``n`` rows of ``path``.

    Raises:
        ValueError: not a 1-D integer array, or an index out of range.
    """
    rows = np.asarray(file_rows)
    if rows.ndim != 1 or not (rows.dtype.kind in "iu" or rows.size == 0):
        raise ValueError("file_rows must be a 1-D integer array")
    rows = rows.astype(np.int64)
    if rows.size and (rows.min() < 0 or rows.max() >= n):
        raise ValueError(f"file_rows out of range for {path} ({n} rows)")
    return rows

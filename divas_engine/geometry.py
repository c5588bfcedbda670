"""Small vectorised rotation helpers shared by loaders, renderers and cameras.

Quaternions are stored ``(w, x, y, z)`` (the 3DGS/2DGS PLY order ``rot_0..3``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "quat_to_rotmat",
    "quat_rotation_entries",
    "rotmat_to_quat",
    "rotation_entries_to_quat",
    "normalize_quats",
]


def normalize_quats(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[N,4]``; a zero quaternion becomes the identity."""
    q = np.asarray(q, dtype=np.float32)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    out = np.where(n > 0, q / np.maximum(n, 1e-30), np.array([1, 0, 0, 0], np.float32))
    return out.astype(np.float32, copy=False)


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[N,3,3]`` from unit quaternions ``[N,4]`` (w, x, y, z).

    Column ``k`` of each matrix is the rotated ``k``-th local axis; for a surfel
    columns 0 and 1 are the tangent directions and column 2 the normal.
    """
    q = np.asarray(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.empty(q.shape[:-1] + (3, 3), dtype=q.dtype)
    r[..., 0, 0] = 1 - 2 * (y * y + z * z)
    r[..., 0, 1] = 2 * (x * y - w * z)
    r[..., 0, 2] = 2 * (x * z + w * y)
    r[..., 1, 0] = 2 * (x * y + w * z)
    r[..., 1, 1] = 1 - 2 * (x * x + z * z)
    r[..., 1, 2] = 2 * (y * z - w * x)
    r[..., 2, 0] = 2 * (x * z - w * y)
    r[..., 2, 1] = 2 * (y * z + w * x)
    r[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return r


def quat_rotation_entries(q: np.ndarray) -> list[list[np.ndarray]]:
    """The entries ``m[i][j]`` (each ``[N]``) of :func:`quat_to_rotmat`, computed with
    the same arithmetic in ``q``'s dtype (bit-identical), without the ``[N,3,3]`` array."""
    q = np.asarray(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def rotation_entries_to_quat(m: list[list[np.ndarray]]) -> np.ndarray:
    """:func:`rotmat_to_quat` of the rotations whose entries are ``m[i][j]`` (each
    ``[N]``): the same float64 arithmetic in the same order (bit-identical), on the
    entries a branch needs instead of copies of whole matrices."""
    e = [[np.asarray(v, dtype=np.float64) for v in row] for row in m]
    m00, m11, m22 = e[0][0], e[1][1], e[2][2]
    tr = m00 + m11 + m22
    k = np.argmax(np.stack([tr, m00, m11, m22], axis=-1), axis=-1)
    d21, d02, d10 = e[2][1] - e[1][2], e[0][2] - e[2][0], e[1][0] - e[0][1]
    a01, a02, a12 = e[0][1] + e[1][0], e[0][2] + e[2][0], e[1][2] + e[2][1]
    q = np.empty(tr.shape + (4,), dtype=np.float64)
    # each branch on every rotation (element-wise, so each value is what the branch
    # alone would give), kept where it is Shepperd's choice
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(np.maximum(1.0 + tr, 1e-300)) * 2
        for c, v in enumerate((0.25 * s, d21 / s, d02 / s, d10 / s)):
            q[..., c] = v
        for branch, (d_a, d_b, d_c) in enumerate(
            ((m00, m11, m22), (m11, m00, m22), (m22, m00, m11)), 1
        ):
            pick = k == branch
            if not np.any(pick):
                continue
            s = np.sqrt(np.maximum(1.0 + d_a - d_b - d_c, 1e-300)) * 2
            vals = {
                1: (d21 / s, 0.25 * s, a01 / s, a02 / s),
                2: (d02 / s, a01 / s, 0.25 * s, a12 / s),
                3: (d10 / s, a02 / s, a12 / s, 0.25 * s),
            }[branch]
            for c, v in enumerate(vals):
                q[..., c] = np.where(pick, v, q[..., c])
    q *= np.where(q[..., :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q


def rotmat_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[N,4]`` (w, x, y, z, with w >= 0) from rotations ``[N,3,3]``.

    Shepperd's method: picks the numerically largest of the four candidate
    denominators per matrix, so it is stable for every rotation angle.
    """
    r = np.asarray(r, dtype=np.float64)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack([tr, m00, m11, m22], axis=-1)
    k = np.argmax(cand, axis=-1)
    q = np.empty(r.shape[:-2] + (4,), dtype=np.float64)

    def _fill(sel: np.ndarray, s: np.ndarray, w, x, y, z) -> None:
        q[sel, 0], q[sel, 1], q[sel, 2], q[sel, 3] = w, x, y, z

    sel = k == 0
    if np.any(sel):
        rr = r[sel]
        s = np.sqrt(np.maximum(1.0 + tr[sel], 1e-300)) * 2
        _fill(
            sel,
            s,
            0.25 * s,
            (rr[:, 2, 1] - rr[:, 1, 2]) / s,
            (rr[:, 0, 2] - rr[:, 2, 0]) / s,
            (rr[:, 1, 0] - rr[:, 0, 1]) / s,
        )
    sel = k == 1
    if np.any(sel):
        rr = r[sel]
        s = np.sqrt(np.maximum(1.0 + rr[:, 0, 0] - rr[:, 1, 1] - rr[:, 2, 2], 1e-300)) * 2
        _fill(
            sel,
            s,
            (rr[:, 2, 1] - rr[:, 1, 2]) / s,
            0.25 * s,
            (rr[:, 0, 1] + rr[:, 1, 0]) / s,
            (rr[:, 0, 2] + rr[:, 2, 0]) / s,
        )
    sel = k == 2
    if np.any(sel):
        rr = r[sel]
        s = np.sqrt(np.maximum(1.0 + rr[:, 1, 1] - rr[:, 0, 0] - rr[:, 2, 2], 1e-300)) * 2
        _fill(
            sel,
            s,
            (rr[:, 0, 2] - rr[:, 2, 0]) / s,
            (rr[:, 0, 1] + rr[:, 1, 0]) / s,
            0.25 * s,
            (rr[:, 1, 2] + rr[:, 2, 1]) / s,
        )
    sel = k == 3
    if np.any(sel):
        rr = r[sel]
        s = np.sqrt(np.maximum(1.0 + rr[:, 2, 2] - rr[:, 0, 0] - rr[:, 1, 1], 1e-300)) * 2
        _fill(
            sel,
            s,
            (rr[:, 1, 0] - rr[:, 0, 1]) / s,
            (rr[:, 0, 2] + rr[:, 2, 0]) / s,
            (rr[:, 1, 2] + rr[:, 2, 1]) / s,
            0.25 * s,
        )
    q *= np.where(q[..., :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return q

"""Host-side (NumPy) 3D Morton codes, the same layout as ``divas_kernels.occupancy``.

Bit ``3k`` of a code is bit ``k`` of ``ix``, ``3k+1`` of ``iy``, ``3k+2`` of ``iz``;
up to 21 bits per axis, codes in ``int64``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["morton_encode", "morton_decode", "MAX_AXIS_BITS"]

MAX_AXIS_BITS = 21
_MASKS = [
    (32, 0x1F00000000FFFF),
    (16, 0x1F0000FF0000FF),
    (8, 0x100F00F00F00F00F),
    (4, 0x10C30C30C30C30C3),
    (2, 0x1249249249249249),
]


def _part1by2(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in _MASKS:
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def _compact1by2(x: np.ndarray) -> np.ndarray:
    x = x & np.uint64(0x1249249249249249)
    for shift, mask in [
        (2, 0x10C30C30C30C30C3),
        (4, 0x100F00F00F00F00F),
        (8, 0x1F0000FF0000FF),
        (16, 0x1F00000000FFFF),
        (32, 0x1FFFFF),
    ]:
        x = (x ^ (x >> np.uint64(shift))) & np.uint64(mask)
    return x


def morton_encode(ijk: np.ndarray) -> np.ndarray:
    """``[N,3]`` non-negative integer coordinates (< 2²¹) → ``[N] int64`` codes."""
    ijk = np.asarray(ijk)
    if ijk.ndim != 2 or ijk.shape[1] != 3:
        raise ValueError(f"morton_encode: expected [N,3] coordinates, got {ijk.shape}")
    if ijk.size and (ijk.min() < 0 or ijk.max() >= (1 << MAX_AXIS_BITS)):
        raise ValueError("morton_encode: coordinates must lie in [0, 2^21)")
    c = (
        _part1by2(ijk[:, 0])
        | (_part1by2(ijk[:, 1]) << np.uint64(1))
        | (_part1by2(ijk[:, 2]) << np.uint64(2))
    )
    return c.astype(np.int64)


def morton_decode(codes: np.ndarray) -> np.ndarray:
    """``[N] int64`` codes → ``[N,3] int64`` coordinates (ix, iy, iz)."""
    c = np.asarray(codes).astype(np.uint64)
    return np.stack(
        [_compact1by2(c), _compact1by2(c >> np.uint64(1)), _compact1by2(c >> np.uint64(2))], -1
    ).astype(np.int64)

"""Per-view summed-area tables (paper Sec. 3.5 "Footprint statistics via integral
images", App. B).

Tables are ``[H+1, W+1]`` with a zero first row and column, so the sum over pixels
``x0..x1 × y0..y1`` (inclusive) is ``S[y1+1,x1+1] − S[y0,x1+1] − S[y1+1,x0] + S[y0,x0]``.

* ``sat_n``, ``sat_n2``: N_samp and N_samp², **int64** — N_samp is a count, so the
  tables, the footprint mean and the variance are exact (float32 would lose the
  N_samp² sums above 2²⁴).
* ``sat_pos``: int32 count of mask-positive pixels (``m > m_pos``), used only by
  the exact thin-path early-out.
"""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["integral_images", "sat_sum", "sat_sum_i32"]


@wp.func
def sat_sum(s: wp.array2d(dtype=wp.int64), x0: int, y0: int, x1: int, y1: int) -> wp.int64:
    """Inclusive box sum over pixels x0..x1, y0..y1."""
    return s[y1 + 1, x1 + 1] - s[y0, x1 + 1] - s[y1 + 1, x0] + s[y0, x0]


@wp.func
def sat_sum_i32(s: wp.array2d(dtype=wp.int32), x0: int, y0: int, x1: int, y1: int) -> int:
    return int(s[y1 + 1, x1 + 1] - s[y0, x1 + 1] - s[y1 + 1, x0] + s[y0, x0])


@wp.kernel
def _rows_kernel(
    nsamp: wp.array2d(dtype=wp.int32),
    mask: wp.array2d(dtype=float),
    thr: float,
    sat_n: wp.array2d(dtype=wp.int64),
    sat_n2: wp.array2d(dtype=wp.int64),
    sat_pos: wp.array2d(dtype=wp.int32),
):
    y = wp.tid()
    a = wp.int64(0)
    a2 = wp.int64(0)
    ap = wp.int32(0)
    for x in range(nsamp.shape[1]):
        n = wp.int64(nsamp[y, x])
        a = a + n
        a2 = a2 + n * n
        if mask[y, x] > thr:
            ap = ap + wp.int32(1)
        sat_n[y + 1, x + 1] = a
        sat_n2[y + 1, x + 1] = a2
        sat_pos[y + 1, x + 1] = ap


@wp.kernel
def _cols_kernel(
    sat_n: wp.array2d(dtype=wp.int64),
    sat_n2: wp.array2d(dtype=wp.int64),
    sat_pos: wp.array2d(dtype=wp.int32),
):
    x = wp.tid()
    for y in range(1, sat_n.shape[0]):
        sat_n[y, x] = sat_n[y, x] + sat_n[y - 1, x]
        sat_n2[y, x] = sat_n2[y, x] + sat_n2[y - 1, x]
        sat_pos[y, x] = sat_pos[y, x] + sat_pos[y - 1, x]


def integral_images(
    nsamp: wp.array2d, mask: wp.array2d, mask_thresh: float, device=None
) -> tuple[wp.array2d, wp.array2d, wp.array2d]:
    """Summed-area tables of ``nsamp [H,W] int32``, its square and ``mask > mask_thresh``.

    Returns ``(sat_n, sat_n2, sat_pos)``, each ``[H+1, W+1]`` (int64, int64, int32).
    """
    device = device or nsamp.device
    if nsamp.dtype != wp.int32 or nsamp.ndim != 2:
        raise TypeError("integral_images: nsamp must be a 2D int32 array")
    if mask.shape != nsamp.shape:
        raise ValueError(f"integral_images: mask {mask.shape} vs nsamp {nsamp.shape}")
    h, w = nsamp.shape
    sat_n = wp.zeros((h + 1, w + 1), dtype=wp.int64, device=device)
    sat_n2 = wp.zeros((h + 1, w + 1), dtype=wp.int64, device=device)
    sat_pos = wp.zeros((h + 1, w + 1), dtype=wp.int32, device=device)
    wp.launch(
        _rows_kernel,
        dim=h,
        inputs=[nsamp, mask, float(mask_thresh), sat_n, sat_n2, sat_pos],
        device=device,
    )
    wp.launch(_cols_kernel, dim=w + 1, inputs=[sat_n, sat_n2, sat_pos], device=device)
    return sat_n, sat_n2, sat_pos


def integral_images_numpy(
    nsamp: np.ndarray, mask: np.ndarray, mask_thresh: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NumPy twin (tests)."""

    def sat(a: np.ndarray, dt) -> np.ndarray:
        s = np.zeros((a.shape[0] + 1, a.shape[1] + 1), dtype=dt)
        s[1:, 1:] = a.astype(dt).cumsum(0).cumsum(1)
        return s

    n = np.asarray(nsamp, dtype=np.int64)
    return sat(n, np.int64), sat(n * n, np.int64), sat(np.asarray(mask) > mask_thresh, np.int32)

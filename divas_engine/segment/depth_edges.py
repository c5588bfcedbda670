"""Depth-edge regions for :class:`.classic.ClassicSegmenter` (weight-free object masks).

A genuine 3D edge is a *depth jump* (an occluding contour) or a *crease* (a normal
discontinuity where an object stands on a surface); both are measured so that a slanted plane
produces neither:

* jump: disparity ``q = 1/D`` of a plane is affine in pixels, so between neighbours the step
  ``s = q[x+1] − q[x]`` equals the one-sided steps ``g_L = q[x−1] − q[x−2]`` and
  ``g_R = q[x+3] − q[x+2]``; the jump is ``min(|s − g_L|, |s − g_R|) / min(q[x], q[x+1])``;
* crease: the angle between the pseudo-normals ``n ∝ (f·∂q/∂u / q, f·∂q/∂v / q, 1)`` taken
  ``crease_gap`` away on either side of the pair.

A pixel's edge strength is ``max(jump / τ_jump, crease / τ_crease)`` over its 4 neighbour
pairs; pixels ≥ 1 form the barrier, the barrier-free 4-connected component under the click is
the object core, which re-grows over barrier pixels whose depth continues it (:func:`regrow`).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["fill_small_holes", "pair_jumps", "pair_creases", "pixel_strength", "regrow"]


def fill_small_holes(logd: np.ndarray, max_area: int) -> np.ndarray:
    """Invalid (non-finite) specks up to ``max_area`` px get their valid neighbours' mean."""
    bad = ~np.isfinite(logd)
    if not bad.any():
        return logd
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bad.astype(np.uint8), connectivity=8)
    small = np.zeros(n, bool)
    small[1:] = stats[1:, cv2.CC_STAT_AREA] <= max_area
    fill = small[lab]
    if not fill.any():
        return logd
    valid = (~bad).astype(np.float32)
    v = np.where(bad, 0.0, logd).astype(np.float32)
    out = logd.copy()
    for k in (5, 9, 17):
        num = cv2.blur(v, (k, k))
        den = cv2.blur(valid, (k, k))
        ok = fill & (den > 1e-3)
        out[ok] = num[ok] / den[ok]
        fill &= ~ok
        if not fill.any():
            break
    return out


def _shift_steps(q: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step ``s`` between neighbours along ``axis`` and the one-sided steps around it
    (edge-replicated), all shaped like the pair array (length − 1 along ``axis``)."""
    qa = np.moveaxis(q, axis, 0)
    p = np.concatenate([qa[:1], qa[:1], qa, qa[-1:], qa[-1:]], axis=0)  # replicate 2 px
    n = qa.shape[0]
    a, b = p[2 : n + 1], p[3 : n + 2]  # q[x], q[x+1] for x = 0 .. n−2
    s = b - a
    gl = p[1:n] - p[0 : n - 1]  # q[x−1] − q[x−2]: skips one pixel, so a jump resampled
    gr = p[4 : n + 3] - p[3 : n + 2]  # q[x+3] − q[x+2]  into a 2-px ramp is still a jump
    lo = np.minimum(a, b)
    return (
        np.moveaxis(s, 0, axis),
        np.moveaxis(gl, 0, axis),
        np.moveaxis(gr, 0, axis),
        np.moveaxis(lo, 0, axis),
    )


def pair_jumps(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Plane-invariant relative disparity jumps of horizontal ``[H,W−1]`` and vertical
    ``[H−1,W]`` neighbour pairs (module docstring); pairs touching no surface → inf."""
    out = []
    for axis in (1, 0):
        s, gl, gr, lo = _shift_steps(q, axis)
        res = np.minimum(np.abs(s - gl), np.abs(s - gr))
        res = np.where(np.isfinite(res), res, np.abs(s))  # no extrapolation at a hole's rim
        with np.errstate(divide="ignore", invalid="ignore"):
            j = res / np.maximum(lo, 1e-12)
        j = np.where(np.isfinite(j), j, np.inf)
        out.append(j.astype(np.float32))
    return out[0], out[1]


def _normals(q: np.ndarray, focal: float) -> np.ndarray:
    qs = cv2.GaussianBlur(q, (0, 0), 1.0)
    gx = cv2.Sobel(qs, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(qs, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    qq = np.maximum(qs, 1e-12)
    n = np.dstack([focal * gx / qq, focal * gy / qq, np.ones_like(q)])
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    return n.astype(np.float32)


def pair_creases(q: np.ndarray, focal: float, gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Angle (radians) between the normals ``gap`` px on either side of each pair."""
    n = _normals(q, focal)
    out = []
    for axis in (1, 0):
        na = np.moveaxis(n, axis, 0)
        m = na.shape[0]
        idx = np.arange(m - 1)
        a = na[np.clip(idx - gap + 1, 0, m - 1)]
        b = na[np.clip(idx + gap, 0, m - 1)]
        a2 = na[np.clip(idx - 3 * gap + 1, 0, m - 1)]
        b2 = na[np.clip(idx + 3 * gap, 0, m - 1)]

        def angle(u, v):
            return np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0))

        # excess of the turn across the pair over the turns on either side: 0 on planes
        # *and* on smoothly curved surfaces (tubes, spheres), the full angle at a crease
        ang = angle(a, b) - 0.5 * np.maximum(angle(a2, a), angle(b, b2))
        ang = np.maximum(ang, 0.0)
        out.append(np.moveaxis(np.nan_to_num(ang, nan=np.pi), 0, axis).astype(np.float32))
    return out[0], out[1]


def pixel_strength(h_pairs: np.ndarray, v_pairs: np.ndarray) -> np.ndarray:
    """Per pixel: the max over its (up to 4) incident pair strengths."""
    hh, ww = v_pairs.shape[0] + 1, h_pairs.shape[1] + 1
    e = np.zeros((hh, ww), np.float32)
    e[:, :-1] = h_pairs
    e[:, 1:] = np.maximum(e[:, 1:], h_pairs)
    e[:-1, :] = np.maximum(e[:-1, :], v_pairs)
    e[1:, :] = np.maximum(e[1:, :], v_pairs)
    return e


def regrow(
    core: np.ndarray, logd: np.ndarray, allowed: np.ndarray, tol: float, steps: int
) -> np.ndarray:
    """Grow ``core`` by up to ``steps`` px into ``allowed`` pixels whose log depth is within
    ``tol`` of the mean log depth of their region neighbours (the barrier's own side)."""
    reg = core.copy()
    k = np.ones((3, 3), np.float32)
    ld = np.where(np.isfinite(logd), logd, 0.0).astype(np.float32)
    fin = np.isfinite(logd)
    for _ in range(steps):
        r = (reg & fin).astype(np.float32)
        cnt = cv2.filter2D(r, -1, k, borderType=cv2.BORDER_CONSTANT)
        sm = cv2.filter2D(r * ld, -1, k, borderType=cv2.BORDER_CONSTANT)
        cand = (cnt > 0) & ~reg & allowed & fin
        with np.errstate(divide="ignore", invalid="ignore"):
            near = np.abs(ld - sm / np.maximum(cnt, 1e-6)) <= tol
        add = cand & near
        if not add.any():
            break
        reg |= add
    return reg

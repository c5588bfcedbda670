"""Supporting ground planes of a scene without cameras (not in the paper).

A supporting plane of normal n has (almost) all content on its +n side and a dense contact
layer on it: it sits at the ``ground_floor_quantile`` (0.5 %) of the heights ``h = (p − c)·n``
of the sampled Gaussian centres, and its *support* is the opacity weight in the band
``|h − h_floor| ≤ ground_band · r_fg``.

* coarse search over ``ground_directions`` Fibonacci normals; the six strongest local maxima
  plus the strongest normal near ``convention_up`` are refined on a 6° cap;
* *sharpness* = 1 − (mean support on the ring 15° away) / (support): a floor or a pair of soles
  loses its band when the normal tilts, the round bottom of a blob does not;
* *coverage* = the fraction of the content's footprint on the plane (a 24×24 grid) holding
  band points; *axis_deg* = angle of n to the nearest world axis.

Which candidate becomes the up is decided in :mod:`.up_direction`: a dense one-sided plane is
not always a floor, so the candidates are only evidence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..scene import DensityGrid, Scene, SurfelScene
from .config import ViewConfig
from .fibonacci import fibonacci_sphere, up_frame

__all__ = ["GroundPlane", "scene_points", "ground_candidates", "spherical_cap"]

_NMS_DEG = 20.0
_CAP_DEG = 6.0
_CAP_DIRECTIONS = 200
_RING_DEG = 15.0
_RING_DIRECTIONS = 24
_COVERAGE_CELLS = 24
_MAX_CANDIDATES = 6


@dataclass(frozen=True, eq=False)
class GroundPlane:
    """A supporting plane ``{x : n·x = offset}``; content lies on its +n side.

    Attributes:
        normal: unit normal n [3], pointing into the content (the up it implies).
        offset: n·x of the plane (world units).
        support: opacity fraction of the sampled Gaussians in the contact band.
        sharpness: 1 − support 15° away / support (module docstring).
        coverage: fraction of the content's footprint on the plane the band covers.
        axis_deg: angle of n to the nearest world axis, degrees.
        below: opacity fraction below the band (floaters; ≈ ``ground_floor_quantile``).
    """

    normal: np.ndarray
    offset: float
    support: float
    sharpness: float
    coverage: float
    axis_deg: float
    below: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed height of ``points [N,3]`` above the plane."""
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset

    def to_dict(self) -> dict:
        return {
            "normal": self.normal.tolist(),
            "offset": self.offset,
            "support": self.support,
            "sharpness": self.sharpness,
            "coverage": self.coverage,
            "axis_deg": self.axis_deg,
            "below": self.below,
        }


def scene_points(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """``(points [N,3] float64, weights [N])`` of a scene: Gaussian centres and
    opacities, or occupied voxel centres and their opacity ``1 − exp(−σ h)``."""
    if isinstance(scene, SurfelScene):
        return np.asarray(scene.means, np.float64), np.asarray(scene.opacities, np.float64)
    if isinstance(scene, DensityGrid):
        occ = scene.density > 0
        idx = np.argwhere(occ)[:, ::-1]
        h = float(np.mean(scene.voxel_size))
        pts = scene.aabb[0] + (idx + 0.5) * scene.voxel_size
        return pts.astype(np.float64), 1.0 - np.exp(-scene.density[occ].astype(np.float64) * h)
    raise TypeError(f"scene_points: unsupported scene type {type(scene).__name__}")


def spherical_cap(
    axis: np.ndarray, half_angle_deg: float, n: int, min_angle_deg: float = 0.0
) -> np.ndarray:
    """``[n,3]`` unit directions evenly covering the zone between ``min_angle_deg`` and
    ``half_angle_deg`` from ``axis`` (a cap when the minimum is 0): the equal-area
    golden-angle lattice of eq:fib restricted to it (band i at
    cos φ = cos φ_min − (cos φ_min − cos φ_max)(i + ½)/n), nearest the axis first."""
    i = np.arange(n, dtype=np.float64)
    cos_min = math.cos(math.radians(min_angle_deg))
    cos_max = math.cos(math.radians(half_angle_deg))
    z = cos_min - (cos_min - cos_max) * (i + 0.5) / n
    theta = 2.0 * math.pi * i / ((1.0 + math.sqrt(5.0)) / 2.0)
    rho = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    local = np.stack([rho * np.cos(theta), rho * np.sin(theta), z], axis=1)
    return local @ up_frame(axis).T


def _ring(axis: np.ndarray, angle_deg: float, n: int) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    a = math.radians(angle_deg)
    local = np.stack(
        [math.sin(a) * np.cos(t), math.sin(a) * np.sin(t), np.full(n, math.cos(a))], axis=1
    )
    return local @ up_frame(axis).T


class _Support:
    """Band support of candidate normals over one point sample (centred at ``c``)."""

    def __init__(self, rel: np.ndarray, w: np.ndarray, band: float, quantile: float):
        self.rel = rel.astype(np.float32)
        self.w = w.astype(np.float32)
        self.band = np.float32(band)
        self.k = min(len(rel) - 1, max(0, int(quantile * len(rel))))

    def __call__(self, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Support ``[D]`` and floor height ``[D]`` of unit normals ``dirs [D,3]``."""
        out, floors = [], []
        for lo in range(0, len(dirs), 256):  # bounded memory: P × 256 heights at a time
            h = self.rel @ dirs[lo : lo + 256].T.astype(np.float32)
            floor = np.partition(h, self.k, axis=0)[self.k]
            inband = np.abs(h - floor) <= self.band
            out.append(self.w @ inband)
            floors.append(floor)
        return np.concatenate(out).astype(np.float64), np.concatenate(floors).astype(np.float64)


def _coverage(rel: np.ndarray, w: np.ndarray, n: np.ndarray, inband: np.ndarray) -> float:
    frame = up_frame(n)
    uv = rel @ frame[:, :2]
    lo, hi = np.percentile(uv, 1.0, axis=0), np.percentile(uv, 99.0, axis=0)
    g = _COVERAGE_CELLS
    cell = np.floor((uv - lo) / np.maximum(hi - lo, 1e-12) * g).astype(np.int64)
    ok = np.all((cell >= 0) & (cell < g), axis=1)
    content = np.zeros((g, g))
    np.add.at(content, (cell[ok, 0], cell[ok, 1]), w[ok])
    banded = np.zeros((g, g), dtype=bool)
    banded[cell[ok & inband, 0], cell[ok & inband, 1]] = True
    occupied = content >= 0.002 * content.sum()
    return float((occupied & banded).sum() / max(int(occupied.sum()), 1))


#: rows per block of the in-range test of :func:`ground_candidates`
_CHUNK = 1 << 18


def ground_candidates(
    points: np.ndarray,
    weights: np.ndarray,
    center: np.ndarray,
    r_fg: float,
    config: ViewConfig | None = None,
    seed: int = 0,
) -> list[GroundPlane]:
    """Supporting-plane candidates of a point set, strongest support first.

    Args:
        points, weights: ``[N,3]`` centres and ``[N]`` opacities (:func:`scene_points`).
        center, r_fg: ``c_scene`` and ``r_fg``; only points within ``r_fg`` are used.
        seed: of the point subsample (the result is deterministic for a seed).
    """
    cfg = config or ViewConfig()
    c = np.asarray(center, np.float64)
    # the rows within r_fg, then the sample, in float64 only for the rows used: the same
    # values as converting everything first, without [N,3] float64 temporaries
    pts, wts = np.asarray(points), np.asarray(weights)
    keep = np.empty(len(pts), bool)
    for s in range(0, len(pts), _CHUNK):
        blk = np.asarray(pts[s : s + _CHUNK], np.float64)
        keep[s : s + _CHUNK] = np.linalg.norm(blk - c, axis=1) <= r_fg
    rows = np.flatnonzero(keep)
    del keep
    w = np.asarray(wts[rows], np.float64)
    if len(rows) < 10 or w.sum() <= 0:
        return []
    if len(rows) > cfg.ground_points:
        idx = np.sort(
            np.random.default_rng(seed).choice(len(rows), cfg.ground_points, replace=False)
        )
        rows, w = rows[idx], w[idx]
    p = np.asarray(pts[rows], np.float64)
    w = w / w.sum()
    rel = p - c
    band = cfg.ground_band * float(r_fg)
    support = _Support(rel, w, band, cfg.ground_floor_quantile)
    dirs = fibonacci_sphere(cfg.ground_directions)
    score, _ = support(dirs)
    cos_nms = math.cos(math.radians(_NMS_DEG))
    peaks: list[int] = []
    for i in np.argsort(-score, kind="stable"):
        if all(dirs[i] @ dirs[j] < cos_nms for j in peaks):
            peaks.append(int(i))
        if len(peaks) == _MAX_CANDIDATES:
            break
    conv = np.asarray(cfg.convention_up, np.float64)
    conv /= np.linalg.norm(conv)
    cone = dirs @ conv >= math.cos(math.radians(cfg.ground_convention_deg))
    if cone.any():
        i = int(np.flatnonzero(cone)[np.argmax(score[cone])])
        if all(dirs[i] @ dirs[j] < cos_nms for j in peaks):
            peaks.append(i)
    out = []
    for i in peaks:
        cap = np.vstack([dirs[i], spherical_cap(dirs[i], _CAP_DEG, _CAP_DIRECTIONS)])
        s_cap, f_cap = support(cap)
        j = int(np.argmax(s_cap))
        n, s_best, floor = cap[j], float(s_cap[j]), float(f_cap[j])
        s_ring, _ = support(_ring(n, _RING_DEG, _RING_DIRECTIONS))
        h = rel @ n
        inband = np.abs(h - floor) <= band
        out.append(
            GroundPlane(
                normal=n.copy(),
                offset=float(floor + c @ n),
                support=s_best,
                sharpness=float(1.0 - s_ring.mean() / s_best) if s_best > 0 else 0.0,
                coverage=_coverage(rel, w, n, inband),
                axis_deg=float(np.degrees(np.arccos(np.clip(np.abs(n).max(), -1.0, 1.0)))),
                below=float(w[h < floor - band].sum()),
            )
        )
    out.sort(key=lambda g: -g.support)
    return out

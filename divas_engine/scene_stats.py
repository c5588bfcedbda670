"""Robust per-scene statistics (paper eq:scene-norm; NOTES "Occupancy").

``c_scene`` is the coordinate-wise median of the centres and ``r_fg`` the 99th
percentile of their distance to it, so floaters move neither.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene, SurfelScene

__all__ = ["RobustFrame", "robust_frame", "scene_summary"]


@dataclass(frozen=True)
class RobustFrame:
    """Working frame of a scene (eq:scene-norm).

    Attributes:
        center: ``c_scene`` [3], coordinate-wise median of surfel centres.
        radius: ``r_fg``, P99 of the radial distance to ``center``.
    """

    center: np.ndarray
    radius: float


def robust_frame(
    points: np.ndarray, weights: np.ndarray | None = None, percentile: float = 99.0
) -> RobustFrame:
    """Median centre and P``percentile`` radius of ``points [N,3]``.

    With ``weights`` (e.g. grid densities) the median and percentile are weighted.
    """
    p = np.asarray(points)
    if weights is None:
        # one contiguous float64 column at a time: the median of each column and the
        # squared distance summed x, y, z in that order are np.median(p, axis=0) and
        # np.linalg.norm(p - c, axis=1) exactly, without the [N,3] float64 copies
        c = np.array([np.median(p[:, k].astype(np.float64)) for k in range(3)])
        r = float(np.percentile(np.sqrt(_squared_distance(p, c)), percentile))
        return RobustFrame(c, r)
    p = np.asarray(p, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    c = np.array([_weighted_quantile(p[:, k], w, 0.5) for k in range(3)])
    r = _weighted_quantile(np.linalg.norm(p - c, axis=1), w, percentile / 100.0)
    return RobustFrame(c, float(r))


def _squared_distance(p: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``[N]`` float64 ``Σ_k (p[:, k] − c_k)²``, summed k = 0, 1, 2."""
    d2 = np.zeros(len(p), np.float64)
    for k in range(p.shape[1]):
        d = p[:, k].astype(np.float64)
        d -= c[k]
        d *= d
        d2 += d
    return d2


def _weighted_quantile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    order = np.argsort(x)
    cw = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cw, q * cw[-1])])


def _pct(x: np.ndarray) -> dict[str, float]:
    p1, p50, p99 = np.percentile(x, [1, 50, 99])
    return {
        "min": float(x.min()),
        "p1": float(p1),
        "median": float(p50),
        "p99": float(p99),
        "max": float(x.max()),
    }


def scene_summary(scene: Scene, frame: RobustFrame | None = None) -> dict:
    """JSON-ready description of a scene (what ``divas info`` prints); ``frame``: the
    scene's :func:`robust_frame` when the caller has it already."""
    info: dict = {}
    if scene.source is not None:
        info["file"] = str(scene.source.path)
        info["format"] = scene.source.format
        info["rows_in_file"] = scene.source.num_rows
        info["dropped_nonfinite"] = scene.source.dropped_nonfinite
    if isinstance(scene, SurfelScene):
        frame = frame or robust_frame(scene.means)
        smax = scene.scales.max(axis=1)
        aspect = smax / (scene.scales.min(axis=1) + 1e-12)
        info.update(
            {
                "kind": scene.kind,
                "count": len(scene),
                "sh_degree": _file_sh_degree(scene),
                "bounds_min": scene.means.min(0).tolist(),
                "bounds_max": scene.means.max(0).tolist(),
                "center": frame.center.tolist(),
                "radius_p99": frame.radius,
                "scale_max": _pct(smax),
                "aspect": _pct(aspect),
                "opacity": _pct(scene.opacities),
            }
        )
    else:
        occupied = scene.density > 0
        idx = np.argwhere(occupied)[:, ::-1]  # (ix, iy, iz)
        centres = scene.aabb[0] + (idx + 0.5) * scene.voxel_size
        frame = frame or robust_frame(centres, scene.density[occupied])
        info.update(
            {
                "kind": "nerf_grid",
                "count": int(scene.density.size),
                "sh_degree": None,
                "resolution": list(scene.density.shape),
                "occupied": int(occupied.sum()),
                "has_rgb": scene.rgb is not None,
                "bounds_min": scene.aabb[0].tolist(),
                "bounds_max": scene.aabb[1].tolist(),
                "occupied_bounds_min": centres.min(0).tolist(),
                "occupied_bounds_max": centres.max(0).tolist(),
                "center": frame.center.tolist(),
                "radius_p99": frame.radius,
                "density": _pct(scene.density[occupied]),
            }
        )
        if "cascades" in scene.extras:  # instant-ngp snapshot
            info["aabb_scale"] = scene.extras.get("aabb_scale")
            info["cascades"] = scene.extras["cascades"]
        if scene.network is not None or scene.extras.get("network_note"):
            info["network"] = (
                "yes: views are rendered from it"
                if scene.network is not None
                else scene.extras["network_note"]
            )
    return info


def _file_sh_degree(scene: SurfelScene) -> int:
    """The SH degree of the scene's file (a scene loaded with fewer bands says so)."""
    src = scene.source
    if src is not None and src.file_sh_degree is not None:
        return int(src.file_sh_degree)
    return int(scene.sh_degree)

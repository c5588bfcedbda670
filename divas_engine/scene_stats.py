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
    p = np.asarray(points, dtype=np.float64)
    if weights is None:
        c = np.median(p, axis=0)
        r = float(np.percentile(np.linalg.norm(p - c, axis=1), percentile))
        return RobustFrame(c, r)
    w = np.asarray(weights, dtype=np.float64)
    c = np.array([_weighted_quantile(p[:, k], w, 0.5) for k in range(3)])
    r = _weighted_quantile(np.linalg.norm(p - c, axis=1), w, percentile / 100.0)
    return RobustFrame(c, float(r))


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


def scene_summary(scene: Scene) -> dict:
    """JSON-ready description of a scene (what ``divas info`` prints)."""
    info: dict = {}
    if scene.source is not None:
        info["file"] = str(scene.source.path)
        info["format"] = scene.source.format
        info["rows_in_file"] = scene.source.num_rows
        info["dropped_nonfinite"] = scene.source.dropped_nonfinite
    if isinstance(scene, SurfelScene):
        frame = robust_frame(scene.means)
        smax = scene.scales.max(axis=1)
        aspect = smax / (scene.scales.min(axis=1) + 1e-12)
        info.update(
            {
                "kind": scene.kind,
                "count": len(scene),
                "sh_degree": scene.sh_degree,
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
        frame = robust_frame(centres, scene.density[occupied])
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
    return info

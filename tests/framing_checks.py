"""Independent checks of an anchor's framing from its render (camera-free anchors).

The framing code works on a sample of Gaussian centres; these checks look at what the
user sees instead: the rendered accumulated opacity α of the view.

* extent: the central 96 % of the α mass along x and along y (its 2 % and 98 %
  quantiles), in pixels;
* fill of the larger image side: max(extent_x, extent_y) / max(W, H);
* centring: offset of the extent's midpoint from the image centre, as a fraction of
  the image side along that axis;
* upright: the true up, projected at the look-at point, points to image-up within a
  tolerance (the camera has no roll when its right axis is ⟂ the scene up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from divas_engine.camera import Camera

__all__ = ["Framing", "rendered_framing", "image_up_angle_deg", "angle_deg"]


@dataclass(frozen=True)
class Framing:
    fill_larger_side: float
    fill_x: float
    fill_y: float
    offset_x: float
    offset_y: float


def _quantiles(mass: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    c = np.cumsum(mass)
    c = c / c[-1]
    return float(np.searchsorted(c, lo)), float(np.searchsorted(c, hi) + 1)


def rendered_framing(alpha: np.ndarray, q: float = 0.02) -> Framing:
    """:class:`Framing` of a rendered α image ``[H,W]``."""
    a = np.asarray(alpha, np.float64)
    h, w = a.shape
    if a.sum() <= 0:
        return Framing(0.0, 0.0, 0.0, 1.0, 1.0)
    x0, x1 = _quantiles(a.sum(0), q, 1 - q)
    y0, y1 = _quantiles(a.sum(1), q, 1 - q)
    return Framing(
        max(x1 - x0, y1 - y0) / max(w, h),
        (x1 - x0) / w,
        (y1 - y0) / h,
        (0.5 * (x0 + x1) - 0.5 * w) / w,
        (0.5 * (y0 + y1) - 0.5 * h) / h,
    )


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def image_up_angle_deg(camera: Camera, point: np.ndarray, true_up: np.ndarray) -> float:
    """Angle in the image between the true up projected at ``point`` and image-up (−y);
    NaN when the up is seen end-on (projected length < 5 % of a unit step)."""
    p = np.asarray(point, float)
    step = 0.05 * np.linalg.norm(camera.center - p)
    uv, _ = camera.project(np.stack([p, p + step * np.asarray(true_up, float)]))
    d = uv[1] - uv[0]
    if np.linalg.norm(d) < 1e-3 * camera.width:
        return float("nan")
    return angle_deg(d, [0.0, -1.0])

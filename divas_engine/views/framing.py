"""Framing of camera-free anchors on the scene's robust foreground (not in the paper).

The paper places anchors from the training cameras (eq:gs-radius). A capture without them gets
anchors framed on its own content:

* **scene layout** (:func:`layout_from_points`) — the up (:func:`~.up_direction.estimate_scene_up`),
  a seeded, opacity-weighted sample of foreground Gaussians (within ``r_fg`` of ``c_scene``),
  the framing centre (midpoint of the sample's weighted [q, 1 − q] box) and the floor height
  when a ground was found;
* **robust extent of a view** (:func:`projected_extent`) — the weighted [q, 1 − q] quantiles of
  the sample's projected u and v; the *fill* is ``max(Δu / W, Δv / H)``;
* **framed camera** (:func:`framed_camera`) — looking along a direction with no roll, at the
  distance where the fill is ``frame_fill`` (bisection) but no nearer than ``frame_min_depth`` ×
  the look-at distance to the foreground's near end, its look-at point moved until the robust
  extent is centred (three rounds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from .config import ViewConfig
from .fibonacci import up_frame
from .up_direction import SceneUp, estimate_scene_up

__all__ = [
    "SceneLayout",
    "layout_from_points",
    "weighted_quantiles",
    "projected_extent",
    "view_fill",
    "framed_camera",
    "look_from",
]

_CENTRING_ROUNDS = 3
_BISECTION_STEPS = 40


@dataclass(frozen=True, eq=False)
class SceneLayout:
    """What camera-free anchors are framed on (module docstring).

    Attributes:
        up: the :class:`~.up_direction.SceneUp` of the scene.
        points, weights: the foreground sample ``[M,3]`` and its opacities ``[M]``.
        center: framing centre [3]; r_fg: the scene's ``r_fg``.
        floor: height of the ground along ``up.up`` (None: no ground found).
    """

    up: SceneUp
    points: np.ndarray
    weights: np.ndarray
    center: np.ndarray
    r_fg: float
    floor: float | None

    def height(self, x: np.ndarray) -> np.ndarray:
        """Height of points ``[...,3]`` above the floor (NaN without a ground)."""
        h = np.asarray(x, np.float64) @ self.up.up
        return h - self.floor if self.floor is not None else np.full(np.shape(h), np.nan)


def weighted_quantiles(x: np.ndarray, w: np.ndarray, qs) -> np.ndarray:
    """Weighted quantiles ``qs`` of ``x [N]`` (the smallest x whose cumulative weight
    reaches ``q`` of the total)."""
    order = np.argsort(x, kind="stable")
    cw = np.cumsum(w[order])
    idx = np.searchsorted(cw, np.asarray(qs, np.float64) * cw[-1])
    return x[order][np.minimum(idx, len(x) - 1)]


def layout_from_points(
    points: np.ndarray,
    weights: np.ndarray,
    center: np.ndarray,
    r_fg: float,
    config: ViewConfig | None = None,
    up: np.ndarray | None = None,
    seed: int = 0,
) -> SceneLayout:
    """:class:`SceneLayout` of a point set (``c_scene`` = ``center``, ``r_fg``)."""
    cfg = config or ViewConfig()
    p = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    est = estimate_scene_up(p, w, center, r_fg, cfg, up)
    keep = (np.linalg.norm(p - np.asarray(center), axis=1) <= r_fg) & (w > 0)
    if not keep.any():
        raise ValueError("scene layout: no foreground point within r_fg of the centre")
    p, w = p[keep], w[keep]
    if len(p) > cfg.frame_points:
        idx = np.sort(np.random.default_rng(seed).choice(len(p), cfg.frame_points, replace=False))
        p, w = p[idx], w[idx]
    frame = up_frame(est.up)
    local = p @ frame
    q = cfg.frame_quantile
    box = np.array([weighted_quantiles(local[:, k], w, (q, 1.0 - q)) for k in range(3)])
    mid = frame @ box.mean(axis=1)
    floor = None
    if est.ground is not None:
        floor = float(weighted_quantiles(local[:, 2], w, (cfg.ground_floor_quantile,))[0])
    return SceneLayout(est, p, w, mid, float(r_fg), floor)


def projected_extent(
    camera: Camera, points: np.ndarray, weights: np.ndarray, q: float
) -> tuple[float, float, float, float, float]:
    """``(u0, u1, v0, v1, behind)``: weighted [q, 1 − q] pixel extent of the points in
    front of the camera, and the weight fraction behind it (``behind``)."""
    uv, z = camera.project(points)
    front = z > 0
    behind = float(weights[~front].sum() / max(weights.sum(), 1e-300))
    if front.sum() < 2:
        return 0.0, 0.0, 0.0, 0.0, 1.0
    u0, u1 = weighted_quantiles(uv[front, 0], weights[front], (q, 1.0 - q))
    v0, v1 = weighted_quantiles(uv[front, 1], weights[front], (q, 1.0 - q))
    return float(u0), float(u1), float(v0), float(v1), behind


def view_fill(camera: Camera, layout: SceneLayout, q: float) -> tuple[float, float, float]:
    """``(fill, du, dv)`` of a view: the fill fraction (module docstring) and the offset
    of the robust extent's centre from the principal point, as fractions of W and H."""
    u0, u1, v0, v1, _ = projected_extent(camera, layout.points, layout.weights, q)
    fill = max((u1 - u0) / camera.width, (v1 - v0) / camera.height)
    return (
        fill,
        (0.5 * (u0 + u1) - camera.cx) / camera.width,
        (0.5 * (v0 + v1) - camera.cy) / camera.height,
    )


def look_from(eye, target, up, intr: Camera, name: str = "") -> Camera:
    """A camera with ``intr``'s intrinsics at ``eye`` looking at ``target``, image-up =
    ``up`` (no roll); straight along the up axis the roll comes from the frame's x."""
    fwd = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    fwd /= np.linalg.norm(fwd)
    u = np.asarray(up, np.float64)
    if abs(fwd @ u) > 0.999:  # straight down/up the up axis: roll from the frame's x
        u = up_frame(u)[:, 0]
    return Camera.look_at(
        eye,
        target,
        u,
        width=intr.width,
        height=intr.height,
        fx=intr.fx,
        fy=intr.fy,
        cx=intr.cx,
        cy=intr.cy,
        name=name,
    )


def framed_camera(
    layout: SceneLayout,
    direction: np.ndarray,
    intr: Camera,
    config: ViewConfig | None = None,
    name: str = "",
) -> Camera:
    """The camera looking at the layout's foreground from unit world ``direction`` (from
    the object towards the camera), framed as in the module docstring.

    Raises:
        ValueError: ``direction`` is zero or not finite.
    """
    cfg = config or ViewConfig()
    d = np.asarray(direction, np.float64)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
        raise ValueError(f"framed_camera: bad direction {direction!r}")
    d = d / np.linalg.norm(d)
    up = layout.up.up
    q = cfg.frame_quantile
    target = layout.center.copy()
    pts, w = layout.points, layout.weights

    def fill_at(t: np.ndarray, r: float) -> float:
        cam = look_from(t + r * d, t, up, intr, name)
        _, z = cam.project(pts)
        if weighted_quantiles(z, w, (q,))[0] < cfg.frame_min_depth * r:
            return math.inf  # too close: inside the content, or a strong perspective
        u0, u1, v0, v1, _ = projected_extent(cam, pts, w, q)
        return max((u1 - u0) / cam.width, (v1 - v0) / cam.height)

    r = 2.5 * layout.r_fg
    for _ in range(_CENTRING_ROUNDS):
        lo, hi = math.log(1e-3 * layout.r_fg), math.log(1e3 * layout.r_fg)
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            if fill_at(target, math.exp(mid)) > cfg.frame_fill:
                lo = mid
            else:
                hi = mid
        r = math.exp(hi)
        cam = look_from(target + r * d, target, up, intr, name)
        u0, u1, v0, v1, _ = projected_extent(cam, pts, w, q)
        du, dv = 0.5 * (u0 + u1) - cam.cx, 0.5 * (v0 + v1) - cam.cy
        # shift the look-at point in the image plane at the target's depth r
        target = target + (du / cam.fx) * r * cam.right + (dv / cam.fy) * r * cam.c2w[:3, 1]
    return look_from(target + r * d, target, up, intr, name)

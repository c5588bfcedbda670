"""Anchors that see given 3D points (prompts in 3D; not in the paper).

A point prompt ``(xyz, positive)`` in the scene's frame becomes a click on an anchor
that sees it. A candidate camera *sees* a point when the point projects inside its
image, lies in front of it, and the rendered depth ``d`` at that pixel (the depth a
click there is back-projected with) agrees with the point's planar depth ``z``:
``z - max(r · (1 + tol), z · tol / (1 + tol)) ≤ d ≤ z / (1 - tol)``. ``r`` (0 by
default) is how far inside its object the point may lie — a detector's object centre:
the object's own surface up to ``r`` in front of it is not an occluder. With ``r = 0``
the lower bound is the occlusion rule of the session's negative clicks (not hidden by
more than ``tol``, ``z ≤ (1 + tol) · d``); the upper one keeps the click on the point's
own surface rather than on one far behind a point in free space.

Choice (:func:`choose_point_anchors`): candidates are ranked by how many positive
points project into them (then how central they fall), rendered in that order until
every positive point is seen or ``max_renders`` is spent; a greedy cover then picks
the fewest rendered candidates that see every positive point, each point clicked on
the first picked candidate that sees it. Negative points go to every picked anchor
that sees them (a negative click prompts the centroid views of its anchor only).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError

__all__ = [
    "PointAnchorConfig",
    "PointClick",
    "PointAnchor",
    "points_seen",
    "choose_point_anchors",
]


@dataclass(frozen=True)
class PointAnchorConfig:
    """How points find their anchors.

    Attributes:
        tol: relative depth agreement of a seen point (the session's
            ``negative_occlusion_tol`` by default, so "visible" means the same for
            negative clicks and 3D points).
        max_renders: candidate renders spent at most.
        border: fraction of the image side kept clear at the border (a click needs a
            neighbourhood inside the view).
    """

    tol: float = 0.05
    max_renders: int = 24
    border: float = 0.02


@dataclass(frozen=True)
class PointClick:
    """Point ``point`` as a click at ``xy`` (pixels of the anchor's full camera)."""

    point: int
    xy: tuple[float, float]
    positive: bool


@dataclass(frozen=True)
class PointAnchor:
    """A chosen candidate and the points clicked on it (in point order)."""

    candidate: int
    clicks: tuple[PointClick, ...]


def points_seen(
    camera: Camera,
    depth: np.ndarray,
    points: np.ndarray,
    tol: float,
    border: float = 0.0,
    radius: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``([N,2] pixels, [N] seen)`` of world points (each inside ``radius`` of its
    object, 0 by default) in ``camera`` whose render gave ``depth`` ``[H,W]`` (module
    docstring)."""
    uv, z = camera.project(np.asarray(points, np.float64).reshape(-1, 3))
    r = np.zeros(len(z)) if radius is None else np.asarray(radius, np.float64).reshape(-1)
    m = border * min(camera.width, camera.height)
    inside = camera.in_image(uv, z, camera.near)
    with np.errstate(invalid="ignore"):
        inside &= (
            (uv[:, 0] >= m)
            & (uv[:, 0] < camera.width - m)
            & (uv[:, 1] >= m)
            & (uv[:, 1] < camera.height - m)
        )
    seen = np.zeros(len(z), bool)
    for i in np.flatnonzero(inside):
        x, y = int(uv[i, 0]), int(uv[i, 1])
        d = float(depth[min(y, depth.shape[0] - 1), min(x, depth.shape[1] - 1)])
        front = max(r[i] * (1.0 + tol), z[i] * tol / (1.0 + tol))
        seen[i] = d > 0 and z[i] - front <= d <= z[i] / (1.0 - tol)
    return uv, seen


def _centrality(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """1 at the image centre, 0 at its border (per point)."""
    dx = np.abs(uv[:, 0] - camera.width / 2) / (camera.width / 2)
    dy = np.abs(uv[:, 1] - camera.height / 2) / (camera.height / 2)
    return 1.0 - np.maximum(dx, dy)


def choose_point_anchors(
    points: np.ndarray,
    positive: np.ndarray,
    candidates: Sequence[Camera],
    depth_of: Callable[[int], tuple[Camera, np.ndarray]],
    config: PointAnchorConfig | None = None,
    *,
    radius: np.ndarray | None = None,
    source: str | None = None,
) -> list[PointAnchor]:
    """The anchors, among ``candidates`` (full-resolution cameras), that see the points.

    Args:
        points: ``[N,3]`` world points; positive: ``[N]`` bool labels; radius: ``[N]``
            how far inside its object each point may lie (None: on its surface).
        depth_of: candidate index → (the camera it was rendered with, its click depth
            map); called at most ``config.max_renders`` times.
        source: names the points in errors (the prompts file).

    Returns the picked anchors in pick order (module docstring).

    Raises:
        DivasInputError: a positive point that no candidate sees, naming ``points[i]``.
    """
    cfg = config or PointAnchorConfig()
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pos = np.asarray(positive, bool).reshape(-1)
    n = len(pts)
    if not candidates or n == 0:
        if pos.any():
            raise DivasInputError(source, "points: the scene offers no anchor cameras")
        return []
    # cheap ranking: positives (then all points) projecting inside, then how central
    inside = np.zeros((len(candidates), n), bool)
    central = np.zeros(len(candidates))
    for c, cam in enumerate(candidates):
        uv, z = cam.project(pts)
        inside[c] = cam.in_image(uv, z, cam.near)
        if inside[c].any():
            central[c] = float(_centrality(cam, uv[inside[c]]).mean())
    order = sorted(
        range(len(candidates)),
        key=lambda c: (-int(inside[c][pos].sum()), -int(inside[c].sum()), -central[c], c),
    )
    seen: dict[int, np.ndarray] = {}
    xy: dict[int, np.ndarray] = {}
    for c in order:
        covered = np.zeros(n, bool)
        for s in seen.values():
            covered |= s
        if len(seen) >= cfg.max_renders or (covered | ~pos).all():
            break
        if not (inside[c] & pos & ~covered).any():
            continue
        cam, depth = depth_of(c)
        uv, s = points_seen(cam, depth, pts, cfg.tol, cfg.border, radius)
        seen[c] = s
        xy[c] = cam.pixels_to(candidates[c], uv)
    covered = np.zeros(n, bool)
    for s in seen.values():
        covered |= s
    missing = np.flatnonzero(pos & ~covered)
    if missing.size:
        i = int(missing[0])
        shown = int(inside[:, i].sum())
        why = (
            f"in the image of {shown} of {len(candidates)} candidate anchors, hidden or off "
            f"the surface (beyond ±{cfg.tol:.0%} of its depth) in the {len(seen)} rendered"
            if shown
            else f"outside the image of all {len(candidates)} candidate anchors"
        )
        x, y, z = pts[i]
        raise DivasInputError(source, f"points[{i}]: no anchor sees ({x:g}, {y:g}, {z:g}): {why}")
    # greedy cover of the positive points by the rendered candidates
    picked: list[int] = []
    todo = pos.copy()
    rank = {c: k for k, c in enumerate(order)}
    while todo.any():
        best = max(seen, key=lambda c: (int((seen[c] & todo).sum()), -rank[c]))
        picked.append(best)
        todo &= ~seen[best]
    owner = np.full(n, -1)
    for c in picked:
        owner[(owner < 0) & seen[c] & pos] = c
    out = []
    for c in picked:
        clicks = []
        for i in range(n):
            if (pos[i] and owner[i] == c) or (not pos[i] and seen[c][i]):
                clicks.append(PointClick(i, (float(xy[c][i, 0]), float(xy[c][i, 1])), bool(pos[i])))
        out.append(PointAnchor(c, tuple(clicks)))
    return out

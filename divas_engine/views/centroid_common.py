"""What both centroid-view instantiations share (paper Sec. 3.3, App. C.3)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError, InputErrorCode

__all__ = ["CentroidView", "ProbeRecord", "click_point", "build_pose"]


@dataclass(frozen=True)
class ProbeRecord:
    """One Strategy-2 probe (alg:centroid-gs).

    Attributes:
        radius: r_k. tau_occ: τ_occ(r_k) (NaN when skipped). occluded: O(r_k) (NaN when
        the central patch held no valid depth). valid: valid central-patch pixels.
        z_near: nearest positive camera z of the neighbourhood (NaN: empty → 0.7 r_k).
        accepted: O(r_k) < τ_O.
    """

    radius: float
    tau_occ: float
    occluded: float
    valid: int
    z_near: float
    accepted: bool


@dataclass(eq=False)
class CentroidView:
    """A centroid view spawned by one click on an anchor.

    Attributes:
        camera: the centroid camera (anchor intrinsics, looks at ``target``, anchor up).
        d_cam: orbit radius, distance from the camera to ``target`` (NOTES "d_cam").
        target: the back-projected 3D click point x_w [3].
        click: the click on the anchor view, continuous pixels (x, y).
        depth: planar anchor depth z at the click (D_med 2DGS / D_mw NeRF).
        box: Strategy-1 2D box on the anchor view ``(x0, y0, x1, y1)`` pixels, or None.
        strategy: ``"nerf-zoom"``, or ``"dense"``/``"sparse"`` (Strategy 1) joined with
            ``"+probe"`` (a probe was accepted) or ``"+fallback"`` (closest radius).
        r_init: Strategy-1 radius (NeRF: the anchor distance to the target).
        neighbours: |N| of eq:neigh (0 for NeRF).
        probes: Strategy-2 log, largest radius first.

    The planner may hand over the full render of ``camera`` it already made (the first
    probe at full resolution): :meth:`take_buffers` gives it once.
    """

    camera: Camera
    d_cam: float
    target: np.ndarray
    click: tuple[float, float]
    depth: float
    box: tuple[float, float, float, float] | None
    strategy: str
    r_init: float
    neighbours: int = 0
    probes: list[ProbeRecord] = field(default_factory=list)
    _buffers: Any = field(default=None, repr=False)
    _render_s: float = field(default=0.0, repr=False)

    def take_buffers(self) -> tuple[Any, float]:
        """The full render of :attr:`camera` the planner made (a ``RenderBuffers``, or
        None) and the seconds it took; given once, so a view that later drops its render
        really frees it."""
        b, self._buffers = self._buffers, None
        return b, (self._render_s if b is not None else 0.0)

    def to_dict(self) -> dict[str, Any]:
        return {
            "camera": self.camera.to_dict(),
            "d_cam": self.d_cam,
            "target": self.target.tolist(),
            "click": list(self.click),
            "depth": self.depth,
            "box": None if self.box is None else list(self.box),
            "strategy": self.strategy,
            "r_init": self.r_init,
            "neighbours": self.neighbours,
            "probes": [
                {k: (None if isinstance(v, float) and v != v else v) for k, v in p.__dict__.items()}
                for p in self.probes
            ],
        }


def click_point(
    anchor: Camera,
    click,
    depth_map: np.ndarray,
    alpha: np.ndarray,
    min_alpha: float,
    depth: float | None = None,
) -> tuple[float, np.ndarray]:
    """Planar depth at a click and its back-projection.

    ``depth_map``/``alpha`` are ``[H,W]`` at the anchor's resolution; the click is a
    continuous pixel point (+0.5 centres), read at the pixel containing it. ``depth``:
    the click's depth when the caller chose it (a nearer surface than ``depth_map``'s,
    :class:`~.config.ViewConfig` ``front_share``); the map still decides whether a
    surface is there.

    Raises:
        DivasInputError: the click is outside the image, or no surface is under it
            (depth 0 or accumulated opacity < ``min_alpha``).
    """
    x, y = float(click[0]), float(click[1])
    h, w = depth_map.shape
    if (h, w) != (anchor.height, anchor.width):
        raise ValueError(
            f"depth map {depth_map.shape} does not match anchor {anchor.width}x{anchor.height}"
        )
    name = anchor.name or "view"
    if not (0.0 <= x < w and 0.0 <= y < h):
        raise DivasInputError(
            None,
            f"click at ({x:g}, {y:g}) is outside anchor {name} ({w}x{h})",
            code=InputErrorCode.CLICK_OUTSIDE,
            details={"x": x, "y": y},
        )
    j, i = int(x), int(y)
    z = float(depth_map[i, j])
    if not np.isfinite(z) or z <= 0.0 or float(alpha[i, j]) < min_alpha:
        raise DivasInputError(
            None,
            f"no surface under the click at ({x:g}, {y:g}) in anchor {name}",
            code=InputErrorCode.NO_SURFACE,
            details={"x": x, "y": y},
        )
    if depth is not None:
        z = float(depth)
    return z, anchor.unproject(np.array([[x, y]]), np.array([z]))[0]


def build_pose(
    anchor: Camera,
    target: np.ndarray,
    view_dir: np.ndarray,
    radius: float,
    name: str = "",
    near_fraction: float = 0.0,
) -> Camera:
    """BuildPose: anchor intrinsics, centre ``target − radius·view_dir``, looking at
    ``target`` (it projects to the principal point), image-up = the anchor's up; its own
    near clip ``Camera.near = near_fraction · radius`` (``ViewConfig.near_fraction``)."""
    eye = np.asarray(target, dtype=np.float64) - float(radius) * np.asarray(
        view_dir, dtype=np.float64
    )
    return Camera.look_at(
        eye,
        target,
        anchor.up,
        width=anchor.width,
        height=anchor.height,
        fx=anchor.fx,
        fy=anchor.fy,
        cx=anchor.cx,
        cy=anchor.cy,
        name=name,
        near=float(near_fraction) * float(radius),
    )

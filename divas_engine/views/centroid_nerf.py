"""NeRF centroid view (paper App. C.3, alg:centroid_view).

The click is back-projected with the largest-weight depth ``D_mw`` of the anchor
render; the camera moves a fixed zoom fraction λ of the way to that point
(0.67 forward-facing, 0.47 360°) and looks at it with the anchor's up.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..render.buffers import RenderBuffers
from .centroid_common import CentroidView, build_pose, click_point
from .config import ViewConfig

__all__ = ["nerf_centroid_view"]


def nerf_centroid_view(
    anchor: Camera,
    click,
    buffers: RenderBuffers,
    *,
    zoom: float | None = None,
    forward_facing: bool = False,
    config: ViewConfig | None = None,
    name: str = "",
) -> CentroidView:
    """alg:centroid_view for one click.

    Args:
        anchor: the anchor camera; ``buffers`` its full-resolution render.
        click: continuous pixel point (x, y) on the anchor.
        zoom: λ ∈ (0, 1); default ``zoom_forward_facing`` / ``zoom_360``.

    Raises:
        DivasInputError: no surface under the click.
    """
    cfg = config or ViewConfig()
    lam = (cfg.zoom_forward_facing if forward_facing else cfg.zoom_360) if zoom is None else zoom
    if not 0.0 < lam < 1.0:
        raise ValueError(f"zoom fraction must be in (0, 1), got {lam}")
    z, x_w = click_point(anchor, click, buffers.D_mw, buffers.alpha, cfg.min_alpha_click)
    p = anchor.center
    p_new = p + lam * (x_w - p)
    dist = float(np.linalg.norm(x_w - p))
    view_dir = (x_w - p) / dist
    d_cam = float(np.linalg.norm(x_w - p_new))
    cam = build_pose(anchor, x_w, view_dir, d_cam, name, cfg.near_fraction)
    return CentroidView(
        cam, d_cam, x_w, (float(click[0]), float(click[1])), z, None, "nerf-zoom", dist
    )

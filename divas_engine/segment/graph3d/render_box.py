"""Where a selection can show in a view: the pixel window of a mask render.

The mask of a selection (:meth:`.segmenter.Graph3DSegmenter.render_masks`) is the
composite of per-primitive values that are 0 off the selection, so every pixel that no
selected primitive's footprint reaches has coverage exactly 0. Rendering only the
window that holds those footprints (:meth:`~divas_engine.camera.Camera.cropped`: the
crop's render is that window of the full render) costs the window instead of the image.

The window is conservative: each selected primitive is a ball of radius ``ρ``
(:attr:`.primitives.ScenePrimitives.reach`, beyond which it draws nothing) around its
position; the ball lies in its axis-aligned box ``p ± ρ`` (camera frame), whose
projection is bounded by its corners'
(:func:`~divas_engine.render.surfel_blocks.ball_pixel_bounds`), widened by ``margin``
pixels (the renderer's screen-space low-pass filter and rounding). A ball
that reaches the camera plane (``Z − ρ ≤ 0 < Z + ρ``) has no finite window: the whole
image. A ball wholly behind the camera draws nothing.
"""

from __future__ import annotations

import numpy as np

from ...camera import Camera
from ...render.surfel_blocks import ball_pixel_bounds

__all__ = ["WHOLE", "screen_box"]

#: a window that is the whole image (:func:`screen_box`)
WHOLE = "whole"


def screen_box(
    camera: Camera, points: np.ndarray, reach: np.ndarray, margin: float
) -> tuple[int, int, int, int] | str | None:
    """Pixel window ``(x0, y0, x1, y1)`` (``x1``, ``y1`` exclusive, clipped to the image)
    that holds every pixel the balls ``points [N,3] ± reach [N]`` can reach in
    ``camera``; :data:`WHOLE` when a ball reaches the camera plane; None when nothing
    can show (no ball in front of the camera, or all beyond the image)."""
    if len(points) == 0:
        return None
    lo_px, hi_px, front, cut = ball_pixel_bounds(camera, points, reach)
    if cut.any():
        return WHOLE
    if not front.any():
        return None
    lo = lo_px[front].min(axis=0) - margin
    hi = hi_px[front].max(axis=0) + margin
    x0 = max(0, int(np.floor(lo[0])))
    y0 = max(0, int(np.floor(lo[1])))
    x1 = min(camera.width, int(np.floor(hi[0])) + 1)
    y1 = min(camera.height, int(np.floor(hi[1])) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, y0, x1, y1

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
pixels (the renderer's screen-space low-pass filter and rounding) — the rule
:func:`~divas_engine.render.surfel_blocks.screen_box` states (the 3DGS completion's sparse
gather windows its pass with it too). A ball
that reaches the camera plane (``Z − ρ ≤ 0 < Z + ρ``) has no finite window: the whole
image. A ball wholly behind the camera draws nothing.
"""

from __future__ import annotations

from ...render.surfel_blocks import WHOLE, screen_box

__all__ = ["WHOLE", "screen_box"]

"""What a session renders, each render an explicit call: anchors, centroid views, value
composites and the selection overlays (paper Sec. 3.7).

:class:`SessionRendering` wraps the session's renderer with one render lock (the
background segmenter work renders too) and the session's timers. Rendering an anchor or
a view stores the buffers in its record, so it is rendered once.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Sequence

import numpy as np

from ..camera import Camera
from ..render import Renderer
from ..render.buffers import RenderBuffers
from .config import SessionConfig
from .records import AnchorView, Overlay, SessionView
from .timing import Timings

__all__ = ["SessionRendering"]


class SessionRendering:
    """The session's renders (module docstring).

    Args:
        renderer: the session's renderer (a :class:`~divas_engine.render.Renderer`, or a
            wrapper that forwards to one).
        timings: the session's timers (``render``, ``overlay``).
        config: returns the session's current :class:`SessionConfig`.
    """

    def __init__(self, renderer, timings: Timings, config: Callable[[], SessionConfig]) -> None:
        self.renderer = renderer
        self.timings = timings
        self._config = config
        self.lock = threading.RLock()

    def render(self, record: AnchorView | SessionView, *, segmented: bool = True) -> RenderBuffers:
        """The render of an anchor or a view: rendered now (and kept in the record) when
        it is not yet. An anchor is never segmented: its blend holds no attached channel."""
        if record.buffers is None:
            record.buffers = self.render_camera(
                record.camera, segmented=segmented and not isinstance(record, AnchorView)
            )
        return record.buffers

    def render_camera(self, camera: Camera, *, segmented: bool = True) -> RenderBuffers:
        """RGB and depth tuple of ``camera``; ``segmented`` False: without the channels
        attached for segmentation (a wrapper's render takes no such opt-out)."""
        with self.lock, self.timings.measure("render"):
            r = self.renderer
            if not segmented and isinstance(r, Renderer):
                return r.render(camera, attached=False)
            return r.render(camera)

    def render_values(self, camera: Camera, values: np.ndarray) -> np.ndarray:
        with self.lock:
            return self.renderer.render_values(camera, values)

    def render_sparse(
        self, camera: Camera, rows: np.ndarray, values: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """A sparse value render; beside the session's other renders (no render lock)
        where the renderer allows it (CPU: graph3d's masks while the view renders)."""
        r = self.renderer
        concurrent = r.sparse_renders_concurrent
        with contextlib.nullcontext() if concurrent else self.lock:
            if threads is None:
                return r.render_values_sparse(camera, rows, values)
            return r.render_values_sparse(camera, rows, values, threads=threads)

    def overlay(
        self,
        camera: Camera,
        rgb: np.ndarray,
        selection: np.ndarray,
        view_id: str | None = None,
    ) -> Overlay:
        """``selection`` (bool per primitive or voxel) recoloured over ``rgb``, the image
        of ``camera``."""
        cfg = self._config()
        with self.timings.measure("overlay"):
            cov = self.render_values(camera, np.asarray(selection, dtype=np.float32))
            a = (np.clip(cov, 0.0, 1.0) * np.float32(cfg.overlay_alpha))[..., None]
            img = rgb * (1.0 - a) + np.asarray(cfg.overlay_color, np.float32) * a
        return Overlay(
            camera,
            cov.astype(np.float32),
            cov >= cfg.overlay_threshold,
            img.astype(np.float32),
            view_id,
        )

    def image_of(self, camera: Camera, anchors: Sequence[AnchorView]) -> np.ndarray:
        """The RGB of ``camera``: an anchor's render when it is that anchor's camera
        and rendered, else a fresh render."""
        anchor = next((a for a in anchors if a.camera is camera), None)
        if anchor is not None and anchor.buffers is not None:
            return anchor.buffers.rgb
        return self.render_camera(camera, segmented=anchor is None).rgb

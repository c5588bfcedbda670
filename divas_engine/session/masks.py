"""Prompt sets and mask previews of a centroid view (paper Sec. 3.4).

* :func:`default_prompts` — the click's 3D point projected into the view (positive)
  plus the anchor's visible negative clicks (NOTES "Headless prompts file");
* :func:`prompt_set` — the user's points, checked;
* :func:`mask_preview` — a SAM result → channel selection (score ≥ ``min_score``) →
  the backend's depth weighting → the "empty mask" rule; the segmenter's hint (what to
  click next when it was unsure, :attr:`~..segment.base.SegResult.message`) is kept as
  the preview's ``advice``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import DivasInputError
from ..kinds import RejectReason
from ..render.buffers import RenderBuffers
from ..segment.base import Rejection, Segmenter, SegResult, select_mask
from ..segment.context import ViewContext
from .backends import SessionBackend
from .config import SessionConfig
from .records import AnchorClick, MaskPreview, SessionView
from .timing import Timings

__all__ = ["TimedSegmenter", "as_prompt_arrays", "default_prompts", "prompt_set", "mask_preview"]


class TimedSegmenter:
    """What the worker and the previews call: ``segment_view`` under the session's timer."""

    def __init__(self, seg: Segmenter, timings: Timings):
        self.seg, self.timings = seg, timings

    def segment_view(self, view: ViewContext, points, labels) -> SegResult:
        with self.timings.measure("segmenter"):
            return self.seg.segment_view(view, points, labels)


def as_prompt_arrays(points, labels) -> tuple[np.ndarray, np.ndarray]:
    """``([K,2] float64 points, [K] int64 labels)``, checked (labels 0/1, finite points)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2) if np.size(points) else np.zeros((0, 2))
    lab = (
        np.asarray(labels, dtype=np.int64).reshape(-1) if np.size(labels) else np.zeros(0, np.int64)
    )
    if len(p) != len(lab):
        raise DivasInputError(None, f"{len(p)} prompt points but {len(lab)} labels")
    if np.any((lab != 0) & (lab != 1)):
        raise DivasInputError(None, "prompt labels must be 1 (positive) or 0 (negative)")
    if not np.all(np.isfinite(p)):
        raise DivasInputError(None, "prompt points contain NaN/Inf")
    return p, lab


def default_prompts(
    v: SessionView, anchor_clicks: Sequence[AnchorClick], occlusion_tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """The click's 3D point projected into ``v`` (positive) plus the negative clicks of
    its anchor that are visible there: in the image, in front, and at a depth
    ≤ (1 + ``occlusion_tol``) · the view's D_ref (negative; ``v`` rendered then)."""
    cam = v.camera
    uv, _ = cam.project(v.centroid.target[None])
    pts, labs = [uv[0]], [1]
    negs = [c for c in anchor_clicks if not c.positive and c.point is not None]
    if negs:
        d_ref = v.buffers.D_ref
        puv, z = cam.project(np.stack([c.point for c in negs]))
        for (x, y), zz in zip(puv, z):
            if not (zz > 0 and 0 <= x < cam.width and 0 <= y < cam.height):
                continue
            d = float(d_ref[int(y), int(x)])
            if d > 0 and zz <= (1.0 + occlusion_tol) * d:
                pts.append((x, y))
                labs.append(0)
    return np.asarray(pts, np.float64), np.asarray(labs, np.int64)


def prompt_set(v: SessionView, points, labels) -> tuple[np.ndarray, np.ndarray]:
    """The checked user prompts of ``v`` (every point inside its image)."""
    p, lab = as_prompt_arrays(points, labels)
    cam = v.camera
    bad = ~((p[:, 0] >= 0) & (p[:, 0] < cam.width) & (p[:, 1] >= 0) & (p[:, 1] < cam.height))
    if bad.any():
        x, y = p[np.flatnonzero(bad)[0]]
        raise DivasInputError(
            None,
            f"view {v.id}: prompt point ({x:g}, {y:g}) is outside "
            f"the {cam.width}x{cam.height} image",
        )
    return p, lab


def mask_preview(
    v: SessionView,
    buffers: RenderBuffers,
    res: SegResult,
    p: np.ndarray,
    lab: np.ndarray,
    config: SessionConfig,
    backend: SessionBackend,
    seconds: float = 0.0,
) -> MaskPreview:
    """The :class:`MaskPreview` of a segmenter result on ``v`` (rendered as ``buffers``)
    for prompts ``p``/``lab``."""
    sel = select_mask(res.masks, res.scores, lab, config.min_score, config.mask_channel)
    weighted, band, rejection = None, None, sel.rejection
    if sel.accepted:
        weighted, band = backend.depth_weight(sel.mask, buffers, p, lab)
        weighted = np.clip(weighted, 0.0, 1.0).astype(np.float32)
        if int(np.count_nonzero(weighted >= 0.5)) < config.min_mask_pixels:
            rejection = Rejection(RejectReason.EMPTY_MASK)
    return MaskPreview(
        v.id, p, lab, res.masks, res.scores, sel, weighted, band, rejection, seconds, res.message
    )

"""Prompt sets and mask previews of a centroid view (paper Sec. 3.4).

* :func:`default_prompts` — the click's 3D point projected into the view (positive)
  plus the visible negative clicks (NOTES "Headless prompts file"; which clicks: the
  object's, or with corrections off its anchor's: :meth:`Session.default_prompts`);
* :func:`prompt_set` — the user's points, checked;
* :func:`mask_preview` — a SAM result → channel selection (score ≥ ``min_score``, when
  the segmenter gates views by score) →
  the backend's depth weighting → the "empty mask" rule; the segmenter's hint (what to
  click next when it was unsure, :attr:`~..segment.base.SegResult.message`) is kept as
  the preview's ``advice``.
"""

from __future__ import annotations

import numpy as np

from ..errors import DivasInputError
from ..kinds import RejectReason
from ..render.buffers import RenderBuffers
from ..segment.base import Rejection, Segmenter, SegResult, select_mask
from ..segment.context import ViewContext
from .backends import SessionBackend
from .config import SessionConfig
from .corrections import visible_pixels
from .records import MaskPreview, SessionView
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
    v: SessionView, negatives: np.ndarray, occlusion_tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """The click's 3D point projected into ``v`` (positive) plus the ``[K,3]`` negative
    click points that are visible there (:func:`.corrections.visible_pixels`: on the
    surface the view shows, within ``occlusion_tol`` of its D_ref; negative; ``v``
    rendered then)."""
    cam = v.camera
    uv, _ = cam.project(v.centroid.target[None])
    pts, labs = [uv[0]], [1]
    if len(negatives):
        puv, ok = visible_pixels(cam, v.buffers.D_ref, negatives, occlusion_tol)
        pts += list(puv[ok])
        labs += [0] * int(ok.sum())
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
    gate: bool = True,
) -> MaskPreview:
    """The :class:`MaskPreview` of a segmenter result on ``v`` (rendered as ``buffers``)
    for prompts ``p``/``lab``. ``gate``: reject below ``config.min_score`` (False: the
    segmenter's :attr:`~..segment.base.Segmenter.score_gates_views` is off; a low score
    keeps its advice)."""
    floor = config.min_score if gate else -np.inf
    sel = select_mask(res.masks, res.scores, lab, floor, config.mask_channel)
    weighted, band, rejection = None, None, sel.rejection
    if sel.accepted:
        weighted, band = backend.depth_weight(sel.mask, buffers, p, lab)
        weighted = np.clip(weighted, 0.0, 1.0).astype(np.float32)
        if int(np.count_nonzero(weighted >= 0.5)) < config.min_mask_pixels:
            rejection = Rejection(RejectReason.EMPTY_MASK)
    return MaskPreview(
        v.id, p, lab, res.masks, res.scores, sel, weighted, band, rejection, seconds, res.message
    )

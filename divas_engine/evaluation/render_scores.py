"""Rendered-mask scores of a selection in the report format of ``divas demo``
(``evaluation.render``) — a thin adapter over :mod:`.metrics`, the one implementation
of the NOTES "Evaluation" protocol (paper App. D):

* Surfels: predicted mask = render of the per-surfel foreground indicator with normal
  alpha blending, ≥ 0.1; ground truth = render of the ground-truth labels, ≥ 0.5.
* NeRF grids: predicted mask = accumulated opacity of the *segmented density* (density
  zeroed outside the selection) ≥ 0.5; ground truth = the same for the ground-truth
  label grid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..camera import Camera
from ..scene import Scene
from .metrics import EvalConfig, SceneScores, evaluate_selection

__all__ = ["MaskScores", "render_iou"]


@dataclass
class MaskScores:
    """Per-camera IoU / precision / recall and the means (``iou`` = mean IoU)."""

    iou: float
    precision: float
    recall: float
    pooled_iou: float
    per_camera: list[dict] = field(default_factory=list)

    @classmethod
    def from_scene_scores(cls, s: SceneScores) -> MaskScores:
        """The report view of :class:`~divas_engine.evaluation.metrics.SceneScores`."""
        rows = [
            {
                "camera": v.camera,
                "iou": v.iou,
                "precision": v.precision,
                "recall": v.recall,
                "pred_pixels": v.pred_pixels,
                "gt_pixels": v.gt_pixels,
            }
            for v in s.views
        ]
        return cls(s.iou, s.precision, s.recall, s.pooled_iou, rows)

    def as_dict(self) -> dict:
        return {
            "iou": self.iou,
            "precision": self.precision,
            "recall": self.recall,
            "pooled_iou": self.pooled_iou,
            "per_camera": self.per_camera,
        }


def render_iou(
    scene: Scene,
    cameras: Sequence[Camera],
    selection: np.ndarray,
    gt: np.ndarray,
    *,
    scale: float = 1.0,
    device=None,
    renderer=None,
    pred_threshold: float | None = None,
    gt_threshold: float = 0.5,
) -> MaskScores:
    """NOTES "Evaluation" masks of ``selection`` vs ``gt`` at ``cameras``
    (:func:`.metrics.evaluate_selection`; ``pred_threshold`` None: by scene kind,
    :meth:`.metrics.EvalConfig.pred_threshold_for`)."""
    cfg = EvalConfig(pred_threshold=pred_threshold, gt_threshold=gt_threshold, scale=scale)
    s = evaluate_selection(
        scene,
        list(cameras),
        np.asarray(selection, bool),
        np.asarray(gt, bool),
        config=cfg,
        renderer=renderer,
        device=device,
    )
    return MaskScores.from_scene_scores(s)

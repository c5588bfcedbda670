"""Rendered-mask evaluation (NOTES "Evaluation", paper App. D protocol).

* Surfels: predicted mask = render of the per-surfel foreground indicator with normal
  alpha blending, ≥ 0.1; ground truth = render of the ground-truth labels, ≥ 0.5.
* NeRF grids: predicted mask = accumulated opacity of the *segmented density* (density
  zeroed outside the selection) ≥ 0.5; ground truth = the same for the ground-truth
  label grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..camera import Camera
from ..render import make_renderer
from ..scene import DensityGrid, Scene, SurfelScene

__all__ = ["MaskScores", "render_iou", "surfel_scores"]


@dataclass
class MaskScores:
    """Per-camera IoU / precision / recall and the means (``iou`` = mean IoU)."""

    iou: float
    precision: float
    recall: float
    pooled_iou: float
    per_camera: list[dict] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"iou": self.iou, "precision": self.precision, "recall": self.recall,
                "pooled_iou": self.pooled_iou, "per_camera": self.per_camera}


def _masked_grid(grid: DensityGrid, keep: np.ndarray) -> DensityGrid:
    return DensityGrid(np.where(keep, grid.density, 0).astype(np.float32), grid.aabb, grid.rgb)


def render_iou(scene: Scene, cameras: Sequence[Camera], selection: np.ndarray,
               gt: np.ndarray, *, scale: float = 1.0, device=None, renderer=None,
               pred_threshold: float = 0.1, gt_threshold: float = 0.5) -> MaskScores:
    """NOTES "Evaluation" masks of ``selection`` vs ``gt`` at ``cameras``."""
    sel = np.asarray(selection, bool)
    g = np.asarray(gt, bool)
    rows, inter_all, union_all = [], 0, 0
    if isinstance(scene, SurfelScene):
        r = renderer or make_renderer(scene, device=device)
        fs, fg = sel.astype(np.float32), g.astype(np.float32)

        def pred_fn(cam):
            return r.render_values(cam, fs, scale) >= pred_threshold

        def gt_fn(cam):
            return r.render_values(cam, fg, scale) >= gt_threshold
    else:
        rp = make_renderer(_masked_grid(scene, sel), device=device)
        rg = make_renderer(_masked_grid(scene, g), device=device)

        def pred_fn(cam):
            return rp.render(cam, scale).alpha >= 0.5

        def gt_fn(cam):
            return rg.render(cam, scale).alpha >= 0.5
    for cam in cameras:
        p, t = pred_fn(cam), gt_fn(cam)
        inter, union = int((p & t).sum()), int((p | t).sum())
        inter_all, union_all = inter_all + inter, union_all + union
        rows.append({"camera": cam.name, "iou": inter / union if union else 1.0,
                     "precision": inter / int(p.sum()) if p.any() else float(not t.any()),
                     "recall": inter / int(t.sum()) if t.any() else 1.0,
                     "pred_pixels": int(p.sum()), "gt_pixels": int(t.sum())})
    mean = lambda k: float(np.mean([x[k] for x in rows])) if rows else float("nan")  # noqa: E731
    return MaskScores(mean("iou"), mean("precision"), mean("recall"),
                      inter_all / union_all if union_all else 1.0, rows)


def surfel_scores(selection: np.ndarray, gt: np.ndarray) -> dict:
    """3D precision / recall / IoU of a per-primitive selection against ground truth."""
    s, g = np.asarray(selection, bool), np.asarray(gt, bool)
    tp = int((s & g).sum())
    return {"precision": tp / int(s.sum()) if s.any() else 0.0,
            "recall": tp / int(g.sum()) if g.any() else 0.0,
            "iou": tp / int((s | g).sum()) if (s | g).any() else 1.0,
            "selected": int(s.sum()), "ground_truth": int(g.sum())}

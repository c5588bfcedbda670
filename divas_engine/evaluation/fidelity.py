"""How complete and faithful an extracted object looks (the metrics users feel).

Surfel scenes only; ``G`` is the ground-truth label set, ``S`` a selection, the *true
silhouette* at a test camera is the NOTES ground-truth mask (``≥ gt_threshold``), and
``w_{i,p} = α_{i,p} T_{i,p}`` is Gaussian ``i``'s blending weight at pixel ``p`` in the whole
scene's render:

* **alpha fidelity** — ``Σ_{p∈sil} Σ_{i∈S∩G} w_{i,p} / Σ_{p∈sil} Σ_{i∈G} w_{i,p}`` pooled over
  the test views (1.0: the extraction renders as solid as in the scene);
* **opacity-weighted Gaussian IoU** — ``Σ_{S∩G} o_i / Σ_{S∪G} o_i`` (``area_weighted_iou``: with
  weight ``o_i · s₁ s₂``);
* **extracted-object PSNR** — the selection rendered alone against the whole scene's render,
  over the RGB inside the true silhouette, ``10 log₁₀(1 / MSE)``. Occluders and background seen
  through translucent edges differ even for ``S = G``: ``psnr_ceiling`` (``G`` alone) is the
  reachable reference, ``psnr_vs_truth`` compares against ``G`` rendered alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from ..camera import Camera
from ..render import make_renderer
from ..scene import SurfelScene

__all__ = ["weighted_iou", "psnr", "FidelityEvaluator", "rendered_report"]


def weighted_iou(selection: np.ndarray, gt: np.ndarray, weights: np.ndarray) -> float:
    """``Σ_{S∩G} w / Σ_{S∪G} w`` (1 when the union weighs nothing)."""
    s, g = np.asarray(selection, bool), np.asarray(gt, bool)
    w = np.asarray(weights, np.float64)
    if not (s.shape == g.shape == w.shape):
        raise ValueError(f"weighted_iou: shapes {s.shape}, {g.shape}, {w.shape} differ")
    union = float(w[s | g].sum())
    return float(w[s & g].sum()) / union if union > 0 else 1.0


def psnr(sq_err_sum: float, count: int) -> float:
    """``10 log₁₀(1 / MSE)`` of a summed squared error over ``count`` values (∞ if 0)."""
    if count <= 0:
        return float("nan")
    mse = sq_err_sum / count
    return float("inf") if mse <= 0 else float(10.0 * math.log10(1.0 / mse))


class FidelityEvaluator:
    """Alpha fidelity, weighted IoUs and extracted-object PSNR of selections of one
    surfel scene at fixed test cameras (module docstring).

    The scene render, the ground-truth weight render and the true object rendered alone
    are made once per camera, in the constructor.

    Args:
        scene: the surfel scene; cameras: test cameras (rendered at ``scale``).
        labels: ``[N]`` bool ground truth.
        gt_masks: the true silhouettes per camera (``ViewEvaluator.gt_masks``), or None
            to render them (``≥ gt_threshold``).
        renderer: a renderer of ``scene`` to reuse.
    """

    def __init__(
        self,
        scene: SurfelScene,
        cameras: Sequence[Camera],
        labels: np.ndarray,
        *,
        gt_masks: Sequence[np.ndarray] | None = None,
        gt_threshold: float = 0.5,
        scale: float = 1.0,
        renderer=None,
        device=None,
    ) -> None:
        if not isinstance(scene, SurfelScene):
            raise TypeError("FidelityEvaluator: surfel scenes only")
        self.scene = scene
        self.cameras = list(cameras)
        self.labels = np.asarray(labels, bool)
        if self.labels.shape != (len(scene),):
            raise ValueError(f"FidelityEvaluator: labels {self.labels.shape} vs {len(scene)}")
        self.scale = float(scale)
        self.device = device
        self.renderer = renderer or make_renderer(scene, device=device)
        self._truth_alone = make_renderer(scene.subset(self.labels), device=device)
        self.sil: list[np.ndarray] = []
        self.rgb: list[np.ndarray] = []
        self.rgb_truth: list[np.ndarray] = []
        for k, cam in enumerate(self.cameras):
            if gt_masks is None:
                g = self.renderer.render_values(cam, self.labels.astype(np.float32), self.scale)
                sil = g >= np.float32(gt_threshold)
            else:
                sil = np.asarray(gt_masks[k], bool)
            self.sil.append(sil)
            self.rgb.append(np.clip(self.renderer.render(cam, self.scale).rgb, 0, 1)[sil])
            self.rgb_truth.append(np.clip(self._truth_alone.render(cam, self.scale).rgb, 0, 1)[sil])
        self.opacity = np.asarray(scene.opacities, np.float64)
        self.area = np.prod(np.asarray(scene.scales, np.float64), axis=1)
        sq = sum(float(((a - b) ** 2).sum()) for a, b in zip(self.rgb, self.rgb_truth))
        self.psnr_ceiling = psnr(sq, sum(a.size for a in self.rgb))

    def score(self, selections: Mapping[str, np.ndarray]) -> dict[str, dict]:
        """Per named selection: ``alpha_fidelity``, ``opacity_weighted_iou``,
        ``area_weighted_iou``, ``psnr``, ``psnr_vs_truth``, ``psnr_ceiling``."""
        names = list(selections)
        sels = {k: np.asarray(selections[k], bool) for k in names}
        for k, s in sels.items():
            if s.shape != self.labels.shape:
                raise ValueError(f"selection {k!r} has shape {s.shape}, labels {self.labels.shape}")
        out: dict[str, dict] = {}
        if not names:
            return out
        g = self.labels
        # channel 0: the true Gaussians, channel 1+j: the selected true Gaussians of j
        vals = np.stack([g] + [sels[k] & g for k in names], axis=1).astype(np.float32)
        num = np.zeros(len(names))
        den = 0.0
        for cam, sil in zip(self.cameras, self.sil):
            img = self.renderer.render_values(cam, vals, self.scale)[sil].astype(np.float64)
            den += float(img[:, 0].sum())
            num += img[:, 1:].sum(axis=0)
        for j, k in enumerate(names):
            s = sels[k]
            sq = sq_t = 0.0
            count = 0
            alone = make_renderer(self.scene.subset(s), device=self.device) if s.any() else None
            for cam, sil, ref, truth in zip(self.cameras, self.sil, self.rgb, self.rgb_truth):
                if alone is None:
                    rgb = np.zeros_like(ref)
                else:
                    rgb = np.clip(alone.render(cam, self.scale).rgb, 0, 1)[sil]
                sq += float(((rgb - ref) ** 2).sum())
                sq_t += float(((rgb - truth) ** 2).sum())
                count += rgb.size
            out[k] = {
                "alpha_fidelity": float(num[j] / den) if den > 0 else 1.0,
                "opacity_weighted_iou": weighted_iou(s, g, self.opacity),
                "area_weighted_iou": weighted_iou(s, g, self.opacity * self.area),
                "psnr": psnr(sq, count),
                "psnr_vs_truth": psnr(sq_t, count),
                "psnr_ceiling": self.psnr_ceiling,
            }
        return out


def rendered_report(
    scene: SurfelScene,
    selections: Mapping[str, np.ndarray],
    labels: np.ndarray,
    up,
    *,
    scale: float = 1.0,
    device=None,
    renderer=None,
) -> dict:
    """The ``--gt-labels`` report of ``divas segment`` on surfel scenes: per named
    selection the NOTES image IoU (mean over views) and this module's metrics at
    camera-free test views framed on the ground truth
    (:func:`~divas_engine.evaluation.real_targets.evaluation_cameras`: 8 azimuths ×
    20°/45° around ``up``, views where the object is mostly hidden left out), rendered at
    ``scale`` of their 640 × 480."""
    from .metrics import EvalConfig, ViewEvaluator
    from .real_targets import evaluation_cameras

    lab = np.asarray(labels, bool)
    if not lab.any():
        return {"test_views": 0}
    cams = evaluation_cameras(scene, lab, up, device=device)
    if not cams:
        return {"test_views": 0}
    r = renderer or make_renderer(scene, device=device)
    ev = ViewEvaluator(scene, cams, lab, config=EvalConfig(scale=scale), renderer=r, device=device)
    fe = FidelityEvaluator(
        scene, cams, lab, gt_masks=ev.gt_masks, scale=scale, renderer=r, device=device
    )
    iou = ev.score(selections)
    fid = fe.score(selections)
    out: dict = {"test_views": len(cams), "up": [float(x) for x in np.asarray(up, float)]}
    for k in selections:
        out[k] = {"image_iou": iou[k].iou, "pooled_iou": iou[k].pooled_iou, **fid[k]}
    return out

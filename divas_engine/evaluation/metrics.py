"""Rendered-mask and per-primitive metrics (NOTES "Evaluation", paper App. D protocol).

Masks at a test camera: surfel scenes — predicted = ``render_values`` of the foreground
indicator F ∈ {0, 1} (``Σ_k α_k T_k F_k``) ``≥ pred_threshold``, ground truth = the same
render of the labels ``≥ gt_threshold`` (0.5); the prediction's threshold is NOTES' 0.1 on
2DGS surfels (the paper's protocol) and 0.5 on trained 3DGS, where the truth then scores 1.0
against itself (:meth:`EvalConfig.pred_threshold_for`); density grids — the accumulated
opacity of the *segmented density* ``≥ nerf_threshold`` (0.5), likewise for the label grid.

Per view: IoU = |P ∧ G| / |P ∨ G| (1 when both are empty), pixel accuracy, precision and recall
(an empty prediction has precision 1 iff the truth is empty; an empty truth has recall 1). Per
scene: the means over views and the pooled IoU. Per primitive: precision / recall / IoU / F1.

:class:`ViewEvaluator` renders the ground-truth masks once and scores any number of selections;
on surfel scenes all selections share one multi-channel render per camera.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from ..camera import Camera
from ..kinds import SceneKind
from ..render import make_renderer
from ..scene import DensityGrid, Scene, SurfelScene

__all__ = [
    "EvalConfig",
    "ViewScore",
    "SceneScores",
    "mask_scores",
    "surfel_scores",
    "segmented_grid",
    "predicted_masks",
    "ground_truth_masks",
    "ViewEvaluator",
    "evaluate_selection",
]


@dataclass(frozen=True)
class EvalConfig:
    """Thresholds and resolution of the evaluation (defaults: NOTES "Evaluation").

    Attributes:
        pred_threshold: surfels: predicted mask = rendered indicator ``≥`` this; None: by
            scene kind (:meth:`pred_threshold_for`: 0.5 on 3DGS, 0.1 otherwise).
        gt_threshold: surfels: ground truth = rendered labels ``≥`` this (0.5).
        nerf_threshold: grids: accumulated opacity ``≥`` this, both masks (0.5).
        scale: test cameras are rendered at this fraction of their resolution (1).
    """

    pred_threshold: float | None = None
    gt_threshold: float = 0.5
    nerf_threshold: float = 0.5
    scale: float = 1.0

    def __post_init__(self) -> None:
        if not self.scale > 0:
            raise ValueError(f"EvalConfig.scale must be positive, got {self.scale}")

    def pred_threshold_for(self, scene) -> float:
        """The prediction's threshold on ``scene``: ``pred_threshold`` where set, else 0.5 on
        trained 3DGS (``SceneKind.GS3D``: a selection's render and the truth's at the same
        level, so the truth scores 1.0) and NOTES' 0.1 on 2DGS surfels."""
        if self.pred_threshold is not None:
            return float(self.pred_threshold)
        return 0.5 if getattr(scene, "kind", None) == SceneKind.GS3D else 0.1


@dataclass(frozen=True)
class ViewScore:
    """Scores of one predicted mask against one ground-truth mask."""

    camera: str
    iou: float
    accuracy: float
    precision: float
    recall: float
    pred_pixels: int
    gt_pixels: int
    intersection: int
    union: int
    pixels: int


@dataclass
class SceneScores:
    """Per-view scores and their means for one selection of one scene.

    Attributes:
        iou, accuracy, precision, recall: means over the test views.
        pooled_iou: Σ intersection / Σ union over the views.
        views: the :class:`ViewScore` of each test camera.
        primitives: :func:`surfel_scores` of the selection (when labels were given).
    """

    iou: float
    accuracy: float
    precision: float
    recall: float
    pooled_iou: float
    views: list[ViewScore] = field(default_factory=list)
    primitives: dict | None = None

    def as_dict(self) -> dict:
        return {
            "iou": self.iou,
            "accuracy": self.accuracy,
            "precision": self.precision,
            "recall": self.recall,
            "pooled_iou": self.pooled_iou,
            "views": [asdict(v) for v in self.views],
            "primitives": self.primitives,
        }


def mask_scores(pred: np.ndarray, gt: np.ndarray, camera: str = "") -> ViewScore:
    """IoU, pixel accuracy, precision and recall of a binary ``pred`` vs ``gt`` (same shape)."""
    p, g = np.asarray(pred, bool), np.asarray(gt, bool)
    if p.shape != g.shape:
        raise ValueError(f"mask_scores: prediction {p.shape} and ground truth {g.shape} differ")
    inter = int(np.count_nonzero(p & g))
    union = int(np.count_nonzero(p | g))
    npred, ngt, total = int(np.count_nonzero(p)), int(np.count_nonzero(g)), int(p.size)
    agree = total - (union - inter)
    return ViewScore(
        camera=camera,
        iou=inter / union if union else 1.0,
        accuracy=agree / total if total else 1.0,
        precision=inter / npred if npred else float(ngt == 0),
        recall=inter / ngt if ngt else 1.0,
        pred_pixels=npred,
        gt_pixels=ngt,
        intersection=inter,
        union=union,
        pixels=total,
    )


def surfel_scores(selection: np.ndarray, gt: np.ndarray) -> dict:
    """Per-primitive precision / recall / IoU / F1 of a bool selection vs bool labels.

    Precision of an empty selection is 0 (1 if the labels are empty too); recall of empty
    labels is 1.
    """
    s, g = np.asarray(selection, bool), np.asarray(gt, bool)
    if s.shape != g.shape:
        raise ValueError(f"surfel_scores: selection {s.shape} and labels {g.shape} differ")
    tp = int(np.count_nonzero(s & g))
    ns, ng, nu = int(np.count_nonzero(s)), int(np.count_nonzero(g)), int(np.count_nonzero(s | g))
    prec = tp / ns if ns else float(ng == 0)
    rec = tp / ng if ng else 1.0
    return {
        "precision": prec,
        "recall": rec,
        "iou": tp / nu if nu else 1.0,
        "f1": 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0,
        "selected": ns,
        "ground_truth": ng,
        "true_positive": tp,
    }


def segmented_grid(grid: DensityGrid, keep: np.ndarray) -> DensityGrid:
    """The density grid with σ zeroed outside the voxel selection ``keep`` ``[D,H,W]``."""
    k = np.asarray(keep, bool)
    if k.shape != grid.density.shape:
        raise ValueError(f"segmented_grid: selection {k.shape} vs grid {grid.density.shape}")
    return DensityGrid(np.where(k, grid.density, 0).astype(np.float32), grid.aabb, grid.rgb)


def _check_selection(scene: Scene, sel: np.ndarray, what: str) -> np.ndarray:
    a = np.asarray(sel)
    shape = (len(scene),) if isinstance(scene, SurfelScene) else scene.density.shape
    if a.shape != shape:
        raise ValueError(f"{what} has shape {a.shape}; the scene needs {shape}")
    return a


def predicted_masks(
    scene: Scene,
    cameras: Sequence[Camera],
    selections: Mapping[str, np.ndarray],
    *,
    config: EvalConfig = EvalConfig(),
    renderer=None,
    device=None,
    thresholds: Mapping[str, float] | None = None,
) -> dict[str, list[np.ndarray]]:
    """Binary ``[H,W]`` masks of each selection at each camera (module docstring rules).

    Surfel scenes: one ``render_values`` per camera with one channel per selection,
    thresholded at ``thresholds[name]`` (default ``config.pred_threshold_for(scene)``). Grids: one
    NeRF render of the segmented density per selection and camera.
    """
    names = list(selections)
    out: dict[str, list[np.ndarray]] = {k: [] for k in names}
    if not names:
        return out
    thr = {k: (thresholds or {}).get(k, config.pred_threshold_for(scene)) for k in names}
    if isinstance(scene, SurfelScene):
        vals = np.stack(
            [
                _check_selection(scene, selections[k], f"selection {k!r}").astype(np.float32)
                for k in names
            ],
            axis=1,
        )
        r = renderer or make_renderer(scene, device=device)
        for cam in cameras:
            img = r.render_values(cam, vals, config.scale)  # [H,W,C]
            for j, k in enumerate(names):
                out[k].append(img[..., j] >= np.float32(thr[k]))
        return out
    for k in names:
        sel = _check_selection(scene, selections[k], f"selection {k!r}").astype(bool)
        r = make_renderer(segmented_grid(scene, sel), device=device)
        for cam in cameras:
            out[k].append(r.render(cam, config.scale).alpha >= np.float32(config.nerf_threshold))
    return out


def ground_truth_masks(
    scene: Scene,
    cameras: Sequence[Camera],
    labels: np.ndarray,
    *,
    config: EvalConfig = EvalConfig(),
    renderer=None,
    device=None,
) -> list[np.ndarray]:
    """Ground-truth ``[H,W]`` masks: rendered labels ``≥ gt_threshold`` (surfels) or the
    accumulated opacity of the label grid's density ``≥ nerf_threshold`` (grids)."""
    if isinstance(scene, SurfelScene):
        return predicted_masks(
            scene,
            cameras,
            {"gt": labels},
            config=config,
            renderer=renderer,
            device=device,
            thresholds={"gt": config.gt_threshold},
        )["gt"]
    return predicted_masks(scene, cameras, {"gt": labels}, config=config, device=device)["gt"]


class ViewEvaluator:
    """Scores selections of one scene at fixed test cameras against fixed labels.

    The ground-truth masks are rendered once, in the constructor.

    Args:
        scene: a :class:`SurfelScene` or :class:`DensityGrid`.
        cameras: the test cameras (full resolution; ``config.scale`` applies).
        labels: ground truth, ``[N]`` bool per surfel or ``[D,H,W]`` bool per voxel.
        renderer: a renderer of ``scene`` to reuse (surfels; else one is made).
    """

    def __init__(
        self,
        scene: Scene,
        cameras: Sequence[Camera],
        labels: np.ndarray,
        *,
        config: EvalConfig = EvalConfig(),
        renderer=None,
        device=None,
    ) -> None:
        self.scene = scene
        self.cameras = list(cameras)
        if not self.cameras:
            raise ValueError("ViewEvaluator: no test cameras")
        self.labels = _check_selection(scene, labels, "labels").astype(bool)
        self.config = config
        self.device = device
        self.renderer = (
            renderer
            if (renderer is not None or not isinstance(scene, SurfelScene))
            else make_renderer(scene, device=device)
        )
        self.gt_masks = ground_truth_masks(
            scene, self.cameras, self.labels, config=config, renderer=self.renderer, device=device
        )

    def masks(self, selections: Mapping[str, np.ndarray]) -> dict[str, list[np.ndarray]]:
        """Predicted masks of each selection at each test camera."""
        return predicted_masks(
            self.scene,
            self.cameras,
            selections,
            config=self.config,
            renderer=self.renderer,
            device=self.device,
        )

    def score(self, selections: Mapping[str, np.ndarray]) -> dict[str, SceneScores]:
        """:class:`SceneScores` of each named selection (one render pass per camera for
        all surfel selections together)."""
        preds = self.masks(selections)
        out = {}
        for k, masks in preds.items():
            views = [
                mask_scores(p, g, c.name) for p, g, c in zip(masks, self.gt_masks, self.cameras)
            ]
            mean = lambda a: float(np.mean([getattr(v, a) for v in views]))  # noqa: E731, B023
            inter = sum(v.intersection for v in views)
            union = sum(v.union for v in views)
            out[k] = SceneScores(
                mean("iou"),
                mean("accuracy"),
                mean("precision"),
                mean("recall"),
                inter / union if union else 1.0,
                views,
                surfel_scores(selections[k], self.labels),
            )
        return out


def evaluate_selection(
    scene: Scene,
    cameras: Sequence[Camera],
    selection: np.ndarray,
    labels: np.ndarray,
    *,
    config: EvalConfig = EvalConfig(),
    renderer=None,
    device=None,
) -> SceneScores:
    """One-shot form of :class:`ViewEvaluator` for a single selection."""
    ev = ViewEvaluator(scene, cameras, labels, config=config, renderer=renderer, device=device)
    return ev.score({"selection": selection})["selection"]

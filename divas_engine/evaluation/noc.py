"""Number of clicks (NoC): the interactive-segmentation metric of the field, on a session.

A simulated user (RITM / SimpleClick style, evaluation only) looks at the session's
anchor renders: truth ``T_a`` (ground truth rendered ``≥ gt_threshold``), prediction
``P_a`` (the selection's indicator ``≥ pred_threshold``) and don't-care pixels. It clicks
the deepest error pixel (Euclidean distance transform of ``FN_a`` or ``FP_a``) over every
anchor — positive on a false negative, negative on a false positive — through the
public session API (:func:`next_click`, :func:`_apply`). After each click the IoU is the
mean over held-out test cameras (:class:`TestViews`); NoC@τ is the first click with
IoU ≥ τ, ``max_clicks`` when none is (a failure, NoF). Ties, thresholds and the rest of
the protocol: docs/noc.md.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..camera import Camera
from ..errors import DivasInputError
from ..scene import SurfelScene

__all__ = [
    "NocConfig",
    "NocClick",
    "NocRun",
    "error_depth",
    "next_click",
    "number_of_clicks",
    "thresholds_for",
    "ignoring_iou",
    "TestViews",
    "run_noc",
]


@dataclass(frozen=True)
class NocConfig:
    """The simulated user's budget and the NoC thresholds.

    Attributes:
        max_clicks: clicks per run (10).
        thresholds: IoU levels of NoC (0.85, 0.90).
        pred_threshold, gt_threshold: the mask thresholds; None: 0.5 each
            (:func:`thresholds_for`).
        eval_scale: the test cameras render at this fraction of their size (1).
    """

    max_clicks: int = 10
    thresholds: tuple[float, ...] = (0.85, 0.90)
    pred_threshold: float | None = None
    gt_threshold: float | None = None
    eval_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.max_clicks < 1:
            raise ValueError(f"NocConfig.max_clicks must be ≥ 1, got {self.max_clicks}")
        if not self.eval_scale > 0:
            raise ValueError(f"NocConfig.eval_scale must be positive, got {self.eval_scale}")


@dataclass(frozen=True)
class NocClick:
    """One click of the simulated user: ``anchor`` index, ``xy`` (pixel centre of the
    anchor render), ``positive``, and the error's ``depth`` (distance-transform value,
    pixels)."""

    anchor: int
    xy: tuple[float, float]
    positive: bool
    depth: float


@dataclass
class NocRun:
    """One run: the clicks, the IoU after each, and what each click did.

    Attributes:
        ious: IoU after click k = 1 … (``ious[k - 1]``).
        clicks: the :class:`NocClick` of each (None: no error left, nothing clicked).
        outcomes: per click, what the session did (``fused``, ``rejected: …``,
            ``negative``, ``no surface``, ``none``).
        seconds: wall time of the run.
    """

    ious: list[float] = field(default_factory=list)
    clicks: list[NocClick | None] = field(default_factory=list)
    outcomes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def noc(self, threshold: float, max_clicks: int | None = None) -> int:
        return number_of_clicks(self.ious, threshold, max_clicks)

    def as_dict(self, thresholds: Sequence[float] = (0.85, 0.90)) -> dict:
        return {
            "ious": list(self.ious),
            "clicks": [
                None if c is None else [c.anchor, list(c.xy), c.positive, c.depth]
                for c in self.clicks
            ],
            "outcomes": list(self.outcomes),
            "noc": {f"{t:g}": self.noc(t) for t in thresholds},
            "failed": {f"{t:g}": not any(i >= t for i in self.ious) for t in thresholds},
            "seconds": self.seconds,
        }


def error_depth(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance of each pixel of ``mask`` to the nearest pixel outside it,
    the image border counting as outside (0 off the mask)."""
    m = np.asarray(mask, bool)
    return ndimage.distance_transform_edt(np.pad(m, 1))[1:-1, 1:-1]


def next_click(
    truths: Sequence[np.ndarray],
    preds: Sequence[np.ndarray],
    ignores: Sequence[np.ndarray | None] | None = None,
) -> NocClick | None:
    """The simulated user's next click over the anchors (docs/noc.md, step 4): the deepest
    false-negative or false-positive pixel; None when no anchor shows an error."""
    best: tuple | None = None
    for a, (t, p) in enumerate(zip(truths, preds)):
        t, p = np.asarray(t, bool), np.asarray(p, bool)
        ign = None if ignores is None else ignores[a]
        keep = np.ones_like(t) if ign is None else ~np.asarray(ign, bool)
        for positive, err in ((True, t & ~p & keep), (False, p & ~t & keep)):
            if not err.any():
                continue
            d = error_depth(err)
            i = int(np.argmax(d))  # the first maximum in row-major order
            # sort key: deeper, then positive, then lower anchor (then the pixel, by argmax)
            key = (-float(d.flat[i]), 0 if positive else 1, a)
            if best is None or key < best[0]:
                y, x = divmod(i, t.shape[1])
                best = (key, NocClick(a, (x + 0.5, y + 0.5), positive, float(d.flat[i])))
    return None if best is None else best[1]


def number_of_clicks(ious: Sequence[float], threshold: float, max_clicks: int | None = None) -> int:
    """The first k (1-based) with ``ious[k - 1] ≥ threshold``; ``max_clicks`` (default
    ``len(ious)``) when none is."""
    for k, v in enumerate(ious, start=1):
        if v >= threshold:
            return k
    return len(ious) if max_clicks is None else int(max_clicks)


def thresholds_for(scene, config: NocConfig = NocConfig()) -> tuple[float, float]:
    """``(pred_threshold, gt_threshold)`` of a scene: the config's where set, else 0.5 /
    0.5 on every kind — the selection's render and the truth's at the same level, so a
    perfect selection scores 1.0 (the field's NoC; on 2DGS NOTES' 0.1 / 0.5 caps a
    perfect thin wheel at 0.76: ``pred_threshold=0.1`` gives that protocol)."""
    pred = 0.5 if config.pred_threshold is None else float(config.pred_threshold)
    gt = config.gt_threshold if config.gt_threshold is not None else 0.5
    return pred, float(gt)


def ignoring_iou(pred: np.ndarray, truth: np.ndarray, ignore: np.ndarray | None = None) -> float:
    """``|P ∧ T| / |P ∨ T|`` over the pixels outside ``ignore`` (1 when both are empty)."""
    p, t = np.asarray(pred, bool), np.asarray(truth, bool)
    if ignore is not None:
        keep = ~np.asarray(ignore, bool)
        p, t = p & keep, t & keep
    union = int(np.count_nonzero(p | t))
    return int(np.count_nonzero(p & t)) / union if union else 1.0


class TestViews:
    """The truth (and don't-care) masks at a set of cameras, rendered once; scores any
    selection there (:func:`ignoring_iou`, mean over the cameras) or gives its masks.

    Args:
        renderer: the scene's renderer (``render_values``).
        cameras: the cameras (held-out test cameras, or the anchors' working cameras).
        labels: bool per primitive; dont_care: bool per primitive or None.
        pred_threshold, gt_threshold: :func:`thresholds_for`.
        scale: render at this fraction of each camera's size.
    """

    def __init__(
        self,
        renderer,
        cameras: Sequence[Camera],
        labels: np.ndarray,
        dont_care: np.ndarray | None,
        pred_threshold: float,
        gt_threshold: float,
        scale: float = 1.0,
    ) -> None:
        self.renderer, self.cameras, self.scale = renderer, list(cameras), float(scale)
        self.pred_threshold = np.float32(pred_threshold)
        lab = np.asarray(labels, np.float32)
        vals = lab[:, None] if dont_care is None else np.stack([lab, dont_care], 1)
        vals = np.ascontiguousarray(vals, np.float32)
        self.truths, self.ignores = [], []
        for cam in self.cameras:
            r = np.asarray(renderer.render_values(cam, vals, self.scale), np.float32)
            r = r.reshape(r.shape[0], r.shape[1], -1)
            self.truths.append(r[..., 0] >= np.float32(gt_threshold))
            self.ignores.append(None if dont_care is None else r[..., 1] >= np.float32(0.5))

    def predictions(self, selection: np.ndarray) -> list[np.ndarray]:
        """The selection's masks at the cameras (indicator render ``≥ pred_threshold``)."""
        sel = np.asarray(selection, np.float32)
        out = []
        for cam, t in zip(self.cameras, self.truths):
            if not sel.any():
                out.append(np.zeros_like(t))
                continue
            r = np.asarray(self.renderer.render_values(cam, sel, self.scale), np.float32)
            out.append(r.reshape(t.shape) >= self.pred_threshold)
        return out

    def iou(self, selection: np.ndarray) -> float:
        """Mean IoU of the selection over the cameras."""
        preds = self.predictions(selection)
        ious = [ignoring_iou(p, t, i) for p, t, i in zip(preds, self.truths, self.ignores)]
        return float(np.mean(ious)) if ious else 1.0


def _apply(session, click: NocClick) -> str:
    """One click through the public session API (docs/noc.md, step 5); what it did."""
    try:
        res = session.click(click.anchor, click.xy, click.positive)
    except DivasInputError:
        return "no surface"
    if not click.positive or not hasattr(res, "camera"):
        return "negative" if not click.positive else "recorded"
    session.prompt(res)
    session.accept(res)
    session.sync()
    status = str(res.status)
    return status if res.reason is None else f"{status}: {res.reason}"


def run_noc(
    scene: SurfelScene,
    cameras: Sequence[Camera],
    labels: np.ndarray,
    test_cameras: Sequence[Camera],
    *,
    segmenter,
    anchors: Sequence | None = None,
    dont_care: np.ndarray | None = None,
    config: NocConfig = NocConfig(),
    session_config=None,
    device=None,
    renderer=None,
    log=None,
) -> NocRun:
    """One NoC run (docs/noc.md) on a surfel scene.

    Args:
        cameras: training cameras (the anchor plan and capture type); may be empty.
        labels: bool per primitive, the target (also the oracle's truth).
        test_cameras: the held-out cameras the IoU is measured at.
        anchors: the session's anchors (``Session.open``'s ``anchors``); None: its plan.
        dont_care: bool per primitive left out of errors and IoU, or None.
    """
    from ..session import Session, SessionConfig

    if not isinstance(scene, SurfelScene):
        raise TypeError("run_noc: surfel scenes only (2DGS / 3DGS)")
    t0 = time.perf_counter()
    lab = np.asarray(labels, bool)
    dc = None if dont_care is None else np.asarray(dont_care, bool)
    pred_t, gt_t = thresholds_for(scene, config)
    s = Session.open(
        scene,
        list(cameras),
        session_config or SessionConfig(),
        segmenter,
        device,
        anchors=anchors,
        gt_values=lab.astype(np.float32),
        render_anchors=False,
        renderer=renderer,
    )
    try:
        ren = s.renderer
        tests = TestViews(ren, test_cameras, lab, dc, pred_t, gt_t, config.eval_scale)
        seen = TestViews(ren, [a.camera for a in s.anchors], lab, dc, pred_t, gt_t)
        run = NocRun()
        for k in range(config.max_clicks):
            click = next_click(seen.truths, seen.predictions(s.selection), seen.ignores)
            outcome = "none" if click is None else _apply(s, click)
            run.clicks.append(click)
            run.outcomes.append(outcome)
            run.ious.append(tests.iou(s.selection))
            if log is not None:
                log(f"  click {k + 1}: {click} -> {outcome}; IoU {run.ious[-1]:.3f}")
        run.seconds = time.perf_counter() - t0
        return run
    finally:
        s.close()

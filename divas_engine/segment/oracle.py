"""SAM-like oracle for evaluation only — never a default (NOTES "Evaluation").

It turns the ground-truth label coverage ``L`` of a view into SAM-like output: area-downsample
to SAM's low-res grid, seeded structured errors there (dropout of thin parts, boundary bleed
within a depth gate, one false-positive disk), logits ``logit_scale · (L − 0.5)``, bilinear
upsample and sigmoid; the same mask in all 3 channels. With ``respond_to_prompts`` a click on
an error takes that error part back, as SAM answers a correction. One generator per view from
``(seed, crc32(view key))``, one child stream per error type; :attr:`OracleSegmenter.last_report`
records every error drawn. The steps and their parameters: docs/design-notes.md.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Hashable
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
from scipy import ndimage

from .base import Segmenter, SegResult, _fingerprint
from .context import ViewContext
from .sam_common import sigmoid

__all__ = ["OracleConfig", "OracleSegmenter"]


@dataclass(frozen=True)
class OracleConfig:
    """Every knob of the SAM-like oracle (defaults: NOTES "Evaluation")."""

    low_res: int = 256
    logit_scale: float = 8.0
    bleed_prob: float = 1.0
    bleed_min_px: float = 0.0
    bleed_max_px: float = 4.0
    bleed_depth_rel: float = 0.10
    thin_px: int = 3
    thin_min_area: int = 2
    dropout_prob: float = 0.3
    fp_prob: float = 0.2
    fp_radius_px: tuple[float, float] = (3.0, 8.0)
    score_nonempty: float = 0.9
    score_empty: float = 0.2
    respond_to_prompts: bool = True
    seed: int = 0


def _area_resize(a: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    if a.shape == hw:
        return a.astype(np.float32)
    return cv2.resize(a.astype(np.float32), (hw[1], hw[0]), interpolation=cv2.INTER_AREA)


class OracleSegmenter(Segmenter):
    """Ground truth with SAM-like structured errors (module docstring).

    Args:
        gt_render: ``view_id -> [H,W]`` label coverage in [0,1]; used when
            ``set_image`` gets no ``gt``. Without it, a session hands the oracle each
            view's ground truth (:attr:`~.context.ViewContext.truth`).
        config: :class:`OracleConfig`.
    """

    name = "oracle"

    def __init__(
        self,
        gt_render: Callable[[Hashable], np.ndarray] | None = None,
        config: OracleConfig | None = None,
    ):
        super().__init__(cache_size=0)
        self.gt_render = gt_render
        self.config = config or OracleConfig()
        self.last_report: dict[str, Any] = {}
        self._gt: np.ndarray | None = None

    def set_image(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None = None,
        *,
        view_id: Hashable | None = None,
        gt: np.ndarray | None = None,
    ) -> None:
        """Like :meth:`Segmenter.set_image`, plus the view's ground-truth coverage ``gt``."""
        if gt is None:
            if self.gt_render is None or view_id is None:
                raise ValueError("oracle: pass gt=, or construct with gt_render and pass view_id")
            gt = self.gt_render(view_id)
        with self._lock:
            self._gt = np.asarray(gt, dtype=np.float32)
            super().set_image(rgb, depth, view_id=view_id)

    def segment(
        self,
        rgb: np.ndarray,
        depth: np.ndarray | None,
        points: np.ndarray,
        labels: np.ndarray,
        *,
        view_id: Hashable | None = None,
        gt: np.ndarray | None = None,
    ) -> SegResult:
        """``set_image`` (with optional ``gt``) + ``predict``, atomically."""
        with self._lock:
            self.set_image(rgb, depth, view_id=view_id, gt=gt)
            masks, scores = self.predict(points, labels)
        return SegResult(masks, scores)

    @property
    def wants_ground_truth(self) -> bool:
        return self.gt_render is None

    def segment_view(self, view: ViewContext, points: np.ndarray, labels: np.ndarray) -> SegResult:
        """:meth:`segment` of the view's image with its ground truth (the context's, else
        ``gt_render``'s)."""
        return self.segment(view.rgb, view.depth, points, labels, view_id=view.id, gt=view.truth)

    def report(self) -> dict[str, Any]:
        """Config (incl. seed) and the errors drawn for the last view."""
        return {"config": asdict(self.config), **self.last_report}

    # -- hooks --------------------------------------------------------------------
    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        cfg = self.config
        gt = self._gt
        h, w = rgb.shape[:2]
        if gt is None or gt.shape != (h, w):
            raise ValueError(
                f"oracle: gt must be [H,W]=({h}, {w}), got {None if gt is None else gt.shape}"
            )
        key = repr(view_id) if view_id is not None else _fingerprint(gt, depth)
        ss = np.random.SeedSequence([cfg.seed, zlib.crc32(key.encode())])
        rng_drop, rng_bleed, rng_fp = (np.random.default_rng(s) for s in ss.spawn(3))
        f = min(1.0, cfg.low_res / max(h, w))
        hw = (max(1, int(round(h * f))), max(1, int(round(w * f))))
        lo = np.clip(_area_resize(np.nan_to_num(gt), hw), 0.0, 1.0)
        truth = lo.copy()
        dlo = None
        if depth is not None:
            valid = (depth > 0).astype(np.float32)
            den = _area_resize(valid, hw)
            dlo = np.where(den >= 0.5, _area_resize(depth * valid, hw) / np.maximum(den, 1e-6), 0.0)
        obj = lo >= 0.5
        rep: dict[str, Any] = {"view_id": view_id, "seed": cfg.seed, "grid": hw}
        rep["dropped_parts"], rep["thin_parts"] = self._dropout(lo, obj, rng_drop)
        obj = lo >= 0.5
        rep["bleed_px"], rep["bleed_pixels"] = self._bleed(lo, obj, dlo, rng_bleed)
        rep["fp_blob"] = self._false_positive(lo, obj, rng_fp)
        self.last_report = rep
        return _OracleState(lo, truth, (h, w))

    def _dropout(
        self, lo: np.ndarray, obj: np.ndarray, rng: np.random.Generator
    ) -> tuple[int, int]:
        cfg = self.config
        k = cv2.getStructuringElement(cv2.MORPH_CROSS, (cfg.thin_px, cfg.thin_px))
        thin = obj & ~cv2.morphologyEx(obj.astype(np.uint8), cv2.MORPH_OPEN, k).astype(bool)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(thin.astype(np.uint8), connectivity=8)
        parts = [i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= cfg.thin_min_area]
        draws = rng.random(len(parts))
        drop = [p for p, u in zip(parts, draws) if u < cfg.dropout_prob]
        if drop:
            lo[np.isin(lab, drop)] = 0.0
        return len(drop), len(parts)

    def _bleed(
        self, lo: np.ndarray, obj: np.ndarray, dlo: np.ndarray | None, rng: np.random.Generator
    ) -> tuple[float, int]:
        cfg = self.config
        u, width = rng.random(), rng.uniform(cfg.bleed_min_px, cfg.bleed_max_px)
        if not (u < cfg.bleed_prob) or not obj.any() or obj.all():
            return 0.0, 0
        dist, (iy, ix) = ndimage.distance_transform_edt(~obj, return_indices=True)
        region = ~obj & (dist <= width)
        if dlo is not None:
            d_obj = dlo[iy, ix]
            region &= (dlo > 0) & (d_obj > 0) & (np.abs(dlo - d_obj) <= cfg.bleed_depth_rel * d_obj)
        lo[region] = 1.0
        return float(width), int(region.sum())

    def _false_positive(
        self, lo: np.ndarray, obj: np.ndarray, rng: np.random.Generator
    ) -> dict[str, float] | None:
        cfg = self.config
        u, r, pick = rng.random(), rng.uniform(*cfg.fp_radius_px), rng.random()
        if not u < cfg.fp_prob:
            return None
        dist = ndimage.distance_transform_edt(~obj) if obj.any() else np.full(obj.shape, np.inf)
        cand = np.flatnonzero(dist.reshape(-1) > r + 2)
        if cand.size == 0:
            return None
        cy, cx = divmod(int(cand[min(int(pick * cand.size), cand.size - 1)]), obj.shape[1])
        blob = np.zeros(obj.shape, np.uint8)
        cv2.circle(blob, (cx, cy), int(round(r)), 1, thickness=-1)
        lo[blob.astype(bool)] = 1.0
        return {"x": cx + 0.5, "y": cy + 0.5, "radius": float(r)}

    def _predict(
        self, state: _OracleState, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        lo = state.grid
        if cfg.respond_to_prompts and len(points):
            lo = lo.copy()
            answered = _answer_prompts(lo, state.truth, state.shape, points, labels)
            self.last_report = {**self.last_report, "prompt_parts": answered}
        h, w = state.shape
        logits = np.float32(cfg.logit_scale) * (lo - np.float32(0.5))
        if lo.shape != (h, w):
            logits = cv2.resize(logits, (w, h), interpolation=cv2.INTER_LINEAR)
        prob = sigmoid(logits)
        score = cfg.score_nonempty if bool((prob >= 0.5).any()) else cfg.score_empty
        return np.repeat(prob[None], 3, axis=0), np.full(3, score, np.float32)


@dataclass(frozen=True, eq=False)
class _OracleState:
    """A view's low-res grid with its errors, the clean truth grid and the image size."""

    grid: np.ndarray
    truth: np.ndarray
    shape: tuple[int, int]


def _answer_prompts(
    lo: np.ndarray, truth: np.ndarray, shape: tuple[int, int], points, labels
) -> list[tuple[int, int]]:
    """Undo, in place on ``lo``, the error parts the prompts point at (module docstring);
    ``(label, cells changed)`` per point that changed something."""
    gh, gw = lo.shape
    h, w = shape
    out = []
    for (x, y), lab in zip(np.asarray(points, np.float64), np.asarray(labels)):
        positive = int(lab) == 1
        # a negative point takes back what the errors added, a positive one what they dropped
        err = (truth < 0.5) & (lo >= 0.5) if not positive else (truth >= 0.5) & (lo < 0.5)
        r = min(max(int(np.floor(y * gh / h)), 0), gh - 1)
        c = min(max(int(np.floor(x * gw / w)), 0), gw - 1)
        if not err[r, c]:
            near = np.argwhere(err[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2])
            if not len(near):
                continue
            d = (near[:, 0] + max(r - 1, 0) - r) ** 2 + (near[:, 1] + max(c - 1, 0) - c) ** 2
            r, c = near[int(np.argmin(d))] + (max(r - 1, 0), max(c - 1, 0))
        _, parts = cv2.connectedComponents(err.astype(np.uint8), connectivity=8)
        part = parts == parts[r, c]
        lo[part] = truth[part]
        out.append((int(positive), int(part.sum())))
    return out

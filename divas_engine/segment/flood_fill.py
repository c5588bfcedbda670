"""Baseline segmenter: colour flood fill from the clicks (``cv2.floodFill``), depth ignored.

Exists to show what the depth channel of :class:`.classic.ClassicSegmenter`
buys; never a default. Granularity ``k`` floods with colour tolerance
``tolerances[k]`` (grey levels per RGB channel, relative to the seed pixel when
``fixed_range`` else to the neighbour) from every positive click; the floods
from negative clicks are removed. Score: 1 for a mask covering some but less
than ``max_area_frac`` of the view, else 0.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .base import Segmenter, pixel_index

__all__ = ["FloodFillConfig", "FloodFillSegmenter"]


@dataclass(frozen=True)
class FloodFillConfig:
    """Attributes: tolerances per granularity; ``fixed_range`` (compare to the seed);
    ``connectivity`` 4 or 8; ``max_area_frac`` for the score."""

    tolerances: tuple[float, float, float] = (10.0, 20.0, 40.0)
    fixed_range: bool = True
    connectivity: int = 4
    max_area_frac: float = 0.95


class FloodFillSegmenter(Segmenter):
    """Colour flood fill from the clicks (module docstring)."""

    name = "flood-fill"

    def __init__(self, config: FloodFillConfig | None = None, cache_size: int = 8):
        super().__init__(cache_size)
        self.config = config or FloodFillConfig()

    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        return np.ascontiguousarray(np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8))

    def _flood(self, img: np.ndarray, pts: np.ndarray, tol: float) -> np.ndarray:
        h, w = img.shape[:2]
        acc = np.zeros((h + 2, w + 2), np.uint8)
        flags = self.config.connectivity | cv2.FLOODFILL_MASK_ONLY | (1 << 8)
        if self.config.fixed_range:
            flags |= cv2.FLOODFILL_FIXED_RANGE
        rows, cols = pixel_index(pts, (h, w))
        for r, c in zip(rows.tolist(), cols.tolist()):
            m = np.zeros((h + 2, w + 2), np.uint8)
            cv2.floodFill(img, m, (int(c), int(r)), 0, (tol,) * 3, (tol,) * 3, flags)
            acc |= m
        return acc[1:-1, 1:-1].astype(bool)

    def _predict(
        self, img: Any, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        h, w = img.shape[:2]
        masks = np.zeros((3, h, w), np.float32)
        scores = np.zeros(3, np.float32)
        pos, neg = points[labels == 1], points[labels == 0]
        if len(pos) == 0:
            return masks, scores
        for k, tol in enumerate(self.config.tolerances):
            m = self._flood(img, pos, tol)
            if len(neg):
                m &= ~self._flood(img, neg, tol)
            masks[k] = m
            scores[k] = 1.0 if 0 < m.mean() < self.config.max_area_frac else 0.0
        return masks, scores

"""Segmenter stubs for tests that need a mask source with a fixed answer."""

from __future__ import annotations

import numpy as np

from divas_engine.segment import Segmenter


class ConstantSegmenter(Segmenter):
    """A confident segmenter (score 0.9 on every channel) whose masks are ``value``
    everywhere: 0 = sure of an empty mask, 1 = a preview spilled over the whole view."""

    name = "constant"

    def __init__(self, value: float) -> None:
        super().__init__()
        self.value = float(value)

    def _encode(self, rgb, depth, view_id):
        return rgb.shape[:2]

    def _predict(self, state, points, labels):
        return np.full((3, *state), self.value, np.float32), np.full(3, 0.9, np.float32)

"""The session's background warm-up also builds the segmenter's per-scene state (graph3d's
primitives, seconds of a large scene's first click otherwise), after the fusion state
and without making readers of the fusion state wait for it."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from divas_engine.segment.graph3d import Graph3DSegmenter
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene

from .stub_segmenters import ConstantSegmenter


@pytest.fixture(scope="module")
def plant():
    return generate_scene("plant", None, size=20_000, seed=0)


def _open(sc, segmenter):
    return Session.open(
        sc.scene, sc.cameras, SessionConfig(render_scale=0.5), segmenter, "cpu",
        render_anchors=True,
    )  # fmt: skip


def _wait_warm(s) -> None:
    assert s.backend._warm is not None and s.wait_warm_up(60)


def test_graph3d_primitives_are_built_before_the_first_prompt(plant):
    seg = Graph3DSegmenter()
    s = _open(plant, seg)
    _wait_warm(s)
    assert seg.prims is not None  # built by the warm-up, no prompt made yet
    built = seg.prims
    a = s.anchors[0]
    ys, xs = np.nonzero(a.buffers.alpha > 0.9)
    v = s.click(a.index, (xs[len(xs) // 2] + 0.5, ys[len(xs) // 2] + 0.5))
    warm = s.prompt(v).mask
    assert warm is not None and warm.any()
    assert seg.prims is built  # the prompt used the warm-up's build
    s.close()
    # the same prompt on a session whose segmenter builds on first use
    cold_seg = Graph3DSegmenter()
    cold_seg.warm_up = lambda: None  # no warm-up: built by the first prompt
    cold = _open(plant, cold_seg)
    cold.backend._warm_done.wait(60)
    v2 = cold.click(cold.anchors[0].index, (xs[len(xs) // 2] + 0.5, ys[len(xs) // 2] + 0.5))
    assert cold_seg.prims is None  # no warm-up: built by the prompt below
    assert np.array_equal(cold.prompt(v2).mask, warm)
    cold.close()


class _SlowWarmUp(ConstantSegmenter):
    """A segmenter whose warm-up blocks until released."""

    def __init__(self) -> None:
        super().__init__(1.0)
        self.started, self.release, self.done = threading.Event(), threading.Event(), False

    def warm_up(self) -> None:
        self.started.set()
        self.release.wait(60)
        self.done = True


def test_fusion_state_readers_do_not_wait_for_the_segmenter_warm_up(plant):
    seg = _SlowWarmUp()
    s = _open(plant, seg)
    assert seg.started.wait(60)  # the fusion state is built, the segmenter's turn began
    _ = s.grid  # returns while the segmenter's warm-up is still blocked
    assert s.warmed_up and not seg.done and not s.wait_warm_up(0.01)
    seg.release.set()
    _wait_warm(s)
    assert seg.done
    s.close()

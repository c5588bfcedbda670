"""Two centroid planners compared click for click (the renders behind their probes may
differ in how they are computed, never in what they give)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np


def same_centroid_views(scene_case, render, planner_a, planner_b) -> Iterator[tuple]:
    """For two clicks on each of the first six cameras of a generated ``scene_case``
    (anchor render ``render(cam, scale=0.25)``), assert that both planners give the same
    centroid camera, strategy and probe log, and yield the two centroid views."""
    for cam in scene_case.cameras[:6]:
        buf = render(cam, scale=0.25)
        anchor = buf.camera
        ys, xs = np.nonzero((buf.alpha > 0.9) & (buf.D_med > 0))
        for k in np.random.default_rng(0).choice(len(xs), 2, replace=False):
            xy = (xs[k] + 0.5, ys[k] + 0.5)
            a = planner_a.centroid_view(anchor, xy, buf)
            b = planner_b.centroid_view(anchor, xy, buf)
            assert np.array_equal(a.camera.w2c, b.camera.w2c) and a.d_cam == b.d_cam
            assert a.strategy == b.strategy and len(a.probes) == len(b.probes)
            for p, q in zip(a.probes, b.probes):
                p_, q_ = list(p.__dict__.values()), list(q.__dict__.values())
                assert np.array_equal(p_, q_, equal_nan=True)
            yield a, b

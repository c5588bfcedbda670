"""graph3d's masks of a click's default prompt rendered in the background while the
view renders (``Graph3DSegmenter.prefetch_view``): the centroid planner hands
the view's camera over before rendering it, the prompt takes the masks the background
thread made, and they equal those of a session without the prefetch bit for bit. The
sparse value render it uses gives the same image on one launch thread and beside
another render."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.views import GsCentroidPlanner
from divas_engine.views.config import ViewConfig

from .test_graph3d_prefetch import _on_object, _open, _same, plant  # noqa: F401


def _masks_loop(sc, prefetch: bool, masks: bool = True):
    s, seg = _open(sc, prefetch)
    seg.prefetch_masks = masks
    where: list[str] = []
    real = seg.render_masks

    def spy(*a, **k):
        where.append(threading.current_thread().name)
        return real(*a, **k)

    seg.render_masks = spy
    v = s.click(*_on_object(s, sc, 0))
    prev = s.prompt(v)
    out = (prev, seg.last_cut, where, seg.masks.prefetch_hits)
    s.close()
    return out


def test_the_prompt_takes_the_masks_rendered_ahead_and_they_are_unchanged(plant):  # noqa: F811
    on = _masks_loop(plant, True)
    off = _masks_loop(plant, False)
    cuts_only = _masks_loop(plant, True, masks=False)
    assert on[2] == ["divas-graph3d-prefetch"] and on[3] == 1  # rendered once, ahead
    assert off[2] == ["MainThread"] and cuts_only[2] == ["MainThread"]
    assert off[3] == 0 and cuts_only[3] == 0
    _same(on, off)
    _same(cuts_only, off)


def test_closing_the_session_waits_for_the_masks_a_click_started(plant):  # noqa: F811
    s, seg = _open(plant, True)
    real = seg.render_masks

    def slow(*a, **k):
        time.sleep(1.0)
        return real(*a, **k)

    seg.render_masks = slow
    s.click(*_on_object(s, plant, 0))
    s.close()
    alive = [t for t in threading.enumerate() if t.name == "divas-graph3d-prefetch"]
    assert not alive and len(seg.masks) == 1


def test_the_planner_hands_over_the_camera_it_renders(plant):  # noqa: F811
    """Before the first radius's full render, and the final camera when that radius is
    rejected (τ_O = 0 rejects every probe: the smallest radius is taken)."""
    s, _ = _open(plant, False)
    a, xy = _on_object(s, plant, 0)
    anchor = s.anchor(a)
    buf = s.render(anchor)
    for cfg, calls in ((ViewConfig(), 1), (ViewConfig(tau_o=0.0), 2)):
        seen = []
        planner = GsCentroidPlanner(s.scene, s.renderer, cfg)
        cv = planner.centroid_view(anchor.camera, xy, buf, on_camera=seen.append)
        assert len(seen) == calls
        last = seen[-1]
        assert np.array_equal(last.c2w, cv.camera.c2w) and last.fx == cv.camera.fx
        if calls == 2:
            assert not np.array_equal(seen[0].c2w, cv.camera.c2w)  # the rejected one
    s.close()


@pytest.fixture(scope="module")
def sparse_case(plant):  # noqa: F811
    r = SurfelRenderer(plant.scene)
    r.scratch_sparse = True  # (the add-on's setting at 3M: buffers kept between calls)
    cams = [c.scaled(0.25) for c in plant.cameras[:3]]
    rng = np.random.default_rng(0)
    rows = np.unique(rng.choice(len(plant.scene), len(plant.scene) // 5, replace=False))
    vals = rng.random((len(rows), 3), dtype=np.float32)
    return r, cams, rows, vals


def test_a_sparse_render_on_one_thread_is_the_same_image(sparse_case):
    r, cams, rows, vals = sparse_case
    assert r.sparse_renders_concurrent  # CPU
    for cam in cams:
        ref = r.render_values_sparse(cam, rows, vals)
        assert ref.any()
        assert np.array_equal(r.render_values_sparse(cam, rows, vals, threads=1), ref)


def test_sparse_renders_beside_other_renders_give_the_same_images(sparse_case):
    r, cams, rows, vals = sparse_case
    ref_sparse = [r.render_values_sparse(c, rows, vals) for c in cams]
    r.clear_cache()
    ref_rgb = [r.render(c).rgb.copy() for c in cams]
    r.clear_cache()
    got: list[np.ndarray] = []
    errors: list[BaseException] = []

    def background():
        try:
            for _ in range(3):
                got.extend(r.render_values_sparse(c, rows, vals, threads=1) for c in cams)
        except BaseException as e:  # noqa: BLE001 - reported below
            errors.append(e)

    t = threading.Thread(target=background)
    t.start()
    rgb = []
    while t.is_alive() or not rgb:
        rgb.extend(r.render(c).rgb.copy() for c in cams)
        r.clear_cache()  # waits for a sparse render holding the scratch buffers
    t.join()
    assert not errors
    assert len(got) == 3 * len(cams)
    for k, img in enumerate(got):
        assert np.array_equal(img, ref_sparse[k % len(cams)])
    for k, img in enumerate(rgb):
        assert np.array_equal(img, ref_rgb[k % len(cams)])

"""A click's pixel rule (an option, off by default): its patch takes the primitives that
draw the pixel, nearest the click's point first, until a positive patch holds half of the
pixel's blending weight and a negative one leaves less than half
(:func:`divas_engine.session.corrections.pixel_patch`).

The rule is checked on hand-made weights, then in a session on the synthetic vase
(perfect masks of one view fused): at a missed pixel of a test camera where the
ellipsoid patch alone draws less than half, the selection's weight at the pixel — summed
from a full-image contribution pass, not the one-pixel pass the session uses — reaches
0.5 after the click, and stays below it with the rule off. A click whose view is refused
at accept still holds its patch (it used to change nothing), with or without the rule.
"""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.kinds import ViewStatus
from divas_engine.session import CorrectionConfig, Session
from divas_engine.session.corrections import patch_radius, pixel_patch
from divas_engine.views.centroid_common import click_point

from .stub_segmenters import ConstantSegmenter
from .test_corrections import _accept_clicks, _open, _perfect, _xy, vase  # noqa: F401


def test_pixel_patch_adds_nearest_the_click_until_half():
    rows = np.array([10, 11, 12, 13, 14])
    w = np.array([0.30, 0.14, 0.10, 0.03, 0.20])
    d = np.array([0.0, 0.69, 0.16, 0.14, 1.94])  # from the click: 11, 14 are occluders
    # the patch (row 10) draws 0.30; 13 (0.14 away) then 12 (0.16) bring it to 0.43,
    # 11 (0.69 away) to 0.57 >= 0.5; 14 (1.94 away) is not needed
    assert pixel_patch(np.array([10]), rows, w, d, 0.5).tolist() == [10, 11, 12, 13]
    assert pixel_patch(np.array([10]), rows, w, d, 0.4).tolist() == [10, 12, 13]
    # a patch that already draws the share is kept as it is, rows off the pixel included
    assert pixel_patch(np.array([3, 10]), rows, w, d, 0.3).tolist() == [3, 10]
    # a pixel with less than the share in all: every primitive that draws it
    empty = np.array([], np.int64)
    assert pixel_patch(empty, rows, w * 0.5, d, 0.5).tolist() == [10, 11, 12, 13, 14]
    assert pixel_patch(np.array([7]), rows[:0], w[:0], d[:0], 0.5).tolist() == [7]
    # negative: until what the patch leaves of the pixel (0.77 in all) draws less than the
    # share: row 10 leaves 0.47 < 0.5; at 0.4, 13 leaves 0.44, 12 then 0.34 < 0.4
    assert pixel_patch(empty, rows, w, d, 0.5, positive=False).tolist() == [10]
    assert pixel_patch(empty, rows, w, d, 0.4, positive=False).tolist() == [10, 12, 13]
    # leaving exactly the share is not less than it: one more joins
    assert pixel_patch(empty, rows, w, d, 0.47, positive=False).tolist() == [10, 13]
    assert pixel_patch(np.array([11, 14]), rows, w, d, 0.5, False).tolist() == [11, 14]
    with pytest.raises(ValueError, match="positive_pixel_share"):
        CorrectionConfig(positive_pixel_share=1.5)


def _pixel_weights(s: Session, cam, x: int, y: int) -> np.ndarray:
    """Every primitive's blending weight at pixel (x, y): a full-image pass."""
    m = np.zeros((cam.height, cam.width), bool)
    m[y, x] = True
    return s.renderer.contributions(cam, m).a1.numpy().astype(np.float64)


def _missed_pixel(s: Session, sc) -> tuple[object, tuple[float, float]]:
    """A test camera and a pixel the truth draws (weight ≥ 0.6), the selection does not
    (< 0.4), and a click's ellipsoid patch holds less than 0.4 of."""
    cfg = s.config.corrections
    missed = np.flatnonzero(sc.labels & ~s.selection)
    for cam in sc.test_cameras:
        c = s.working_camera(cam)
        b = s.rendering.render_camera(c, segmented=False)
        uv, _ = c.project(sc.scene.means[missed])
        ok = (
            (uv[:, 0] >= 1) & (uv[:, 0] < c.width - 1) & (uv[:, 1] >= 1) & (uv[:, 1] < c.height - 1)
        )
        for u, v in uv[ok][:: max(1, int(ok.sum()) // 60)]:
            x, y = int(u), int(v)
            w = _pixel_weights(s, c, x, y)
            if w[sc.labels].sum() < 0.6 or w[s.selection].sum() >= 0.4:
                continue
            xy = (x + 0.5, y + 0.5)
            depth, point = click_point(c, xy, s.backend.click_depth(b), b.alpha, 0.0)
            r = patch_radius(c, depth, cfg.patch_px)
            patch = s.backend.click_patch(point, r, cfg.positive_sigmas)
            if w[patch].sum() < 0.4:
                return c, xy
    raise AssertionError("no missed pixel the ellipsoid patch draws less than 0.4 of")


def test_a_positive_click_leaves_its_pixel_selected(vase):  # noqa: F811
    sc = vase[0]
    on = _open(vase, _perfect(), corrections=CorrectionConfig(positive_pixel_share=0.5))
    off = _open(vase, _perfect())  # the default: the ellipsoid patch alone
    assert off.config.corrections.positive_pixel_share == 0
    for s in (on, off):
        _accept_clicks(s, vase, anchors=[0])
    np.testing.assert_array_equal(on.selection, off.selection)
    cam, xy = _missed_pixel(on, sc)
    x, y = int(xy[0]), int(xy[1])
    got = {}
    for name, s in (("on", on), ("off", off)):
        res = s.click_camera(cam, xy, positive=True, full_camera=False)
        w = _pixel_weights(s, cam, x, y)
        got[name] = (w[s.selection].sum(), w[res.correction.patch].sum(), res)
    sel_on, patch_on, res_on = got["on"]
    sel_off, patch_off, _ = got["off"]
    assert patch_on >= 0.5 and sel_on >= 0.5  # the pixel shows selected
    assert patch_off < 0.4 and sel_off < 0.5  # the ellipsoid patch alone left it out
    # what came in draws the pixel and is mostly the vase the truth holds there
    added = res_on.correction.patch
    assert on.selection[added].all() and sc.labels[added].mean() > 0.5
    on.close()
    off.close()


def test_a_click_whose_view_is_refused_still_selects_its_pixel(vase):  # noqa: F811
    sc, _, clicks, _ = vase
    s = _open(vase, ConstantSegmenter(0.0), corrections=CorrectionConfig(positive_pixel_share=0.5))
    s.history.record("start")
    xy = _xy(s, 0, clicks[0])
    v = s.click(0, xy)
    c = s.current.corrections[-1]
    assert c.spawned == v.id and not s.selection.any()  # an open view: nothing yet
    s.history.record("click")
    assert s.accept(v).status == ViewStatus.REJECTED
    assert s.click_holds(v)  # what the add-on's refusal message says
    s.history.record("accept")
    cam = s.anchors[0].camera
    w = _pixel_weights(s, cam, int(xy[0]), int(xy[1]))
    # the click stands: its patch, and the pixel it was made on, are selected
    assert s.selection[c.patch].all() and w[s.selection].sum() >= 0.5
    assert np.array_equal(np.flatnonzero(s.selection), c.patch)
    held = s.selection.copy()
    s.history.undo()
    assert not s.selection.any()  # back to the open view
    s.history.redo()
    assert np.array_equal(s.selection, held)
    assert s.undo() is v and v.status == ViewStatus.OPEN and not s.selection.any()
    assert not s.click_holds(v)
    s.close()
    # the default (no pixel rule): the ellipsoid patch holds the same way
    d = _open(vase, ConstantSegmenter(0.0))
    assert d.accept(d.click(0, xy)).status == ViewStatus.REJECTED
    patch = d.current.corrections[-1].patch
    assert len(patch) and np.array_equal(np.flatnonzero(d.selection), patch)
    assert d.click_holds(d.views[-1].id)
    d.close()
    # the paper's loop (no corrections): a refused view leaves nothing, and says so
    p = _open(vase, ConstantSegmenter(0.0), corrections=CorrectionConfig(enabled=False))
    pv = p.click(0, xy)
    assert p.accept(pv).status == ViewStatus.REJECTED
    assert not p.selection.any() and not p.click_holds(pv)
    p.close()

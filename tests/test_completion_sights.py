"""Views that share a sight count once in the completion (:mod:`.completion_sights`): a
wider view of a click looks along its close-up's direction, so what the close-up hides
behind the object is still hidden from one direction only. On the solid ball of
``test_completion``: two views from one direction fill its hidden interior when counted
as two views, not as one sight; a second direction fills it again; the over-count is
checked against a hand count on hand-made records."""

from __future__ import annotations

import numpy as np

from divas_engine.fusion.occupancy import GridConfig, build_occupancy
from divas_engine.mapping import SurfelMapper
from divas_engine.mapping.completion import VolumetricCompletion
from divas_engine.mapping.completion_records import HIDDEN, INCONSISTENT, SURFACE, _ViewRecord
from divas_engine.mapping.completion_sights import deep_repeats, shared_sights, voxel_repeats
from divas_engine.mapping.config import CompletionConfig
from tests.test_completion import CPU, _ball_scene, _divas_like, _views


def test_a_wider_view_along_the_same_sight_adds_no_cone():
    scene, labels, parts = _ball_scene()
    grid = build_occupancy(scene, GridConfig(), CPU)
    act = SurfelMapper(scene, grid, device=CPU).active_index
    close, side = _views(scene, labels, [(0, 0, -1), (1, 0, -0.3)])
    (wider,) = _views(scene, labels, [(0, 0, -1)], distance=6.0)  # same point and direction
    sel, seg = _divas_like(labels, parts, act, len(grid))
    interior = np.zeros(len(labels), bool)
    interior[parts["interior"]] = True
    interior &= ~seg[act]  # in a voxel of its own, not one the surface already holds

    def completed(views, sights):
        comp = VolumetricCompletion(scene, grid, act, CompletionConfig(), device=CPU)
        comp.sync(list(enumerate(views)), sights)
        return comp, comp.complete(sel, seg).selected

    # counted as two views, the close-up's own cone fills the hidden interior …
    two, as_views = completed([close, wider], None)
    assert as_views[interior].mean() > 0.9
    hid = np.flatnonzero(two.n_hidden == 2)
    assert len(hid) and (two.n_surf[hid] == 0).all()
    # … as one sight it is hidden from one direction only: the fill takes none of it
    # (what joins lies on the front surface a view sees, or passes the contribution test)
    one, as_sight = completed([close, wider], {0: "close", 1: "close"})
    res = one.complete(sel, seg)
    assert as_sight[interior].mean() < 0.1
    assert not (res.fill_added & interior & (one.n_surf[act] == 0)).any()
    assert (voxel_repeats(shared_sights(one.sights, [0, 1]), one._record_map(), hid) == 1).all()
    # a second direction fills it again, and the sights of views not passed are dropped
    _, with_side = completed([close, wider, side], {0: "close", 1: "close", 9: "x"})
    assert with_side[interior].mean() > 0.9
    # undo of the wider view: its sight is a view of its own again
    one.sync([(0, close)], {0: "close", 1: "close"})
    assert one.sights == {0: "close"} and shared_sights(one.sights, [0]) == []


def test_repeats_are_the_per_view_count_less_the_per_sight_one():
    def rec(vox, flags, gauss, deep):
        g = np.asarray(gauss, np.int32)
        z = np.zeros(len(g), np.int64)
        return _ViewRecord(
            g, z, z, np.zeros(len(g), bool), np.asarray(deep, np.int8),
            np.asarray(vox, np.int32), np.asarray(flags, np.uint8),
        )  # fmt: skip

    s, h, i = SURFACE, HIDDEN, INCONSISTENT
    records = {
        0: rec([1, 2, 3, 4], [h, h, s, i], [10, 11, 12], [1, 1, -1]),
        1: rec([2, 3, 4, 5], [h, h, h, h], [11, 12, 13], [1, 1, 1]),
        2: rec([2, 3, 5], [s, h, h], [11, 13], [1, 1]),
        3: rec([1, 2, 3], [h, h, h], [10, 11], [1, 1]),  # a sight of its own
    }
    groups = shared_sights({0: "a", 1: "a", 2: "a", 3: "b"}, [0, 1, 2, 3])
    assert groups == [[0, 1, 2]]
    # voxel 1: one member (0); 2: three (h, h, s); 3: three (s, h, h); 4: one (1: the
    # inconsistent flag is no evidence); 5: two (1, 2); 6: none
    vox = np.array([1, 2, 3, 4, 5, 6])
    assert voxel_repeats(groups, records, vox).tolist() == [0, 2, 2, 0, 1, 0]
    # Gaussian 10: one member deep-ok (0); 11: three; 12: one (0 is beyond: -1); 13: two
    gauss = np.array([10, 11, 12, 13])
    assert deep_repeats(groups, records, gauss).tolist() == [0, 2, 0, 1]
    assert shared_sights({}, [0, 1]) == []

"""The geometry of the manual selection tools on known point layouts
(:mod:`divas_engine.selection_tools`) — each expected set is written out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.selection_tools import (
    RegionView,
    SelectMode,
    combine,
    grow,
    in_box,
    in_circle,
    in_lasso,
    in_range,
    in_sphere,
    neighbour_radius,
    points_under_mask,
    project_to_region,
    shrink,
)


def _grid_view():
    """An orthographic-like region view: world (x, y) in [-1, 1]² fills a 200×100 region
    (x → region x, y → region y); z is ignored except behind the view (w ≤ 0)."""
    m = np.eye(4)
    m[3] = [0.0, 0.0, -1.0, 0.0]  # w = −z: points need z < 0 to be in front
    return RegionView(m, 200, 100)


def _layout():
    """A 5 × 5 grid of points at x, y ∈ {−0.8, −0.4, 0, 0.4, 0.8}, z = −1 (in front),
    plus one point behind the view at the centre."""
    xs = np.array([-0.8, -0.4, 0.0, 0.4, 0.8])
    gx, gy = np.meshgrid(xs, xs, indexing="xy")
    pts = np.c_[gx.ravel(), gy.ravel(), -np.ones(25)]
    return np.vstack([pts, [0.0, 0.0, 1.0]])


def test_projection_of_the_layout():
    xy, front = project_to_region(_layout(), _grid_view())
    # x = −0.8 at z = −1: ndc −0.8 → region (0.2 × 100) = 20
    assert xy[0].tolist() == pytest.approx([20.0, 10.0])
    assert xy[24].tolist() == pytest.approx([180.0, 90.0])
    assert front[:25].all() and not front[25]
    # with an object matrix: translate the object by +0.4 in x
    mw = np.eye(4)
    mw[0, 3] = 0.4
    xy2, _ = project_to_region(_layout(), _grid_view(), mw)
    assert xy2[0].tolist() == pytest.approx([60.0, 10.0])


def test_box_selects_exactly_the_expected_points():
    xy, front = project_to_region(_layout(), _grid_view())
    # region box x ∈ [50, 110], y ∈ [25, 55]: columns x ∈ {−0.4, 0} (region 60, 100),
    # rows y ∈ {−0.4, 0} (region 30, 50); the centre point behind the view is out
    got = np.flatnonzero(in_box(xy, front, (110, 55, 50, 25)))
    assert got.tolist() == [6, 7, 11, 12]


def test_lasso_selects_exactly_the_expected_points():
    xy, front = project_to_region(_layout(), _grid_view())
    # a triangle with corners around points 0 (20,10), 4 (180,10) and 22 (100,90):
    tri = [(10, 5), (190, 5), (100, 95)]
    got = set(np.flatnonzero(in_lasso(xy, front, tri)).tolist())
    # by hand: the bottom row (0–4), row 2 x ∈ {−0.4, 0, 0.4} (6–8 at y=30: edges at
    # x = 10 + 90·25/90 = 35 … 165), row 3 (y = 50): x between 50 and 150 → 11, 12, 13;
    # row 4 (y = 70): x between ~72 and ~128 → 17 (100); row 5 (y = 90): 22 (x = 100
    # exactly on the axis, inside: the edges are at 95.5 and 104.5)
    assert got == {0, 1, 2, 3, 4, 6, 7, 8, 11, 12, 13, 17, 22}
    # a concave (U-shaped) lasso leaves the notch out
    u = [(10, 5), (190, 5), (190, 95), (130, 95), (130, 40), (70, 40), (70, 95), (10, 95)]
    got = set(np.flatnonzero(in_lasso(xy, front, u)).tolist())
    notch = {12, 17, 22}  # x = 100 (region), y ≥ 50
    assert got == set(range(25)) - notch
    with pytest.raises(ValueError, match="3 points"):
        in_lasso(xy, front, [(0, 0), (1, 1)])


def test_circle_and_sphere():
    pts = _layout()
    xy, front = project_to_region(pts, _grid_view())
    # brush at the centre (100, 50) of radius 25 px: centre (0 px away) plus the two
    # horizontal neighbours (40 px: out) and the vertical ones (20 px: in)
    got = np.flatnonzero(in_circle(xy, front, (100, 50), 25)).tolist()
    assert got == [7, 12, 17]
    # 3D sphere of radius 0.45 around (0.4, 0.4, −1): the point itself and its four
    # axis neighbours at 0.4, not the diagonals at 0.566
    got = np.flatnonzero(in_sphere(pts, (0.4, 0.4, -1.0), 0.45)).tolist()
    assert got == [13, 17, 18, 19, 23]


def test_modes():
    f = np.array([1, 1, 0, 0], bool)
    r = np.array([1, 0, 1, 0], bool)
    assert combine(f, r, SelectMode.SET).tolist() == [1, 0, 1, 0]
    assert combine(f, r, "ADD").tolist() == [1, 1, 1, 0]
    assert combine(f, r, SelectMode.SUBTRACT).tolist() == [0, 1, 0, 0]
    assert combine(f, r, "AND").tolist() == [1, 0, 0, 0]
    assert combine(f, r, "XOR").tolist() == [0, 1, 1, 0]
    with pytest.raises(ValueError):
        combine(f, r[:3], "ADD")


def test_grow_shrink_by_neighbourhood():
    # points on a line, spacing 1, plus a far island at x = 10
    pts = np.c_[[0, 1, 2, 3, 4, 10], np.zeros(6), np.zeros(6)].astype(float)
    sel = np.array([0, 0, 1, 0, 0, 0], bool)
    assert np.flatnonzero(grow(pts, sel, 1.01)).tolist() == [1, 2, 3]
    assert np.flatnonzero(grow(pts, sel, 1.01, steps=2)).tolist() == [0, 1, 2, 3, 4]
    assert np.flatnonzero(grow(pts, sel, 1.01, steps=10)).tolist() == [0, 1, 2, 3, 4]
    allowed = np.array([1, 0, 1, 1, 1, 1], bool)  # point 1 hidden
    assert np.flatnonzero(grow(pts, sel, 1.01, steps=2, allowed=allowed)).tolist() == [2, 3, 4]
    full = np.array([1, 1, 1, 1, 1, 0], bool)
    # the unselected island is 6 away: nothing erodes
    assert np.flatnonzero(shrink(pts, full, 1.01)).tolist() == [0, 1, 2, 3, 4]
    line = np.array([1, 1, 1, 1, 1, 1], bool)
    line[5] = False
    pts2 = pts.copy()
    pts2[5, 0] = 5.0  # now the unselected point is next to 4
    assert np.flatnonzero(shrink(pts2, line, 1.01)).tolist() == [0, 1, 2, 3]
    assert np.flatnonzero(shrink(pts2, line, 1.01, steps=2)).tolist() == [0, 1, 2]
    # ``allowed`` unselected points only: a hidden neighbour does not erode
    assert shrink(pts2, line, 1.01, allowed=np.array([1, 1, 1, 1, 1, 0], bool)).sum() == 5
    # the automatic radius: 2 × the median nearest-neighbour distance
    assert neighbour_radius(pts[:5]) == pytest.approx(2.0)


def test_in_range():
    v = np.array([0.1, 0.5, 0.9, np.nan])
    assert in_range(v, 0.4, None).tolist() == [False, True, True, False]
    assert in_range(v, None, 0.5).tolist() == [True, True, False, False]
    assert in_range(v, 0.2, 0.8).tolist() == [False, True, False, False]


def test_points_under_mask_keep_the_visible_surface():
    from divas_engine.camera import Camera

    cam = Camera(8, 4, 4.0, 4.0, 4.0, 2.0)  # at the origin, looking down +z
    mask = np.zeros((4, 8))
    mask[:, :4] = 1.0  # the left half
    depth = np.full((4, 8), 2.0)
    depth[0, 0] = 0.0  # no surface at pixel (0, 0)
    pts = np.array(
        [
            [-0.5, 0.0, 2.0],  # left half, on the surface → in
            [0.5, 0.0, 2.0],  # right half → out
            [-1.0, 0.0, 4.0],  # left half but far behind the surface → out
            [-0.51, 0.0, 2.05],  # within 3 % of the depth → in
            [-1.9, -0.9, 2.0],  # pixel (0.2, 0.2): no surface there → out
            [0.0, 0.0, -2.0],  # behind the camera → out
            [-9.0, 0.0, 2.0],  # outside the image → out
        ]
    )
    got = points_under_mask(pts, cam, mask, depth)
    assert got.tolist() == [True, False, False, True, False, False, False]

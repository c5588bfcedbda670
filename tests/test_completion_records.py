"""Helpers of the completion's per-view records: the edge distance computed on
the mask's box equals the whole image's, point projection does not depend on which other
points are projected, and a record widened by a disjoint part is the union."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.mapping.completion_records import (
    _ViewRecord,
    edge_distance,
    fill_holes,
    project_points,
)


def _whole_image_edge_distance(mask: np.ndarray, exact: bool = True) -> np.ndarray:
    """Reference: fill the holes and take the distance transform of the whole image
    padded by one background pixel — by brute force over every background pixel
    (``exact``), or with OpenCV's precise transform (the former implementation)."""
    import cv2
    from scipy.ndimage import binary_fill_holes

    m = np.pad(binary_fill_holes(np.asarray(mask, bool)), 1)
    if not exact:
        d = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        return d[1:-1, 1:-1].astype(np.float64)
    out = np.zeros(m.shape)
    bg = np.argwhere(~m)
    for y, x in np.argwhere(m):
        d2 = ((bg - (y, x)) ** 2).sum(axis=1).min()
        out[y, x] = np.float32(np.sqrt(float(d2)))
    return out[1:-1, 1:-1]


def _masks():
    rng = np.random.default_rng(7)
    H, W = 60, 80
    yy, xx = np.mgrid[:H, :W]
    out = {"empty": np.zeros((H, W), bool), "full": np.ones((H, W), bool)}
    disc = (yy - 30) ** 2 + (xx - 40) ** 2 < 15**2
    out["disc"] = disc
    ring = disc & ((yy - 30) ** 2 + (xx - 40) ** 2 > 6**2)  # a hole in the middle
    out["ring"] = ring
    out["corner"] = (yy - 2) ** 2 + (xx - 3) ** 2 < 12**2  # touches two borders
    out["right"] = (xx > 70) & (yy > 10) & (yy < 50)  # touches the right border
    out["pixel"] = (yy == 5) & (xx == 77)
    # a frame with a notch open to the outside (no hole) and a blob inside it
    frame = (np.abs(yy - 30) < 20) & (np.abs(xx - 40) < 25)
    frame &= ~((np.abs(yy - 30) < 15) & (np.abs(xx - 40) < 20))
    notch = frame.copy()
    notch[28:32, 15:25] = False
    out["frame"] = frame
    out["notch"] = notch | ((yy - 30) ** 2 + (xx - 40) ** 2 < 16)
    for k in range(6):
        out[f"noise{k}"] = rng.random((H, W)) < 0.05 * (k + 1)
    return out


@pytest.mark.parametrize("name", list(_masks()))
def test_edge_distance_on_the_box_is_the_whole_images(name):
    m = _masks()[name]
    got = edge_distance(m)
    ref = _whole_image_edge_distance(m)
    assert got.dtype == np.float64 and got.shape == m.shape
    assert np.array_equal(got, ref), name
    # the former OpenCV values, up to its float32 rounding
    assert np.allclose(got, _whole_image_edge_distance(m, exact=False), rtol=0, atol=4e-6)
    if name == "ring":  # the hole is filled: its pixels have a distance
        assert got[30, 40] > 0


def test_fill_holes_is_scipys():
    """The labelling fill equals ``binary_fill_holes`` (the reference): holes, nested
    holes with islands, holes open to a border or a corner, noise, degenerate shapes."""
    from scipy.ndimage import binary_fill_holes

    masks = dict(_masks())
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[:90, :70]
    r2 = (yy - 45) ** 2 + (xx - 35) ** 2
    masks["nested"] = ((r2 < 30**2) & (r2 > 22**2)) | ((r2 < 15**2) & (r2 > 8**2)) | (r2 < 9)
    masks["open_corner"] = ~((yy < 5) & (xx < 5)) & (r2 < 60**2)
    masks["row"] = np.ones((1, 9), bool)
    masks["col_gap"] = np.array([[True], [False], [True]])
    for k in range(8):
        blobs = rng.random((90, 70)) < 0.3 + 0.08 * k
        masks[f"blobs{k}"] = blobs
    for name, m in masks.items():
        got = fill_holes(m)
        assert got.dtype == bool and np.array_equal(got, binary_fill_holes(m)), name
    assert fill_holes(masks["nested"]).sum() > masks["nested"].sum()  # holes were filled


def test_project_points_is_per_point():
    cam = Camera.look_at(
        np.array([0.3, -0.2, -4.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]),
        width=96, height=80, fx=80.0, name="c",
    )  # fmt: skip
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(5001, 3))
    uv, z = project_points(cam, pts)
    ref_uv, ref_z = cam.project(pts)
    assert np.allclose(uv, ref_uv, rtol=1e-12, atol=1e-9) and np.allclose(z, ref_z, rtol=1e-12)
    for idx in (np.arange(3), rng.choice(5001, 777, replace=False), np.array([5000])):
        uv2, z2 = project_points(cam, pts[idx])
        assert np.array_equal(uv2, uv[idx]) and np.array_equal(z2, z[idx])


def test_merged_record_is_the_union():
    def rec(g, v, cover):
        g = np.asarray(g, np.int32)
        return _ViewRecord(
            g, g.astype(np.int64) * 3, g.astype(np.int64), g % 2 == 0, (g % 3 - 1).astype(np.int8),
            np.asarray(v, np.int32), np.ones(len(v), np.uint8), cover,
        )  # fmt: skip

    a = rec([1, 5], [2], np.array([True, False, False, False]))
    b = rec([7], [3, 4], np.array([False, False, True, False]))
    m = a.merged(b)
    assert m.gauss.tolist() == [1, 5, 7] and m.q1.tolist() == [3, 15, 21]
    assert m.voxels.tolist() == [2, 3, 4] and m.cover.tolist() == [True, False, True, False]
    assert m.seen.tolist() == [False, False, False] and m.deep.tolist() == [0, 1, 0]
    assert a.merged(rec([], [], None)).cover is None

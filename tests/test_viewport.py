"""Viewport click → camera pixel (:mod:`divas_engine.viewport`), hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.viewport import camera_pixel_to_region, frame_homography, region_to_camera_pixel


def rect(left, bottom, right, top):
    """Axis-aligned frame in view_frame order: top-right, bottom-right, bottom-left, top-left."""
    return [(right, top), (right, bottom), (left, bottom), (left, top)]


def test_frame_filling_the_region_maps_pixel_for_pixel():
    # region 640x480 exactly covered by a 640x480 camera: region pixel (i, j) from the
    # bottom is image pixel (i, 479 - j) from the top; centres match.
    frame = rect(0, 0, 640, 480)
    assert region_to_camera_pixel((640, 480), frame, (0, 0), (640, 480)) == (0.5, 479.5)
    assert region_to_camera_pixel((640, 480), frame, (639, 479), (640, 480)) == (639.5, 0.5)
    assert region_to_camera_pixel((640, 480), frame, (100, 200), (640, 480)) == (100.5, 279.5)


def test_scaled_frame():
    # 1000x500 camera shown at half size in a 500x250 region: one region pixel = 2 image px
    frame = rect(0, 0, 500, 250)
    u, v = region_to_camera_pixel((500, 250), frame, (10, 20), (1000, 500))
    assert (u, v) == pytest.approx((21.0, 500 - 41.0))


def test_letterbox_inside_and_outside():
    # region 1000x500, a 4:3 camera frame 600x450 centred: x 200..800, y 25..475
    frame = rect(200, 25, 800, 475)
    size = (1000, 500)
    img = (800, 600)  # 4:3 image, 600/800 = 0.75 region px per image px
    # region pixel (499, 249) -> centre (499.5, 249.5) -> ((299.5)/600*800, (475-249.5)/450*600)
    u, v = region_to_camera_pixel(size, frame, (499, 249), img)
    assert u == pytest.approx(299.5 / 600 * 800)
    assert v == pytest.approx(225.5 / 450 * 600)
    # clicks in the side bars and the top/bottom bars are outside the frame
    for m in [(100, 250), (850, 250), (500, 10), (500, 480), (199, 250)]:
        assert region_to_camera_pixel(size, frame, m, img) is None
    # and clicks outside the region are rejected even if the frame extends there
    assert region_to_camera_pixel((100, 100), rect(-50, -50, 150, 150), (120, 50), (10, 10)) is None
    assert region_to_camera_pixel((100, 100), rect(-50, -50, 150, 150), (-1, 50), (10, 10)) is None


def test_frame_edges():
    frame = rect(10, 10, 20, 20)  # 10x10 region px for a 10x10 image
    assert region_to_camera_pixel((100, 100), frame, (10, 19), (10, 10)) == pytest.approx(
        (0.5, 0.5)
    )
    assert region_to_camera_pixel((100, 100), frame, (19, 10), (10, 10)) == pytest.approx(
        (9.5, 9.5)
    )
    assert region_to_camera_pixel((100, 100), frame, (20, 15), (10, 10)) is None  # u = 10.5
    assert region_to_camera_pixel((100, 100), frame, (9, 15), (10, 10)) is None  # u = -0.5


def test_non_square_pixel_aspect():
    # 200x100 image with pixel aspect y=2 displays as a square: frame 300x300 in the region
    # (x 50..350, y 100..400). Each image column is 1.5 region px, each row 3 region px.
    frame = rect(50, 100, 350, 400)
    u, v = region_to_camera_pixel((400, 500), frame, (199, 249), (200, 100))
    assert u == pytest.approx((199.5 - 50) / 1.5)
    assert v == pytest.approx((400 - 249.5) / 3.0)
    # the image centre sits at the frame centre
    assert camera_pixel_to_region([(100, 50)], frame, (200, 100))[0] == pytest.approx((200, 250))


def test_shifted_frame():
    # lens shift moves the frame off-centre in the region; the mapping follows the corners
    frame = rect(-30, 120, 290, 360)  # 320x240 frame partly left of the region
    assert region_to_camera_pixel((400, 400), frame, (0, 239), (640, 480)) == pytest.approx(
        ((0.5 + 30) * 2, (360 - 239.5) * 2)
    )


def test_projective_frame_round_trip():
    # a general quadrilateral (the frame seen from off the camera's axis)
    frame = [(310.0, 290.0), (330.0, 40.0), (20.0, 60.0), (60.0, 250.0)]
    img = (640, 480)
    hmat = frame_homography(frame, img)
    corners = np.c_[np.array(frame), np.ones(4)] @ hmat.T
    np.testing.assert_allclose(
        corners[:, :2] / corners[:, 2:], [(640, 0), (640, 480), (0, 480), (0, 0)], atol=1e-9
    )
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], img, (50, 2))
    reg = camera_pixel_to_region(uv, frame, img)
    for (x, y), expect in zip(reg, uv):
        got = region_to_camera_pixel((400, 400), frame, (x - 0.5, y - 0.5), img)
        assert got == pytest.approx(tuple(expect), abs=1e-6)


def test_bad_frames():
    with pytest.raises(ValueError, match="degenerate"):
        frame_homography([(0, 0), (0, 0), (0, 0), (0, 0)], (10, 10))
    with pytest.raises(ValueError, match="4 finite"):
        frame_homography([(0, 0), (1, 1)], (10, 10))
    with pytest.raises(ValueError, match="empty camera"):
        frame_homography(rect(0, 0, 1, 1), (0, 10))


# ----------------------------------------------------------------------------- free views
def _region_xy(view_matrix, window_matrix, size, pts):
    """Blender's region position of world points (``location_3d_to_region_2d``'s formula,
    written out): clip = P · V · p, ((ndc + 1) / 2) × size."""
    clip = np.c_[pts, np.ones(len(pts))] @ (window_matrix @ view_matrix).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return (ndc + 1.0) * 0.5 * np.asarray(size, float)


def test_camera_from_region_reproduces_the_region_projection():
    from divas_engine.camera import Camera
    from divas_engine.viewport import camera_from_region, region_matrices

    rng = np.random.default_rng(3)
    for w, h, fx, fy, cx, cy in [(640, 480, 500, 500, 320, 240), (803, 611, 700, 640, 390.5, 330)]:
        cam = Camera.look_at(
            rng.normal(size=3) * 5,
            rng.normal(size=3) * 0.2,
            [0, 0, 1],
            width=w,
            height=h,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
        )
        vm, wm = region_matrices(cam, near=0.05, far=200.0)
        back = camera_from_region(vm, wm, (w, h))
        assert (back.width, back.height) == (w, h)
        np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [fx, fy, cx, cy])
        np.testing.assert_allclose(back.c2w, cam.c2w, atol=1e-12)
        # independent: the region position of 3D points (Blender's formula) is the
        # camera pixel with y flipped
        pts = cam.unproject(rng.uniform([0, 0], [w, h], (50, 2)), rng.uniform(1, 9, 50))
        reg = _region_xy(vm, wm, (w, h), pts)
        uv, _ = back.project(pts)
        np.testing.assert_allclose(reg[:, 0], uv[:, 0], atol=1e-9)
        np.testing.assert_allclose(h - reg[:, 1], uv[:, 1], atol=1e-9)
        # float32 matrices (what Blender holds) still give a valid camera, sub-pixel close
        b32 = camera_from_region(vm.astype(np.float32), wm.astype(np.float32), (w, h))
        assert np.abs(b32.project(pts)[0] - uv).max() < 1e-2


def test_region_click_pixel_and_orthographic_views():
    from divas_engine.viewport import OrthographicViewError, camera_from_region, region_click_pixel

    assert region_click_pixel((0, 0), (640, 480)) == (0.5, 479.5)
    assert region_click_pixel((639, 479), (640, 480)) == (639.5, 0.5)
    ortho = np.diag([0.1, 0.1, -0.01, 1.0])
    with pytest.raises(OrthographicViewError, match="orthographic"):
        camera_from_region(np.eye(4), ortho, (640, 480))
    with pytest.raises(ValueError, match="empty region"):
        camera_from_region(np.eye(4), ortho, (0, 480))

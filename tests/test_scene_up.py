"""Scene up without cameras and framed camera-free anchors on analytic point
sets whose up, ground and extent are known by construction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from divas_engine.views import (
    UpSource,
    ViewConfig,
    estimate_scene_up,
    framed_camera,
    ground_candidates,
    plan_anchors,
    view_fill,
)
from divas_engine.views.fibonacci import up_frame
from divas_engine.views.framing import layout_from_points
from divas_engine.views.up_direction import snap_to_axis
from tests.framing_checks import angle_deg


def _rot_to(n: np.ndarray) -> np.ndarray:
    """Rotation taking +z to unit ``n`` (columns: a frame whose z is n)."""
    return up_frame(n / np.linalg.norm(n))


def _floor_and_box(up: np.ndarray, seed: int = 0, floor_half: float = 2.0):
    """A square floor (4000 points, opacity 0.3) with a box 1 × 0.6 × 1.5 standing on
    it (3000 points, opacity 0.9), in the frame whose +z is ``up``."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-floor_half, floor_half, (4000, 2)), rng.normal(0, 0.003, 4000)]
    box = rng.uniform([-0.5, -0.3, 0.0], [0.5, 0.3, 1.5], (3000, 3))
    local = np.vstack([floor, box])
    w = np.r_[np.full(4000, 0.3), np.full(3000, 0.9)]
    R = _rot_to(up)
    pts = local @ R.T + np.array([0.3, -1.0, 2.0])
    c = np.median(pts, 0)
    r = float(np.percentile(np.linalg.norm(pts - c, axis=1), 99))
    return pts, w, c, r


def _standing_figure(up: np.ndarray, seed: int = 0):
    """A standing 'figure' without a floor: a round column (radius 0.2) with a domed top,
    1.8 tall, whose only flat contact is its flat bottom (the soles), in the frame whose
    +z is ``up`` (what the biker capture looks like). A column with broad flat sides
    would be a slab lying on them as much as a figure standing: not this case."""
    rng = np.random.default_rng(seed)
    n = 8000
    t = rng.uniform(0, 2 * math.pi, n)
    rad = np.sqrt(rng.uniform(0, 1, n))
    x, y = 0.2 * rad * np.cos(t), 0.2 * rad * np.sin(t)
    z = rng.uniform(0, 1, n) * (1.8 - 0.3 * rad**2)  # dome: lower at the rim
    pts = np.c_[x, y, z] @ _rot_to(up).T
    w = np.full(n, 0.8)
    c = np.median(pts, 0)
    return pts, w, c, float(np.percentile(np.linalg.norm(pts - c, axis=1), 99))


def test_snap_to_axis():
    v, ang = snap_to_axis(np.array([0.05, -1.0, 0.0]), 10.0)
    np.testing.assert_array_equal(v, [0, -1.0, 0])
    assert ang == pytest.approx(math.degrees(math.atan(0.05)))
    v, ang = snap_to_axis(np.array([0.5, -1.0, 0.0]), 10.0)
    assert ang > 10 and abs(np.linalg.norm(v) - 1) < 1e-12 and v[0] > 0.4


def test_tilted_floor_near_the_convention_gives_its_normal():
    # a floor 20° off -y (beyond the 10° snap, inside the 30° convention cone)
    up = _rot_to(np.array([0, -1.0, 0])) @ np.array([math.sin(math.radians(20)), 0, 1])
    up = up / np.linalg.norm(up)
    pts, w, c, r = _floor_and_box(up)
    est = estimate_scene_up(pts, w, c, r)
    assert est.source == UpSource.GROUND
    assert angle_deg(est.up, up) < 1.5
    assert est.ground is not None and est.ground.coverage > 0.9
    assert 0.5 < est.confidence <= 1.0
    # the ground plane is the floor: heights of the floor points ≈ 0
    assert np.abs(est.ground.height(pts[:4000])).mean() < 0.02 * r


def test_floor_on_an_axis_far_from_the_convention_is_taken():
    pts, w, c, r = _floor_and_box(np.array([0, 0, 1.0]))
    est = estimate_scene_up(pts, w, c, r)
    assert est.source == UpSource.GROUND
    np.testing.assert_array_equal(est.up, [0, 0, 1.0])  # snapped
    assert "world axis" in est.reason


def test_a_dense_plane_off_axis_and_off_convention_is_not_a_ground():
    # the guitar case: a large dense disk with all content on one side, its normal
    # 75° from the convention and ~20° from every axis; nothing else is flat
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 2 * math.pi, 6000)
    rad = np.sqrt(rng.uniform(0, 1, 6000))
    disk = np.c_[rad * np.cos(t), rad * np.sin(t), rng.normal(0, 0.002, 6000)]
    blob = rng.normal([0, 0, 0.35], 0.12, (1500, 3))
    n = np.array([-0.93, 0.24, -0.27])
    pts = np.vstack([disk, blob]) @ _rot_to(n).T
    w = np.full(len(pts), 0.8)
    c = np.median(pts, 0)
    r = float(np.percentile(np.linalg.norm(pts - c, axis=1), 99))
    cands = ground_candidates(pts, w, c, r)
    assert angle_deg(cands[0].normal, n / np.linalg.norm(n)) < 2.0  # it is a candidate …
    est = estimate_scene_up(pts, w, c, r)
    assert est.source != UpSource.GROUND or angle_deg(est.up, [0, -1.0, 0]) <= 30.0
    assert angle_deg(est.up, n) > 45.0  # … but not the up


def test_no_ground_falls_back_to_the_convention_with_low_confidence():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(5000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)  # a hollow sphere: no flat support
    est = estimate_scene_up(pts, np.full(5000, 0.8), np.zeros(3), 1.0)
    assert est.source == UpSource.CONVENTION and est.ground is None
    np.testing.assert_array_equal(est.up, [0, -1.0, 0])
    assert est.confidence == pytest.approx(0.3)
    cfg = ViewConfig(convention_up=(0, 0, 1))
    np.testing.assert_array_equal(
        estimate_scene_up(pts, np.ones(5000), np.zeros(3), 1.0, cfg).up, [0, 0, 1.0]
    )


def test_small_sole_contact_of_a_standing_figure():
    up = np.array([0, -1.0, 0])
    pts, w, c, r = _standing_figure(up)
    est = estimate_scene_up(pts, w, c, r)
    assert est.source == UpSource.GROUND and angle_deg(est.up, up) < 1e-9


def test_override_wins():
    pts, w, c, r = _floor_and_box(np.array([0, 0, 1.0]))
    est = estimate_scene_up(pts, w, c, r, up=np.array([0, 0, 3.0]))
    assert est.source == UpSource.OVERRIDE and est.confidence == 1.0
    np.testing.assert_allclose(est.up, [0, 0, 1.0])
    assert est.ground is not None  # the floor along the given up is kept (framing)
    est = estimate_scene_up(pts, w, c, r, ViewConfig(up=(1, 0, 0)))
    assert est.source == UpSource.OVERRIDE and est.ground is None


def test_framed_camera_fills_centres_and_keeps_up():
    up = np.array([0, 0, 1.0])
    pts, w, c, r = _floor_and_box(up, floor_half=0.8)
    layout = layout_from_points(pts, w, c, r)
    assert layout.floor is not None
    intr = plan_anchors(c, r, None).candidates[0].camera
    for el in (10.0, 35.0, 60.0):
        for az in (0.0, 100.0, 230.0):
            a, e = math.radians(az), math.radians(el)
            d = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
            cam = framed_camera(layout, d, intr)
            fill, du, dv = view_fill(cam, layout, 0.02)
            assert fill == pytest.approx(0.65, abs=0.02)
            assert abs(du) < 0.02 and abs(dv) < 0.02
            assert abs(cam.right @ up) < 1e-9 and cam.up @ up > 0  # no roll, upright
            assert layout.height(cam.center) > 0  # above the ground
            assert angle_deg(-cam.forward, d) < 1e-6  # looks along the direction


def test_plan_with_layout_stays_above_the_ground_and_frames_manual_directions():
    up = np.array([0, 0, 1.0])
    pts, w, c, r = _floor_and_box(up, floor_half=0.8)
    layout = layout_from_points(pts, w, c, r)
    cfg = ViewConfig()
    plan = plan_anchors(c, r, None, layout=layout, config=cfg)
    assert plan.scene_up is layout.up and plan.to_dict()["scene_up"]["source"] == "ground"
    for a in plan.candidates:
        el = math.degrees(math.asin(a.direction @ up))
        assert cfg.ground_min_elevation_deg - 1e-9 <= el <= cfg.ground_max_elevation_deg + 1e-9
        assert layout.height(a.camera.center) > 0
    # a user-chosen direction from below the floor is raised to the minimum elevation
    cam = plan.frame_direction(np.array([1.0, 0.0, -1.0]))
    el = math.degrees(math.asin(-cam.forward @ up))
    assert el == pytest.approx(cfg.ground_min_elevation_deg, abs=1e-6)
    assert view_fill(cam, layout, 0.02)[0] == pytest.approx(0.65, abs=0.02)
    with pytest.raises(ValueError):
        plan.frame_direction(np.zeros(3))

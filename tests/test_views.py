"""Anchor views: Fibonacci pool, ranking, up direction, 2DGS radii (paper Sec. 3.2, App. C)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from divas_engine.camera import Camera
from divas_engine.views import (
    ViewConfig,
    estimate_up,
    fibonacci_sphere,
    gs_anchor_radii,
    plan_anchors,
    rank_directions,
    training_anchor,
)


def _rot(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def _cam(eye, target, up, name=""):
    return Camera.look_at(eye, target, up, width=64, height=48, fx=60.0, name=name)


def _angle(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


# ----------------------------------------------------------------------------- Fibonacci
@pytest.mark.parametrize("n", [12, 50, 200])
def test_fibonacci_unit_and_uniform(n):
    d = fibonacci_sphere(n)
    assert d.shape == (n, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # eq:fib: golden-angle azimuth steps, equal-area heights (half-index offset, see module)
    az = np.arctan2(d[:, 1], d[:, 0])
    step = np.degrees(np.mod(np.diff(az), 2 * np.pi))
    np.testing.assert_allclose(step, 360.0 / ((1 + 5**0.5) / 2) % 360.0, atol=1e-9)
    np.testing.assert_allclose(d[:, 2], 1 - 2 * (np.arange(n) + 0.5) / n, atol=1e-12)
    # uniformity against the equal-area cap radius rho = arccos(1 - 2/N)
    rho = math.degrees(math.acos(1 - 2 / n))
    c = d @ d.T
    np.fill_diagonal(c, -1.0)
    min_sep = math.degrees(math.acos(c.max()))
    q = np.random.default_rng(0).normal(size=(50_000, 3))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    covering = math.degrees(math.acos((q @ d.T).max(1).min()))
    assert min_sep >= 1.3 * rho  # no clustering (random points: ≪ rho)
    assert covering <= 1.5 * rho  # no holes (any set: ≥ rho)
    assert np.linalg.norm(d.mean(0)) < 0.05


# ----------------------------------------------------------------------------- ranking
def test_ranking_hand_computed():
    d = np.array([[0.6, 0.0, 0.8], [0.8, 0.6, 0.0], [0.0, -0.6, -0.8], [0.28, 0.96, 0.0]])
    r = rank_directions(d)
    # D_i = mean over j≠i of (1 − d_i·d_j); dots: 01 .48, 02 −.64, 03 .168, 12 −.36, 13 .8, 23 −.576
    D = np.array([2.992, 2.08, 4.576, 2.608]) / 3
    np.testing.assert_allclose(r.D_raw, D, atol=1e-12)
    # C_i: nearest axes +z, +x, −z (distance √0.4) and +y (√0.08)
    np.testing.assert_allclose(r.C_raw, [1 / 0.4**0.5] * 3 + [1 / 0.08**0.5], rtol=1e-5)
    # P_i = |elevation| / 90°, elevation asin(±0.8) = ±53.13°
    p = math.degrees(math.asin(0.8)) / 90
    np.testing.assert_allclose(r.P_raw, [p, 0, p, 0], atol=1e-12)
    # min–max normalisation
    np.testing.assert_allclose(r.D, [0.304 / 0.832, 0, 1, 0.176 / 0.832], atol=1e-9)
    np.testing.assert_allclose(r.C, [0, 0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(r.P, [1, 0, 1, 0], atol=1e-12)
    score = np.array([0.4 * 0.304 / 0.832 + 0.3, 0.0, 0.4 + 0.3, 0.4 * 0.176 / 0.832 + 0.3])
    np.testing.assert_allclose(r.score, score, atol=1e-6)
    assert r.order.tolist() == [2, 0, 3, 1]


def test_ranking_weights_come_from_config():
    d = fibonacci_sphere(12)
    r = rank_directions(d, ViewConfig(w_diversity=0.0, w_cardinal=0.0, w_pitch=1.0))
    np.testing.assert_allclose(r.score, r.P)
    assert abs(d[r.order[0], 2]) == pytest.approx(np.abs(d[:, 2]).max())


# ----------------------------------------------------------------------------- up direction
def _ring(R, center, radius, elevations, counts, rng, jitter=0.0):
    up = R @ np.array([0, 0, 1.0])
    cams = []
    for e, n in zip(elevations, counts):
        for a in np.linspace(0, 360, n, endpoint=False) + 7 * e:
            aa, ee = math.radians(a), math.radians(e + jitter * rng.uniform(-1, 1))
            local = radius * np.array(
                [math.cos(ee) * math.cos(aa), math.cos(ee) * math.sin(aa), math.sin(ee)]
            )
            cams.append(
                _cam(center + R @ local, center + jitter * 0.05 * rng.uniform(-1, 1, 3), up)
            )
    return cams


def test_up_recovered_on_tilted_ring():
    rng = np.random.default_rng(3)
    R = _rot([0.3, -1.0, 0.4], 37.0)
    center = np.array([1.0, -2.0, 0.5])
    cams = _ring(R, center, 4.0, [5, 25], [24, 16], rng, jitter=1.0)
    est = estimate_up(cams)
    assert not est.forward_facing
    assert _angle(est.up, R @ [0, 0, 1.0]) < 2.0


def test_up_plane_refinement_on_half_ring():
    # a half ring looking down: the mean camera up leans towards the centre; the plane does not
    R = _rot([1.0, 1.0, 0.0], 20.0)
    up = R @ [0, 0, 1.0]
    cams = []
    for a in np.linspace(-160, -20, 15):
        local = 3.0 * np.array(
            [
                math.cos(math.radians(25)) * math.cos(math.radians(a)),
                math.cos(math.radians(25)) * math.sin(math.radians(a)),
                math.sin(math.radians(25)),
            ]
        )
        cams.append(_cam(R @ local, np.zeros(3), up))
    est = estimate_up(cams)
    assert not est.forward_facing and est.plane_used
    assert _angle(est.mean_up, up) > 10.0
    assert _angle(est.up, up) < 2.0


def test_forward_facing_detected():
    up = np.array([0, 0, 1.0])
    cams = [_cam([x, -3.0, z], [0.1 * x, 0, 0.1 * z], up) for x in (-1, 0, 1) for z in (-0.5, 0.5)]
    est = estimate_up(cams)
    assert est.forward_facing and not est.plane_used
    assert _angle(est.up, up) < 5.0


# ----------------------------------------------------------------------------- 2DGS radius
def _dir(deg):
    return np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg)), 0.0])


def test_gs_radius_hand_made_rig():
    # cameras at 0°, 10°, …, 40° (distances 2..6) and one at 90° (distance 10)
    centres = np.array(
        [_dir(a) * r for a, r in [(0, 2), (10, 3), (20, 4), (30, 5), (40, 6), (90, 10)]]
    )
    dirs = np.array([_dir(0), _dir(90), _dir(180)])
    r, r_knn, r_cap, uns = gs_anchor_radii(dirs, np.zeros(3), centres)
    # +x: 5 nearest = 0..40° → mean 4; cone 45° holds the same five → P90 = 2 + 0.9·4 = 5.6
    np.testing.assert_allclose([r_knn[0], r_cap[0], r[0]], [4.0, 5.6, 4.0])
    # +y: nearest 90°, 40°, 30°, 20°, 10° → (10+6+5+4+3)/5 = 5.6; only the 90° camera in cone
    np.testing.assert_allclose([r_knn[1], r_cap[1], r[1]], [5.6, 10.0, 5.6])
    # −x: nothing within 45° → unsupported, placed at r_knn
    assert uns.tolist() == [False, False, True]
    assert np.isinf(r_cap[2]) and r[2] == pytest.approx(5.6)


def test_gs_radius_cap_binds():
    centres = np.array([_dir(0) * 2, _dir(10) * 2, _dir(90) * 20, _dir(100) * 20, _dir(110) * 20])
    r, r_knn, r_cap, uns = gs_anchor_radii(_dir(0)[None], np.zeros(3), centres)
    np.testing.assert_allclose([r_knn[0], r_cap[0], r[0]], [12.8, 2.0, 2.0])
    assert not uns[0]


def test_plan_anchors_360_unsupported_and_all():
    rng = np.random.default_rng(1)
    # a half ring on the −y side: directions towards +y are unsupported
    cams = [
        _cam(4 * _dir(a) + [0, 0, 0.8 * rng.uniform()], np.zeros(3), [0, 0, 1.0])
        for a in np.linspace(-170, -10, 30)
    ]
    plan = plan_anchors(np.zeros(3), 1.0, cams, kind="2dgs")
    assert not plan.forward_facing and len(plan.anchors) == 5
    assert all(a.source == "fibonacci" and not a.unsupported for a in plan.anchors)
    uns = [a for a in plan.candidates if a.unsupported]
    assert any(a.direction @ [0, 1.0, 0] > 0.7 for a in uns)
    u = np.stack([c.center / np.linalg.norm(c.center) for c in cams])
    for a in plan.candidates:  # unsupported ⇔ no camera within 45° of the direction
        assert a.unsupported == bool((u @ a.direction).max() < math.cos(math.radians(45)))
    scores = [a.score for a in plan.anchors]
    assert scores == sorted(scores, reverse=True)
    everything = plan_anchors(np.zeros(3), 1.0, cams, kind="2dgs", all_views=True)
    assert len(everything.anchors) == 12 and any(a.unsupported for a in everything.anchors)
    # NeRF: one global radius, the median camera distance; nothing unsupported
    nerf = plan_anchors(np.zeros(3), 1.0, cams, kind="nerf")
    med = np.median([np.linalg.norm(c.center) for c in cams])
    np.testing.assert_allclose([a.radius for a in nerf.candidates], med)
    assert not any(a.unsupported for a in nerf.candidates)
    # anchor cameras look at c_scene with image-up = scene up, median-fx intrinsics
    for a in plan.candidates:
        uv, z = a.camera.project(np.zeros((1, 3)))
        np.testing.assert_allclose(uv[0], [a.camera.cx, a.camera.cy], atol=1e-6)
        assert z[0] == pytest.approx(a.radius)
        assert a.camera.up @ plan.up > 0 and abs(a.camera.right @ plan.up) < 1e-9
        assert (a.camera.width, a.camera.fx) == (64, 60.0)


def test_plan_anchors_forward_facing_uses_training_cameras():
    up = np.array([0, 0, 1.0])
    cams = [
        _cam([x, -3.0, z], [0, 0, 0], up, f"c{i}")
        for i, (x, z) in enumerate((x, z) for x in (-1, -0.5, 0, 0.5, 1) for z in (-0.5, 0.5))
    ]
    plan = plan_anchors(np.zeros(3), 1.0, cams)
    assert plan.forward_facing
    assert len(plan.anchors) == 5 and all(a.source == "training" for a in plan.anchors)
    assert len({a.index for a in plan.anchors}) == 5
    assert plan.anchors[0].camera is cams[plan.anchors[0].index]
    a = training_anchor(cams, "c3", np.zeros(3))
    assert a.camera is cams[3] and a.source == "training" and math.isnan(a.score)
    with pytest.raises(KeyError):
        training_anchor(cams, "nope", np.zeros(3))
    assert len(plan_anchors(np.zeros(3), 1.0, cams, all_views=True).anchors) == 5 + 12


def test_plan_anchors_camera_free():
    c = np.array([1.0, 2.0, 3.0])
    plan = plan_anchors(c, 2.0, None)
    assert plan.camera_free and len(plan.anchors) == 5
    # without a scene layout: the capture convention (COLMAP-trained: -y), ViewConfig.up wins
    np.testing.assert_allclose(plan.up, [0, -1.0, 0])
    plan_z = plan_anchors(c, 2.0, None, config=ViewConfig(up=(0, 0, 2.0)))
    np.testing.assert_allclose(plan_z.up, [0, 0, 1.0])
    for a in plan.candidates:
        assert a.radius == pytest.approx(5.0) and not a.unsupported
        assert (a.camera.width, a.camera.height, a.camera.fx) == (640, 480, 600.0)
        np.testing.assert_allclose(np.linalg.norm(a.camera.center - c), 5.0)
    d = plan.to_dict()
    assert d["anchors"][0]["camera"]["width"] == 640 and d["anchors"][0]["source"] == "fibonacci"
    plan_y = plan_anchors(c, 2.0, [], up=np.array([0, -1.0, 0]))
    assert all(a.camera.up @ [0, -1.0, 0] > 0 for a in plan_y.candidates)


def test_cli_anchors(tmp_path):
    import argparse
    import json

    from divas_engine.cli import anchors as cli
    from divas_engine.synthetic import generate_scene

    generate_scene("occluded", tmp_path / "s", size=3000, seed=0)
    p = argparse.ArgumentParser()
    cli.add_parser(p.add_subparsers())
    args = p.parse_args(
        [
            "anchors",
            str(tmp_path / "s" / "scene.ply"),
            "--out",
            str(tmp_path / "out"),
            "--device",
            "cpu",
            "--scale",
            "0.1",
        ]
    )
    assert args.func(args) == 0
    doc = json.loads((tmp_path / "out" / "anchors.json").read_text())
    assert len(doc["anchors"]) == 5
    for a in doc["anchors"]:
        Camera.from_dict(a["camera"])
        assert {"direction", "score", "unsupported", "source"} <= set(a)
        assert (tmp_path / "out" / a["image"]).is_file()

"""Prompts in 3D: world points in a prompts file become clicks on anchors that see them.

The choice of anchors is checked on an analytic scene (cameras looking straight down
at the plane z = 0, depth maps written by hand: the plane at the camera's height, a box
in front of part of it), the end-to-end path on a generated scene against its ground
truth, and ``divas session export-points`` against the clicks' own geometry.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import divas_engine.cli as cli
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.evaluation import demo_prompts
from divas_engine.session import load_prompts
from divas_engine.session.point_prompts import session_points
from divas_engine.session.prompts import parse_prompts
from divas_engine.synthetic import generate_scene
from divas_engine.views.point_anchors import PointAnchorConfig, choose_point_anchors, points_seen

W, H, F, HEIGHT = 64, 48, 50.0, 4.0


def _down(x: float, y: float, name: str, height: float = HEIGHT) -> Camera:
    """A camera at (x, y, height) looking down -z (image x along +x, image y along -y)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.diag([1.0, -1.0, -1.0])
    c2w[:3, 3] = (x, y, height)
    return Camera(W, H, F, F, W / 2, H / 2, c2w, name)


def _pixel(cam: Camera, p) -> tuple[float, float]:
    """Analytic projection of a world point for a :func:`_down` camera."""
    cx, cy, h = cam.c2w[:3, 3]
    z = h - p[2]
    return (F * (p[0] - cx) / z + W / 2, F * -(p[1] - cy) / z + H / 2)


def _depth(cam: Camera, box=None) -> np.ndarray:
    """The plane z = 0 at the camera's height; ``box`` = (x0, x1, y0, y1, top): a box
    whose top face hides the plane below it."""
    d = np.full((H, W), cam.c2w[2, 3])
    if box is not None:
        x0, x1, y0, y1, top = box
        for j in range(H):
            for i in range(W):
                # the pixel's ray meets the plane z = top at (x, y)
                z = cam.c2w[2, 3] - top
                x = cam.c2w[0, 3] + (i + 0.5 - W / 2) * z / F
                y = cam.c2w[1, 3] - (j + 0.5 - H / 2) * z / F
                if x0 <= x <= x1 and y0 <= y <= y1:
                    d[j, i] = z
    return d


def _run(points, positive, cams, depths, **kw):
    calls = []

    def depth_of(i):
        calls.append(i)
        return cams[i], depths[i]

    out = choose_point_anchors(np.array(points, float), np.array(positive), cams, depth_of, **kw)
    return out, calls


def test_points_seen_by_depth_agreement():
    cam = _down(0, 0, "a")
    pts = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 1.0], [0.5, 0.5, -1.0], [40, 0, 0], [0, 0, 5]])
    d = _depth(cam)
    uv, seen = points_seen(cam, d, pts, tol=0.05)
    # on the surface; floating 1 in front of it; 1 behind it (hidden); outside; behind the camera
    assert seen.tolist() == [True, False, False, False, False]
    np.testing.assert_allclose(uv[0], _pixel(cam, pts[0]), atol=1e-9)
    # inside the tolerance: 4 % of the depth behind the surface is still seen
    _, s = points_seen(cam, d, np.array([[0.5, 0.5, -0.16]]), tol=0.05)
    assert s.tolist() == [True]


def test_a_radius_lets_an_objects_centre_be_seen_through_its_own_surface():
    cam = _down(0, 0, "a")
    centre = np.array([[0.5, 0.5, 0.0]])  # a ball of radius 0.6 around it: its top is 0.6 nearer
    d = _depth(cam, (-5, 5, -5, 5, 0.6))
    assert points_seen(cam, d, centre, 0.05)[1].tolist() == [False]
    assert points_seen(cam, d, centre, 0.05, radius=np.array([0.6]))[1].tolist() == [True]
    # an occluder well in front of the ball is still one
    d = _depth(cam, (-5, 5, -5, 5, 2.0))
    assert points_seen(cam, d, centre, 0.05, radius=np.array([0.6]))[1].tolist() == [False]
    picked = choose_point_anchors(
        centre,
        np.array([True]),
        [cam],
        lambda i: (cam, _depth(cam, (-5, 5, -5, 5, 0.6))),
        radius=np.array([0.6]),
    )
    assert picked[0].clicks[0].point == 0


def test_an_occluded_camera_is_passed_over_and_the_cover_is_minimal():
    b, a, c = _down(0.3, 0, "b"), _down(0, 0, "a"), _down(6, 0, "c")
    box = (0.6, 1.4, -0.4, 0.4, 2.0)  # its top hides (1, 0, 0) from b, not from a
    cams, depths = [b, a, c], [_depth(b, box), _depth(a), _depth(c)]
    pts = [(1.0, 0.0, 0.0), (-1.0, 0.3, 0.0), (0.2, -0.2, 0.0)]
    picked, calls = _run(pts, [True, True, False], cams, depths)
    assert [p.candidate for p in picked] == [1]  # a alone sees both positive points
    assert 2 not in calls  # c sees none of them: never rendered
    clicks = {c.point: c for c in picked[0].clicks}
    assert set(clicks) == {0, 1, 2} and clicks[2].positive is False  # the negative seen there
    for j in (0, 1, 2):
        np.testing.assert_allclose(clicks[j].xy, _pixel(a, pts[j]), atol=1e-9)
    _, seen_b = points_seen(b, depths[0], np.array(pts), 0.05)
    assert seen_b.tolist() == [False, True, True]


def test_two_anchors_when_no_one_sees_every_point():
    a, c = _down(0, 0, "a"), _down(6, 0, "c")
    pts = [(0.5, 0.0, 0.0), (6.5, 0.0, 0.0), (3.0, 0.0, 0.0)]
    # (3, 0, 0) projects 3 * 50 / 4 = 37.5 px off both centres: outside both images
    picked, _ = _run(pts, [True, True, False], [a, c], [_depth(a), _depth(c)])
    assert sorted(p.candidate for p in picked) == [0, 1]
    owners = {c.point: p.candidate for p in picked for c in p.clicks}
    assert owners == {0: 0, 1: 1}  # the negative point is seen by neither: no click


def test_render_scale_clicks_are_in_full_resolution_pixels():
    a = _down(0, 0, "a")
    half = a.scaled(0.5)
    p = (0.7, -0.4, 0.0)
    picked = choose_point_anchors(
        np.array([p]), np.array([True]), [a], lambda i: (half, _depth(half))
    )
    np.testing.assert_allclose(picked[0].clicks[0].xy, _pixel(a, p), atol=1e-9)


def test_unseen_points_are_one_error_naming_them():
    a = _down(0, 0, "a")
    hidden = _depth(a, (0.1, 0.4, -0.2, 0.2, 2.0))  # hides (0.5, 0, 0): its ray is at x=0.25
    with pytest.raises(DivasInputError, match=r"p.json: points\[1\]: no anchor sees .*hidden"):
        _run([(0, 0, 0), (0.5, 0, 0)], [True, True], [a], [hidden], source="p.json")
    with pytest.raises(DivasInputError, match=r"points\[0\].*outside the image of all 1"):
        _run([(50, 0, 0)], [True], [a], [_depth(a)])
    many = [_down(0.01 * k, 0, f"c{k}") for k in range(5)]
    blocked = [_depth(c, (-1, 1, -1, 1, 2.0)) for c in many]
    with pytest.raises(DivasInputError, match="in the 2 rendered"):
        _run([(0, 0, 0)], [True], many, blocked, config=PointAnchorConfig(max_renders=2))


POINTS_DOC = {
    "version": 1,
    "points": [{"xyz": [1, 2, 3], "radius": 0.5}, {"xyz": [0, 0, 0], "positive": False}],
}


def test_points_parse_and_round_trip():
    p = parse_prompts(POINTS_DOC, "p.json")
    assert p.anchors == () and [q.positive for q in p.points] == [True, False]
    assert [q.radius for q in p.points] == [0.5, 0.0]
    assert parse_prompts(json.loads(json.dumps(p.to_dict()))).points == p.points


@pytest.mark.parametrize(
    "doc, says",
    [
        ({"version": 1, "points": [{"xyz": [1, 2]}]}, "points[0].xyz: must be three"),
        ({"version": 1, "points": [{"xyz": [1, 2, "a"]}]}, "points[0].xyz"),
        ({"version": 1, "points": [{"xyz": [1, 2, 3], "label": 1}]}, "points[0]: unknown keys"),
        ({"version": 1, "points": [{"xyz": [1, 2, 3], "positive": 1}]}, "points[0].positive"),
        ({"version": 1, "points": [{"xyz": [1, 2, 3], "radius": -1}]}, "points[0].radius"),
        ({"version": 1, "points": {"xyz": [1, 2, 3]}}, "points: must be a list"),
        ({"version": 1, "points": []}, "anchors: must be a non-empty list"),
    ],
)
def test_bad_points_name_the_entry(doc, says):
    with pytest.raises(DivasInputError) as e:
        parse_prompts(doc, "p.json")
    assert says in str(e.value)


def test_session_points_takes_one_objects_clicks():
    def click(a, k, xyz, pos=True):
        return {"anchor": a, "index": k, "xy": [1, 1], "positive": pos, "point": xyz}

    doc = {
        "objects": [
            {"index": 0, "clicks": {"0": [click(0, 0, [1, 1, 1])]}},
            {
                "index": 1,
                "clicks": {"2": [click(2, 0, [3, 3, 3])], "1": [click(1, 0, [2, 2, 2], False)]},
            },
            {"index": 2, "clicks": {}},
        ]
    }
    last = session_points(doc, source="s.json")
    assert [(p.xyz, p.positive) for p in last.points] == [((2, 2, 2), False), ((3, 3, 3), True)]
    assert [p.xyz for p in session_points(doc, 0).points] == [(1, 1, 1)]
    with pytest.raises(DivasInputError, match="no object 5"):
        session_points(doc, 5)
    with pytest.raises(DivasInputError, match="holds no click"):
        session_points(doc, 2)


@pytest.fixture(scope="module")
def ribs(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs_points")
    sc = generate_scene("ribs", out, size=20_000, seed=0, grid_resolution=64)
    demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(out / "prompts.json")
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def test_exported_clicks_segment_the_same_object_from_3d_points(ribs, tmp_path, capsys):
    common = ["--scale", "0.5", "--no-progress", "--device", "cpu"]
    assert (
        cli.main(
            ["segment", str(ribs / "scene.ply"), "--prompts", str(ribs / "prompts.json")]
            + ["--out", str(tmp_path / "a.ply"), "--labels-out", str(tmp_path / "a.npy")]
            + ["--session", str(tmp_path / "s.json"), *common]
        )
        == 0
    )
    assert (
        cli.main(
            [
                "session",
                "export-points",
                str(tmp_path / "s.json"),
                "--out",
                str(tmp_path / "pts.json"),
            ]
        )
        == 0
    )
    assert "positive" in capsys.readouterr().out
    pts = load_prompts(tmp_path / "pts.json")
    saved = json.loads((tmp_path / "s.json").read_text())
    # every exported point is its click's back-projection: it projects onto the click
    clicks = [(int(a), c) for a, cs in saved["objects"][-1]["clicks"].items() for c in cs]
    assert len(pts.points) == len(clicks) > 0
    for (a, c), p in zip(clicks, pts.points):
        cam = Camera.from_dict(saved["anchors"][a]["camera"]).scaled(0.5)
        uv, z = cam.project(np.array([p.xyz]))
        assert z[0] > 0 and np.allclose(uv[0], c["xy"], atol=1e-6)
    assert (
        cli.main(
            ["segment", str(ribs / "scene.ply"), "--prompts", str(tmp_path / "pts.json")]
            + ["--out", str(tmp_path / "b.ply"), "--labels-out", str(tmp_path / "b.npy")]
            + ["--report", str(tmp_path / "b.json"), *common]
        )
        == 0
    )
    rep = json.loads((tmp_path / "b.json").read_text())
    assert len(rep["points"]) == len(pts.points) and all(q["clicks"] for q in rep["points"])
    assert rep["counts"]["accepted"] >= 1
    gt = np.load(ribs / "labels.npy")
    a, b = np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy")
    # the same object: as good against the truth as the pixel clicks, and mostly the same
    assert _iou(b, gt) >= _iou(a, gt) - 0.1 and _iou(a, b) > 0.7

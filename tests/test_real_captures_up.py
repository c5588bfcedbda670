"""Camera-free up and anchors on the shared real captures.

True ups, determined by eye on renders (tests/data/targets/<capture>/targets.json,
``true_up_note`` says how): biker (compressed PLY and SPZ) and guitar −y, the three
GaussianSplats3D LOD tiles +z. Captures: tests/data (playcanvas/engine @ 0aaef5e, MIT;
mkkellogg/GaussianSplats3D PR 477, MIT).

Each default anchor is checked on its own render (tests/framing_checks.py), not on the
sample the framing code uses: upright (the true up projects to image-up within 10°, no
roll), the object's rendered extent ≥ 40 % of the larger image side and inside the
frame, centred within 15 % of the image side, the camera above the ground.
"""

from __future__ import annotations

import json
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from divas_engine.evaluation.real_target_defs import CAPTURES
from divas_engine.io.load import load_scene
from divas_engine.render import make_renderer
from divas_engine.views import UpSource, plan_scene_anchors
from tests.framing_checks import angle_deg, image_up_angle_deg, rendered_framing

DATA = Path(__file__).parent / "data"


@cache
def _scene(name: str):
    return load_scene(DATA / CAPTURES[name].path)


@cache
def _plan(name: str):
    return plan_scene_anchors(_scene(name), [])


def _true_up(name: str) -> np.ndarray:
    doc = json.loads((DATA / "targets" / name / "targets.json").read_text())
    assert doc["true_up"] == list(CAPTURES[name].true_up)
    return np.asarray(doc["true_up"], np.float64)


@pytest.mark.parametrize("capture", list(CAPTURES))
def test_estimated_up_within_10_degrees(capture):
    plan = _plan(capture)
    su = plan.scene_up
    assert su is not None and su.source == UpSource.GROUND
    assert angle_deg(su.up, _true_up(capture)) <= 10.0
    assert 0.5 < su.confidence <= 1.0 and su.reason


@pytest.mark.parametrize("capture", list(CAPTURES))
def test_default_anchors_frame_the_object_upright(capture):
    plan, up = _plan(capture), _true_up(capture)
    ren = make_renderer(_scene(capture), device="cpu")
    assert len(plan.anchors) == 5
    for a in plan.anchors:
        cam = a.camera
        assert abs(cam.right @ plan.up) < 1e-9  # no roll about the estimated up
        assert angle_deg(cam.up, up) <= 75.0  # looks at most 60° down (+ estimate error)
        look_at = cam.center + cam.forward * a.radius
        tilt = image_up_angle_deg(cam, look_at, up)
        assert np.isnan(tilt) or tilt <= 10.0, (a.camera.name, tilt)
        if plan.layout.floor is not None:
            assert plan.layout.height(cam.center) > 0
        fr = rendered_framing(ren.render(cam, 0.25).alpha)
        assert fr.fill_larger_side >= 0.4, (cam.name, fr)
        assert fr.fill_x <= 0.98 and fr.fill_y <= 0.98, (cam.name, fr)
        assert abs(fr.offset_x) <= 0.15 and abs(fr.offset_y) <= 0.15, (cam.name, fr)


def test_manual_anchor_direction_is_framed_like_the_default_ones():
    plan, up = _plan("guitar"), _true_up("guitar")
    ren = make_renderer(_scene("guitar"), device="cpu")
    cam = plan.frame_direction(np.array([0.3, 0.8, -0.5]))  # from below the floor
    assert plan.layout.height(cam.center) > 0
    assert abs(cam.right @ up) < 1e-9
    fr = rendered_framing(ren.render(cam, 0.25).alpha)
    assert fr.fill_larger_side >= 0.4 and abs(fr.offset_x) <= 0.15


def _cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "divas_engine", *args], capture_output=True, text=True, timeout=600
    )


def test_cli_reports_the_up_and_takes_an_override(tmp_path):
    scene = DATA / CAPTURES["lod3"].path
    r = _cli("info", str(scene), "--json")
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout.strip().splitlines()[-1])
    assert info["up"] == [0.0, 0.0, 1.0] and info["up_source"] == "ground"
    assert 0.5 < info["up_confidence"] <= 1.0
    r = _cli("anchors", str(scene), "--no-render", "--up", "0,0,2", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "override" in r.stdout
    doc = json.loads((tmp_path / "anchors.json").read_text())
    assert doc["scene_up"]["source"] == "override" and doc["up"] == [0.0, 0.0, 1.0]
    r = _cli("anchors", str(scene), "--no-render", "--up", "0,0,0", "--out", str(tmp_path))
    assert r.returncode != 0 and "--up" in r.stderr


def test_segment_up_override_reaches_the_planned_anchors(tmp_path):
    from divas_engine.cli.segment import segment_scene
    from divas_engine.segment_request import SegmentRequest

    prompts = tmp_path / "prompts.json"
    prompts.write_text(
        json.dumps({"version": 1, "anchors": [{"fibonacci": 0, "clicks": [{"xy": [320, 240]}]}]})
    )
    scene = DATA / CAPTURES["lod3"].path
    cams = {}
    for up in (None, (0.0, 0.0, -1.0)):
        _, s = segment_scene(
            SegmentRequest(scene, prompts, scale=0.25, device="cpu", up=up),
            progress=False,
            keep_session=True,
        )
        try:
            cams[up] = s.anchors[0].full_camera
        finally:
            s.close()
    for up, want in ((None, [0, 0, 1.0]), ((0.0, 0.0, -1.0), [0, 0, -1.0])):
        cam = cams[up]  # estimated: +z; then the override -z
        assert cam.up @ np.array(want) > 0.3 and abs(cam.right @ np.array(want)) < 1e-9

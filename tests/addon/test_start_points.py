"""Start DivAS from a prompts file that gives 3D points: the session offers the anchors
the engine picked for them (each sees its points), and the Blender script, which clicks
a file's anchors through the operators, refuses such a file with one line."""

from __future__ import annotations

import json
import subprocess
import sys

import bpy
import numpy as np
import pytest

from blender_addon import session_registry

from .conftest import REPO


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_points_addon")
    sc = generate_scene("ribs", out, size=15_000, seed=0, grid_resolution=32)
    xyz = [c["xyz"] for c in sc.metadata["clicks"][:2]]
    doc = {"version": 1, "points": [{"xyz": list(map(float, p))} for p in xyz]}
    (out / "points.json").write_text(json.dumps(doc))
    return out, np.array(xyz, float)


def test_start_offers_anchors_that_see_the_points(scene_dir):
    out, xyz = scene_dir
    bpy.ops.divas.import_splats(filepath=str(out / "scene.ply"), display=False)
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = 0.5
    bpy.context.scene.divas.autosave = False
    assert bpy.ops.divas.start_session(device="cpu", prompts=str(out / "points.json")) == {
        "FINISHED"
    }
    anchors = session_registry.get(obj).session.anchors
    assert 1 <= len(anchors) <= len(xyz)
    assert all(a.source == "training" for a in anchors)
    for p in xyz:  # every point projects inside some anchor, in front of it
        seen = False
        for a in anchors:
            uv, z = a.camera.project(p[None])
            seen |= bool(a.camera.in_image(uv, z)[0])
        assert seen


def test_blender_script_refuses_points(scene_dir, tmp_path):
    out, _ = scene_dir
    r = subprocess.run(
        [sys.executable, str(REPO / "blender_scripts" / "segment.py"), "--"]
        + ["--scene", str(out / "scene.ply"), "--prompts", str(out / "points.json")]
        + ["--out", str(tmp_path / "o.ply"), "--device", "cpu"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1 and "3D 'points' are clicked by `divas segment`" in r.stderr
    assert "Traceback" not in r.stderr

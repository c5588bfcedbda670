"""A 3DGS session with the completion, saved and replayed: the replay reads the
segmenter's raw masks from the file (the completion's evidence), so its labels equal
the live session's exactly — after an undo and a re-accept too."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine import load_scene
from divas_engine.kinds import SceneKind
from divas_engine.segment import OracleSegmenter
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene


@pytest.fixture(scope="module")
def ribs3d(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs3d")
    sc = generate_scene("ribs", out, size=6_000, seed=0, kind="3dgs")
    scene = load_scene(out / "scene.ply")
    names = [c.name for c in sc.cameras]
    anchors, clicks = [], []
    for c in sc.metadata["clicks"][:3]:
        vis = c["visible_in"]
        anchors.append(sc.cameras[names.index(vis[len(vis) // 2])])
        clicks.append(np.array(c["xyz"]))
    return sc, scene, anchors, clicks


def test_replay_with_raw_masks_equals_live(ribs3d, tmp_path):
    sc, scene, anchors, clicks = ribs3d
    assert scene.kind == SceneKind.GS3D
    s = Session.open(
        scene,
        sc.cameras,
        SessionConfig(render_scale=0.5, seed=0),
        OracleSegmenter(),
        "cpu",
        anchors=anchors,
        gt_values=sc.labels,
        render_anchors=False,
    )
    views = []
    for i, xyz in enumerate(clicks):
        uv, _ = s.anchors[i].camera.project(xyz[None])
        views.append(s.click(i, uv[0]))
    for v in views:
        s.accept(v)
    s.undo()  # the last accept, then again: the completion's records follow exactly
    s.accept(views[-1])
    comp = s.backend.last_completion
    assert comp is not None and comp.counts()["contrib_added"] + comp.counts()["fill_added"] > 0
    live = s.selection.copy()
    # the raw masks differ from the depth-weighted ones the fusion stored
    assert any(not np.array_equal(v.preview.selection.mask >= 0.5, v.mask >= 0.5) for v in views)
    path = s.save(tmp_path / "s.json")
    s.close()
    s2 = Session.load(path, scene, device="cpu")
    assert s2.replay_matches and np.array_equal(s2.selection, live)
    assert all(v.preview is None and v.raw_mask is not None for v in s2.views)
    s2.close()
    # an older file without the raw masks replays on the fused masks: another selection
    # (what the stored raw masks are for)
    from divas_engine.session.store import load_state

    doc, arrays = load_state(path)
    s3 = Session.load(path, scene, device="cpu")
    for v in s3.views:
        v.raw_mask = None
    s3.backend._evidence.clear()
    s3.backend._completion = None
    s3._update_selection()
    assert not np.array_equal(s3.selection, live)
    fused = [v for v in s3.views if v.status == "fused"]  # with the wider views
    assert len(fused) >= len(views) and sum(k.startswith("raw_") for k in arrays) == len(fused)
    s3.close()

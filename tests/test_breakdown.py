"""The error breakdown by source of a completed 3DGS selection (diagnostics,
:mod:`divas_engine.evaluation.breakdown`): hand-made cases with the sums written out, and
a scripted 3DGS session whose parts must rebuild its selection."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.evaluation.breakdown import completion_sources, source_breakdown


def test_breakdown_by_hand():
    #            0     1     2     3     4     5     6     7
    sel = np.array([1, 1, 1, 1, 1, 0, 0, 1], bool)
    gt = np.array([1, 0, 1, 0, 1, 1, 0, 0], bool)
    w = np.array([0.5, 0.25, 1.0, 0.125, 2.0, 0.75, 3.0, 0.0625])
    src = {
        "paper": np.array([1, 1, 0, 0, 0, 0, 0, 0], bool),
        "contribution": np.array([0, 0, 1, 1, 0, 0, 0, 0], bool),
        "fill": np.array([0, 0, 0, 0, 1, 0, 0, 0], bool),
    }
    br = source_breakdown(sel, gt, w, src)
    # Gaussian 7 is selected but in no source: "other"
    assert list(br) == ["paper", "contribution", "fill", "other", "missed"]
    assert br["paper"] == {
        "tp": 1,
        "fp": 1,
        "tp_w": 0.5,
        "fp_w": 0.25,
        # without 1: S = {0,2,3,4,7}, G = {0,2,4,5}: (0.5+1+2) / (0.5+1+0.125+2+0.75+0.0625)
        "iou_without_fp": 3.5 / 4.4375,
    }
    assert br["contribution"]["tp"] == 1 and br["contribution"]["fp"] == 1
    assert br["contribution"]["fp_w"] == 0.125
    assert br["contribution"]["iou_without_fp"] == pytest.approx(3.5 / 4.5625)
    fill = {"tp": 1, "fp": 0, "tp_w": 2.0, "fp_w": 0.0, "iou_without_fp": 3.5 / 4.6875}
    assert br["fill"] == fill
    assert br["other"]["fp"] == 1 and br["other"]["fp_w"] == 0.0625
    assert br["missed"] == {"fn": 1, "fn_w": 0.75}
    with pytest.raises(ValueError):
        source_breakdown(sel, gt, w[:-1], src)


def test_completion_sources_partition():
    mapped = np.array([1, 1, 1, 0, 0, 0], bool)
    dropped = np.array([0, 1, 0, 0, 0, 0], bool)
    contrib = np.array([0, 0, 0, 1, 0, 0], bool)
    fill = np.array([0, 0, 0, 1, 1, 0], bool)  # 3 is both: it counts as contribution
    src = completion_sources(mapped, contrib, fill, dropped)
    assert src["paper"].tolist() == [True, False, True, False, False, False]
    assert src["contribution"].tolist() == [False, False, False, True, False, False]
    assert src["fill"].tolist() == [False, False, False, False, True, False]


def test_session_parts_rebuild_the_selection():
    """On a 3DGS session the paper's selection less the drops, the contribution and the
    fill additions are disjoint and make up the session's selection exactly."""
    from divas_engine.evaluation.pipeline import make_segmenter, run_session, scripted_anchors
    from divas_engine.kinds import SceneKind
    from divas_engine.session import SessionConfig
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("ribs", None, size=6_000, seed=0, kind="3dgs")
    scene = sc.scene
    assert scene.kind == SceneKind.GS3D
    anchors = scripted_anchors(sc.metadata, sc.cameras)[:2]
    out = run_session(
        scene,
        sc.cameras,
        sc.labels,
        anchors,
        segmenter=make_segmenter("oracle"),
        config=SessionConfig(render_scale=0.5, seed=0),
        device="cpu",
    )
    assert out.completion_masks is not None
    m = out.completion_masks
    assert m["contrib_added"].any() or m["fill_added"].any()
    src = completion_sources(out.mapped, **m)
    total = np.zeros_like(out.selection)
    for part in src.values():
        assert not (total & part).any()
        total |= part
    assert np.array_equal(total, out.selection)
    w = np.asarray(scene.opacities, np.float64)
    br = source_breakdown(out.selection, sc.labels, w, src)
    assert "other" not in br
    parts = [v for k, v in br.items() if k != "missed"]
    assert sum(v["tp"] for v in parts) == (out.selection & sc.labels).sum()
    assert sum(v["fp"] for v in parts) == (out.selection & ~sc.labels).sum()

"""The NoC protocol (divas_engine.evaluation.noc): the simulated user's click on
hand-made error maps, the tie rules, NoC counting, the IoU with don't-care pixels, and
one short run through a session on a small synthetic scene."""

from __future__ import annotations

import numpy as np
import pytest

from divas_engine.evaluation.noc import (
    NocConfig,
    error_depth,
    ignoring_iou,
    next_click,
    number_of_clicks,
    run_noc,
    thresholds_for,
)
from divas_engine.kinds import SceneKind


def _rect(h, w, y0, y1, x0, x1):
    m = np.zeros((h, w), bool)
    m[y0:y1, x0:x1] = True
    return m


def test_error_depth_is_the_distance_to_the_border_and_the_image_edge():
    m = _rect(9, 9, 1, 8, 1, 8)  # 7 × 7 square
    d = error_depth(m)
    assert d[4, 4] == 4.0  # the centre: 4 pixels to the first pixel outside
    assert d[1, 1] == 1.0 and d[0, 0] == 0.0
    full = np.ones((5, 5), bool)  # the image edge counts as outside
    assert error_depth(full)[2, 2] == 3.0 and error_depth(full)[0, 2] == 1.0


def test_first_click_is_the_centre_of_the_target_on_the_anchor_where_it_is_deepest():
    t0 = _rect(40, 60, 10, 20, 10, 20)  # 10 × 10: depth 5
    t1 = _rect(40, 60, 5, 35, 20, 50)  # 30 × 30: depth 15, centre (35, 20)
    empty = np.zeros((40, 60), bool)
    c = next_click([t0, t1], [empty, empty])
    assert c.anchor == 1 and c.positive
    assert c.depth == 15.0
    # the first maximum in row-major order of the 30 × 30 square (rows 5..34, cols 20..49)
    assert c.xy == (34.5, 19.5)


def test_a_spill_deeper_than_the_miss_gets_a_negative_click_at_its_centre():
    truth = _rect(50, 50, 0, 50, 0, 10)  # the left strip
    pred = truth.copy()
    pred[2:5, 0:10] = False  # a 3-row miss: depth 2
    pred |= _rect(50, 50, 20, 41, 25, 46)  # a 21 × 21 spill: depth 11 at (35, 30)
    c = next_click([truth], [pred])
    assert not c.positive and c.anchor == 0 and c.depth == 11.0
    assert c.xy == (35.5, 30.5)


def test_ties_positive_first_then_the_lower_anchor():
    h, w = 30, 30
    sq = _rect(h, w, 5, 12, 5, 12)  # 7 × 7: depth 4
    sq2 = _rect(h, w, 15, 22, 15, 22)
    none = np.zeros((h, w), bool)
    # anchor 0: a spill of depth 4; anchor 1: a miss of depth 4 -> the positive wins
    c = next_click([none, sq], [sq2, none])
    assert c.positive and c.anchor == 1
    # two equal misses on anchors 0 and 1 -> anchor 0
    c = next_click([sq, sq], [none, none])
    assert c.anchor == 0 and c.positive


def test_no_error_no_click_and_dont_care_pixels_are_no_error():
    t = _rect(20, 20, 5, 15, 5, 15)
    assert next_click([t], [t.copy()]) is None
    pred = t | _rect(20, 20, 0, 20, 15, 20)  # a spill on the right strip
    assert not next_click([t], [pred]).positive
    ignore = _rect(20, 20, 0, 20, 15, 20)  # ... which is don't-care
    assert next_click([t], [pred], [ignore]) is None
    # the IoU leaves don't-care pixels out of both masks
    assert ignoring_iou(pred, t) == pytest.approx(100 / 200)  # a 20 × 5 spill beside 10 × 10
    assert ignoring_iou(pred, t, ignore) == 1.0
    assert ignoring_iou(np.zeros((3, 3), bool), np.zeros((3, 3), bool)) == 1.0


def test_number_of_clicks_counts_the_first_click_that_reaches_the_level():
    ious = [0.5, 0.86, 0.84, 0.91, 0.95]
    assert number_of_clicks(ious, 0.85) == 2
    assert number_of_clicks(ious, 0.90) == 4
    assert number_of_clicks(ious, 0.99) == 5  # never: the number of clicks (the cap)
    assert number_of_clicks(ious, 0.99, max_clicks=10) == 10
    assert number_of_clicks([0.9], 0.9) == 1


def test_thresholds_are_the_same_level_on_every_kind():
    class S:
        kind = SceneKind.GS3D

    class T:
        kind = SceneKind.GS2D

    assert thresholds_for(S()) == (0.5, 0.5)
    assert thresholds_for(T()) == (0.5, 0.5)  # a perfect selection scores 1.0 on 2DGS too
    assert thresholds_for(T(), NocConfig(pred_threshold=0.1)) == (0.1, 0.5)  # NOTES'
    assert thresholds_for(T(), NocConfig(pred_threshold=0.3)) == (0.3, 0.5)


def test_a_run_on_a_small_scene_with_the_oracle_reaches_high_iou(tmp_path):
    """Three clicks of the simulated user with the SAM-like oracle on the small occluded
    scene: the first click is positive on an anchor and fuses a view; the IoU rises
    from the empty selection's 0 and the run's records line up."""
    from divas_engine.evaluation.pipeline import make_segmenter
    from divas_engine.synthetic import generate_scene

    sc = generate_scene("occluded", size=6000, seed=0)
    run = run_noc(
        sc.scene,
        sc.cameras,
        sc.labels,
        sc.test_cameras[:3],
        segmenter=make_segmenter("oracle", 0),
        config=NocConfig(max_clicks=3, eval_scale=0.25),
    )
    assert len(run.ious) == len(run.clicks) == len(run.outcomes) == 3
    first = run.clicks[0]
    assert first is not None and first.positive
    assert run.outcomes[0] == "fused"
    assert run.ious[0] > 0.5
    assert max(run.ious) >= run.ious[0] - 1e-9 or run.outcomes[1] != "fused"
    d = run.as_dict()
    assert d["noc"]["0.85"] == number_of_clicks(run.ious, 0.85)


def test_every_scene_and_capture_is_in_one_half_of_the_split():
    from divas_engine.evaluation.noc_suite import (
        HELD_OUT_CAPTURES,
        HELD_OUT_SCENES,
        TUNING_CAPTURES,
        TUNING_SCENES,
        half_of,
        real_cases,
    )
    from divas_engine.evaluation.real_target_defs import CAPTURES
    from divas_engine.synthetic import SCENE_NAMES

    assert set(TUNING_SCENES) | set(HELD_OUT_SCENES) == set(SCENE_NAMES)
    assert not set(TUNING_SCENES) & set(HELD_OUT_SCENES)
    with_targets = {k for k, c in CAPTURES.items() if c.targets}
    assert set(TUNING_CAPTURES) | set(HELD_OUT_CAPTURES) == with_targets
    assert not set(TUNING_CAPTURES) & set(HELD_OUT_CAPTURES)
    halves = {c.name: c.half for c in real_cases()}
    assert halves["biker/helmet"] == halves["biker_spz/helmet"] == "held-out"
    assert halves["guitar/stand"] == "tuning" and half_of("ribs") == "tuning"
    with pytest.raises(ValueError):
        half_of("nowhere")


def test_eval_cli_noc_protocol_prints_one_row_per_case(capsys):
    import argparse
    import json

    from divas_engine.cli import evaluate

    p = argparse.ArgumentParser()
    evaluate.add_parser(p.add_subparsers())
    args = p.parse_args(
        ["eval", "--protocol", "noc", "--scenes", "occluded", "--size", "4000"]
        + ["--segmenters", "oracle", "--max-clicks", "2", "--eval-scale", "0.25"]
        + ["--json", "--quiet", "--device", "cpu"]
    )
    assert evaluate.run(args) == 0
    out = json.loads(capsys.readouterr().out)
    (row,) = out["rows"]
    assert row["case"] == "occluded/2dgs" and row["half"] == "held-out"
    assert len(row["ious"]) == 2 and row["segmenter"] == "oracle"
    assert out["summary"]["oracle|held-out"]["miou"] == row["ious"]

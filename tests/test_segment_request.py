"""``SegmentRequest``: one headless segmentation, built from ``divas segment``'s flags, the
Blender script's, or a manifest row — the same fields and checks every way."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from divas_engine.errors import DivasInputError
from divas_engine.segment.factory import SegmenterKind
from divas_engine.segment_request import (
    SEGMENTERS,
    SegmentRequest,
    add_request_arguments,
    request_path,
)


def _parse(argv, **kw):
    p = argparse.ArgumentParser()
    add_request_arguments(p, **kw)
    return SegmentRequest.from_args(p.parse_args(argv))


def test_segmenter_names_are_the_engines():
    assert set(SEGMENTERS) == {k.value for k in SegmenterKind}


def test_flags_give_the_dataclass_defaults():
    r = _parse(["s.ply", "--prompts", "p.json", "--out", "o.ply"])
    assert r == SegmentRequest(Path("s.ply"), Path("p.json"), out=Path("o.ply"))
    assert r.completion is True and r.up is None and r.lod is None and r.segmenter == "graph3d"


def test_every_flag_reaches_its_field():
    argv = (
        "s.ply --prompts p.json --out o.ply --labels-out l.npy --cameras c.json "
        "--segmenter classic --scale 0.5 --device cpu --seed 7 --mask-channel 2 "
        "--up 0,0,2 --no-completion --lod 1 --session s.json --resume --report r.json"
    )
    r = _parse(argv.split(" "))
    assert (r.labels_out, r.cameras, r.session, r.report) == tuple(
        map(Path, ("l.npy", "c.json", "s.json", "r.json"))
    )
    assert (r.segmenter, r.scale, r.device, r.seed, r.mask_channel) == ("classic", 0.5, "cpu", 7, 2)
    assert r.up == (0.0, 0.0, 1.0) and not r.completion and r.lod == 1 and r.resume


def test_a_host_may_leave_flags_out_and_name_the_scene_by_option():
    omit = frozenset({"resume", "up", "completion", "lod"})
    r = _parse(
        ["--scene", "s.ply", "--prompts", "p.json", "--out", "o"], scene_option=True, omit=omit
    )
    assert r.scene == Path("s.ply") and r.completion and r.up is None
    with pytest.raises(SystemExit):
        _parse(
            ["--scene", "s", "--prompts", "p", "--out", "o", "--lod", "1"],
            omit=omit,
            scene_option=True,
        )


def test_mapping_paths_types_and_unknown_keys(tmp_path):
    r = SegmentRequest.from_mapping(
        {
            "scene": "a/s.ply",
            "prompts": f"file://{tmp_path}/p.json",
            "seed": 3,
            "up": [0, 1, 0],
            "mask-channel": 0,
        },
        base=tmp_path,
    )
    assert r.scene == tmp_path / "a" / "s.ply" and r.prompts == tmp_path / "p.json"
    assert r.seed == 3 and r.up == (0.0, 1.0, 0.0) and r.mask_channel == 0
    assert SegmentRequest.from_mapping(r.to_dict()) == r  # the JSON form round-trips
    bad = [
        ({"scene": "s", "prompts": "p", "sede": 1}, "jobs[2].sede: unknown option"),
        ({"scene": "s", "prompts": "p", "seed": "1"}, "jobs[2].seed: must be an integer"),
        ({"scene": "s", "prompts": "p", "scale": -1}, "jobs[2]: --scale must be positive"),
        ({"scene": "s", "prompts": "p", "segmenter": "sam"}, "unknown segmenter 'sam'"),
        ({"scene": "s", "prompts": "p", "up": [0, 0, 0]}, "jobs[2].up: --up must be three"),
        ({"scene": "s"}, "jobs[2]: missing 'prompts'"),
        ({"scene": "s3://bucket/s.ply", "prompts": "p"}, "only paths and file:// URIs"),
    ]
    for values, says in bad:
        with pytest.raises(DivasInputError) as e:
            SegmentRequest.from_mapping(values, base=tmp_path, where="jobs[2]")
        assert says in str(e.value), (values, str(e.value))


def test_checks_before_any_work():
    with pytest.raises(DivasInputError, match="--resume needs --session"):
        SegmentRequest("s", "p", resume=True).check()
    with pytest.raises(DivasInputError, match="--scale must be positive"):
        SegmentRequest("s", "p", scale=float("nan")).check()
    assert SegmentRequest("s", "p", segmenter="sam_onnx").segmenter == "sam-onnx"


def test_paths_relative_to_a_base_and_home(tmp_path):
    assert request_path("x/y.ply", tmp_path, "w") == tmp_path / "x" / "y.ply"
    assert request_path("/abs/y.ply", tmp_path, "w") == Path("/abs/y.ply")
    assert request_path("file:///a%20b/y.ply", tmp_path, "w") == Path("/a b/y.ply")
    assert np.isclose(
        np.linalg.norm(_parse(["s", "--prompts", "p", "--out", "o", "--up", "3,4,0"]).up), 1
    )

"""The headless prompts file (NOTES "Headless prompts file", version 1).
Every malformed entry raises DivasInputError naming the entry."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from divas_engine import Camera, DivasInputError
from divas_engine.session import load_prompts, parse_prompts, resolve_anchors
from divas_engine.session.prompts import find_training_camera

NOTES_EXAMPLE = {
    "version": 1,
    "anchors": [
        {
            "camera": {
                "width": 800,
                "height": 600,
                "fx": 700,
                "fy": 700,
                "cx": 400,
                "cy": 300,
                "c2w": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
            },
            "clicks": [{"xy": [412.5, 300.0]}, {"xy": [200, 310]}],
        },
        {"training_camera": "IMG_0012", "clicks": [{"xy": [100, 90]}]},
        {"fibonacci": 2, "clicks": [{"xy": [320, 240]}]},
    ],
    "centroid_prompts": {"0:1": [{"xy": [410, 290], "positive": False}]},
}


def _train_cams():
    return [
        Camera(640, 480, 500, 500, 320, 240, np.eye(4), name=n)
        for n in ("IMG_0011.JPG", "IMG_0012.JPG", "IMG_0013.JPG")
    ]


def _fib():
    return [Camera(640, 480, 600, 600, 320, 240, np.eye(4), name=f"fib_{i:02d}") for i in range(12)]


def test_notes_example_parses_and_round_trips():
    p = parse_prompts(NOTES_EXAMPLE, "p.json")
    assert [a.kind for a in p.anchors] == ["camera", "training_camera", "fibonacci"]
    assert p.anchors[0].clicks[0].xy == (412.5, 300.0) and p.anchors[0].clicks[0].positive
    assert p.extra_points(0, 1)[0].positive is False
    again = parse_prompts(json.loads(json.dumps(p.to_dict())))
    assert again.to_dict() == p.to_dict()
    res = resolve_anchors(p, _train_cams(), _fib)
    assert res[1].source == "training" and res[1].index == 1  # name without extension
    assert res[2].camera.name == "fib_02" and res[0].source == "camera"


def _mut(fn):
    d = copy.deepcopy(NOTES_EXAMPLE)
    fn(d)
    return d


BAD = [
    (lambda d: d.update(extra=1), "unknown top-level keys"),
    (lambda d: d.update(version=2), "version"),
    (lambda d: d.pop("anchors"), "anchors"),
    (lambda d: d.update(anchors=[]), "anchors"),
    (lambda d: d["anchors"].__setitem__(1, 5), "anchors[1]"),
    (lambda d: d["anchors"][1].update(fibonacci=1), "anchors[1]: needs exactly one"),
    (lambda d: d["anchors"][2].pop("fibonacci"), "anchors[2]: needs exactly one"),
    (lambda d: d["anchors"][0].update(zoom=2), "anchors[0]: unknown keys"),
    (lambda d: d["anchors"][0]["camera"].pop("fx"), "anchors[0].camera"),
    (lambda d: d["anchors"][0]["camera"].update(c2w=[[1, 0], [0, 1]]), "anchors[0].camera"),
    (lambda d: d["anchors"][0]["camera"].update(lens=3), "anchors[0].camera"),
    (lambda d: d["anchors"][1].update(training_camera=3), "anchors[1].training_camera"),
    (lambda d: d["anchors"][2].update(fibonacci=-1), "anchors[2].fibonacci"),
    (lambda d: d["anchors"][2].update(fibonacci=True), "anchors[2].fibonacci"),
    (lambda d: d["anchors"][1].pop("clicks"), "anchors[1]: missing 'clicks'"),
    (lambda d: d["anchors"][1].update(clicks=[]), "anchors[1].clicks"),
    (lambda d: d["anchors"][1].update(clicks={"xy": [1, 2]}), "anchors[1].clicks"),
    (lambda d: d["anchors"][0]["clicks"].__setitem__(1, [1, 2]), "anchors[0].clicks[1]"),
    (lambda d: d["anchors"][0]["clicks"][1].update(label=1), "anchors[0].clicks[1]: unknown"),
    (lambda d: d["anchors"][0]["clicks"][1].pop("xy"), "anchors[0].clicks[1]: missing 'xy'"),
    (lambda d: d["anchors"][0]["clicks"][1].update(xy=[1, 2, 3]), "anchors[0].clicks[1].xy"),
    (lambda d: d["anchors"][0]["clicks"][1].update(xy=[1, "a"]), "anchors[0].clicks[1].xy"),
    (
        lambda d: d["anchors"][0]["clicks"][1].update(xy=[1, float("nan")]),
        "anchors[0].clicks[1].xy",
    ),
    (lambda d: d["anchors"][0]["clicks"][1].update(positive=1), "anchors[0].clicks[1].positive"),
    (lambda d: d.update(centroid_prompts=[]), "centroid_prompts"),
    (lambda d: d["centroid_prompts"].update({"0-1": []}), "centroid_prompts['0-1']"),
    (lambda d: d["centroid_prompts"].update({"3:0": []}), "centroid_prompts['3:0']"),
    (lambda d: d["centroid_prompts"].update({"1:4": []}), "centroid_prompts['1:4']"),
    (
        lambda d: d["centroid_prompts"].update({"0:0": [{"xy": [1]}]}),
        "centroid_prompts['0:0'][0].xy",
    ),
    (
        lambda d: (
            d["anchors"][1]["clicks"].__setitem__(0, {"xy": [1, 2], "positive": False}),
            d["centroid_prompts"].update({"1:0": []}),
        ),
        "centroid_prompts['1:0']",
    ),
]


@pytest.mark.parametrize("mutate,where", BAD)
def test_bad_entries_name_the_entry(mutate, where):
    with pytest.raises(DivasInputError) as e:
        parse_prompts(_mut(mutate), "p.json")
    assert where in str(e.value) and "p.json" in str(e.value)


def test_not_an_object():
    with pytest.raises(DivasInputError, match="JSON object"):
        parse_prompts([1, 2])


BAD_RESOLVE = [
    (
        lambda d: d["anchors"][1].update(training_camera="IMG_9999"),
        "anchors[1].training_camera: no training camera named",
    ),
    (lambda d: d["anchors"][2].update(fibonacci=12), "anchors[2].fibonacci: index 12 out of range"),
    (lambda d: d["anchors"][0]["clicks"][0].update(xy=[800, 10]), "anchors[0].clicks[0].xy"),
    (lambda d: d["anchors"][1]["clicks"][0].update(xy=[10, -0.5]), "anchors[1].clicks[0].xy"),
    (
        lambda d: d["centroid_prompts"]["0:1"][0].update(xy=[900, 10]),
        "centroid_prompts['0:1'][0].xy",
    ),
]


@pytest.mark.parametrize("mutate,where", BAD_RESOLVE)
def test_resolution_errors_name_the_entry(mutate, where):
    p = parse_prompts(_mut(mutate), "p.json")
    with pytest.raises(DivasInputError) as e:
        resolve_anchors(p, _train_cams(), _fib)
    assert where in str(e.value)


def test_training_camera_needs_cameras():
    p = parse_prompts(NOTES_EXAMPLE)
    with pytest.raises(DivasInputError, match=r"anchors\[1\].training_camera: the scene has no"):
        resolve_anchors(p, [], _fib)


def test_find_training_camera_with_or_without_extension():
    cams = _train_cams()
    assert find_training_camera(cams, "IMG_0013") == 2
    assert find_training_camera(cams, "IMG_0013.JPG") == 2
    assert find_training_camera(cams, "IMG_0013.png") == 2
    assert find_training_camera(cams, "IMG_0014") is None


def test_load_prompts_file_errors(tmp_path):
    with pytest.raises(DivasInputError, match="not found"):
        load_prompts(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DivasInputError, match="not valid JSON"):
        load_prompts(bad)
    good = tmp_path / "good.json"
    good.write_text(json.dumps(NOTES_EXAMPLE))
    assert load_prompts(good).source == str(good)

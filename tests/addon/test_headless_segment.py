"""``blender_scripts/segment.py`` — a headless segmentation through
the add-on's operators, run as a subprocess (``python segment.py -- …`` with the ``bpy``
module), gives the labels and the PLY ``divas segment`` gives on the same inputs; bad
inputs exit non-zero with one ``error:`` line."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from .conftest import REPO

SCRIPT = REPO / "blender_scripts" / "segment.py"


def _script_module():
    spec = importlib.util.spec_from_file_location("divas_blender_segment", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.evaluation import demo_prompts
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_headless")
    sc = generate_scene("ribs", out, size=15_000, seed=0, grid_resolution=32)
    prompts = demo_prompts(sc.metadata, sc.cameras, views_per_click=1)
    # one extra negative point on the first centroid view, in full-camera pixels
    from divas_engine.session import Click, Prompts

    extra = {(0, 0): (Click((3.25, 5.75), positive=False),)}
    Prompts(prompts.anchors, extra).write(out / "prompts.json")
    return out


def _run(*args, timeout=120):
    return subprocess.run(
        [sys.executable, str(SCRIPT), "--", *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_headless_matches_divas_segment(scene_dir, tmp_path):
    from divas_engine.cli.segment import segment_scene
    from divas_engine.segment_request import SegmentRequest

    common = dict(
        cameras=scene_dir / "cameras.json",
        segmenter="oracle",
        gt_labels=scene_dir / "labels.npy",
        scale=0.5,
        device="cpu",
        seed=2,
    )
    ref_dir = tmp_path / "engine"
    ref_dir.mkdir()  # an output's folder must exist
    report_ref, _ = segment_scene(
        SegmentRequest(
            scene_dir / "scene.ply",
            scene_dir / "prompts.json",
            out=ref_dir / "sel.ply",
            labels_out=ref_dir / "labels.npy",
            **common,
        ),
        progress=False,
    )
    ours = tmp_path / "blender"
    ours.mkdir()
    r = _run(
        "--scene",
        scene_dir / "scene.ply",
        "--cameras",
        scene_dir / "cameras.json",
        "--prompts",
        scene_dir / "prompts.json",
        "--out",
        ours / "sel.ply",
        "--labels-out",
        ours / "labels.npy",
        "--segmenter",
        "oracle",
        "--gt-labels",
        scene_dir / "labels.npy",
        "--scale",
        "0.5",
        "--device",
        "cpu",
        "--seed",
        "2",
        "--report",
        ours / "report.json",
        "--session",
        ours / "session.json",
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "centroid views fused" in r.stdout
    labels, ref_labels = np.load(ours / "labels.npy"), np.load(ref_dir / "labels.npy")
    assert labels.dtype == bool and labels.any()
    np.testing.assert_array_equal(labels, ref_labels)
    assert (ours / "sel.ply").read_bytes() == (ref_dir / "sel.ply").read_bytes()
    assert not (ours / "sel_labels.npy").exists()  # moved to --labels-out
    rep = json.loads((ours / "report.json").read_text())
    assert rep["counts"] == report_ref["counts"]
    assert [v["status"] for v in rep["views"]] == [v["status"] for v in report_ref["views"]]
    assert rep["evaluation"] == report_ref["evaluation"]
    assert rep["views"][0]["prompts"] == 2  # the default prompt + the extra negative one
    assert {"T_pipe_s", "import_s", "start_s", "export_s", "kernel"} <= set(rep["timings"])
    assert (ours / "session.json").is_file()


def test_headless_bad_inputs_exit_nonzero(scene_dir, tmp_path):
    r = _run(
        "--scene",
        scene_dir / "scene.ply",
        "--prompts",
        tmp_path / "missing.json",
        "--out",
        tmp_path / "o.ply",
        "--device",
        "cpu",
    )
    assert r.returncode == 1
    err = r.stderr.strip().splitlines()[-1]
    assert err.startswith("error:") and "missing.json" in err and "Traceback" not in r.stderr
    r = _run(
        "--scene",
        scene_dir / "scene.ply",
        "--prompts",
        scene_dir / "prompts.json",
        "--out",
        tmp_path / "o.ply",
        "--segmenter",
        "oracle",
        "--device",
        "cpu",
    )
    assert (
        r.returncode == 1 and "oracle segmenter needs" in r.stderr and "Traceback" not in r.stderr
    )
    assert not (tmp_path / "o.ply").exists()
    r = _run("--scene", scene_dir / "scene.ply")  # --prompts and --out are required
    assert r.returncode == 2 and "required" in r.stderr


def test_script_argv():
    mod = _script_module()
    assert mod.script_argv(["blender", "-b", "--python", "s.py", "--", "--scene", "a"]) == [
        "--scene",
        "a",
    ]
    assert mod.script_argv(["s.py", "--scene", "a"]) == ["--scene", "a"]

"""``divas segment`` end to end (oracle and classic; 2DGS PLY and NeRF
grid), its report keys, bad inputs as one-line errors (exit 2), and ``divas demo``."""

from __future__ import annotations

import json

import numpy as np
import pytest

import divas_engine.cli as cli
from divas_engine.evaluation import demo_prompts
from divas_engine.io.ply import read_ply_header
from divas_engine.session import AnchorPrompt, Click, Prompts
from divas_engine.synthetic import generate_scene

REPORT_KEYS = {
    "version",
    "command",
    "scene",
    "cameras",
    "prompts",
    "kind",
    "segmenter",
    "seed",
    "device",
    "render_scale",
    "timings",
    "updates",
    "counts",
    "views",
    "memory",
    "config",
    "outputs",
}


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs_cli")
    sc = generate_scene("ribs", out, size=20_000, seed=0, grid_resolution=64)
    demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(out / "prompts.json")
    return out, sc


def _segment(scene_dir, tmp_path, *extra, scene="scene.ply"):
    out, _ = scene_dir
    argv = [
        "segment",
        str(out / scene),
        "--prompts",
        str(out / "prompts.json"),
        "--scale",
        "0.5",
        "--no-progress",
        "--report",
        str(tmp_path / "report.json"),
        *extra,
    ]
    return cli.main(argv)


def test_segment_oracle_2dgs(scene_dir, tmp_path, capsys):
    out, sc = scene_dir
    rc = _segment(
        scene_dir,
        tmp_path,
        "--out",
        str(tmp_path / "sel.ply"),
        "--labels-out",
        str(tmp_path / "labels.npy"),
        "--segmenter",
        "oracle",
        "--gt-labels",
        str(out / "labels.npy"),
        "--seed",
        "3",
        "--session",
        str(tmp_path / "s.json"),
    )
    assert rc == 0, capsys.readouterr().err
    labels = np.load(tmp_path / "labels.npy")
    assert labels.dtype == bool and labels.shape == (len(sc.scene),) and labels.any()
    assert read_ply_header(tmp_path / "sel.ply").vertex.count == labels.sum()
    rep = json.loads((tmp_path / "report.json").read_text())
    assert set(rep) >= REPORT_KEYS and rep["seed"] == 3 and rep["kind"] == "2dgs"
    t = rep["timings"]
    assert {"render", "segmenter", "kernel", "mapping", "T_pipe_s"} <= set(t)
    assert len(t["kernel"]["per_call_s"]) == rep["counts"]["accepted"] > 0
    assert rep["counts"]["centroid_views"] - rep["counts"]["wider_views"] == 4
    assert rep["memory"]["peak_rss_bytes"] > 0 and rep["oracle"]["seed"] == 3
    assert rep["evaluation"]["surfels"]["precision"] > 0.95
    r = rep["evaluation"]["render"]
    assert r["test_views"] > 0 and "without_completion" not in r  # 2DGS: no completion
    x = r["selection"]
    assert 0 < x["image_iou"] <= 1 and 0 < x["alpha_fidelity"] <= 1 and x["psnr"] > 5
    # equal opacities in the generated scene: the weighted IoU is the per-surfel one
    assert abs(x["opacity_weighted_iou"] - rep["evaluation"]["surfels"]["iou"]) < 0.1
    assert rep["config"]["render_scale"] == 0.5
    assert all(v["status"] in ("fused", "rejected") for v in rep["views"])
    # the arrays file is content-addressed, named by the manifest
    arrays_file = json.loads((tmp_path / "s.json").read_text())["arrays"]["file"]
    assert arrays_file.startswith("s.json.") and (tmp_path / arrays_file).exists()
    assert "centroid views fused" in capsys.readouterr().out


def test_segment_default_graph3d_2dgs(scene_dir, tmp_path):
    rc = _segment(scene_dir, tmp_path, "--out", str(tmp_path / "sel.ply"))
    rep = json.loads((tmp_path / "report.json").read_text())
    assert (
        rep["segmenter"] == "graph3d"
        and rep["counts"]["centroid_views"] - rep["counts"]["wider_views"] == 4
    )
    assert rc == 0 and (tmp_path / "sel.ply").exists() and rep["counts"]["selected"] > 0


def test_segment_no_widening_keeps_one_view_per_click(scene_dir, tmp_path):
    """The ribs' close-ups cut the ribcage off: by default they get wider views; with
    --no-widening each click fuses its own view only (the paper's loop)."""
    out, _ = scene_dir
    reps = {}
    for flag in ((), ("--no-widening",)):
        d = tmp_path / ("off" if flag else "on")
        d.mkdir()
        oracle = ("--segmenter", "oracle", "--gt-labels", str(out / "labels.npy"))
        assert _segment(scene_dir, d, "--out", str(d / "sel.ply"), *oracle, *flag) == 0
        reps[bool(flag)] = json.loads((d / "report.json").read_text())
    on, off = reps[False], reps[True]
    assert on["counts"]["wider_views"] > 0 and off["counts"]["wider_views"] == 0
    assert off["counts"]["centroid_views"] == 4 and off["config"]["widening"]["enabled"] is False
    assert all(":w" not in v["id"] for v in off["views"])
    assert on["counts"]["selected"] > off["counts"]["selected"]


def test_segment_classic_2dgs(scene_dir, tmp_path):
    rc = _segment(scene_dir, tmp_path, "--out", str(tmp_path / "sel.ply"), "--segmenter", "classic")
    rep = json.loads((tmp_path / "report.json").read_text())
    assert (
        rep["segmenter"] == "classic"
        and rep["counts"]["centroid_views"] - rep["counts"]["wider_views"] == 4
    )
    if rc == 0:
        assert (tmp_path / "sel.ply").exists() and rep["counts"]["selected"] > 0
    else:  # every view rejected: a clear error, the report names the reasons
        assert rep["error"].startswith("the selection is empty")


def test_segment_nerf_grid(scene_dir, tmp_path):
    out, sc = scene_dir
    rc = _segment(
        scene_dir,
        tmp_path,
        "--out",
        str(tmp_path / "seg.npz"),
        "--labels-out",
        str(tmp_path / "grid_sel.npy"),
        "--segmenter",
        "oracle",
        "--gt-labels",
        str(out / "grid_labels.npy"),
        "--cameras",
        str(out / "cameras.json"),
        scene="grid.npz",
    )
    assert rc == 0
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["kind"] == "nerf" and rep["preset"] == "llff"
    sel = np.load(tmp_path / "grid_sel.npy")
    assert sel.shape == sc.grid.density.shape and sel.any()
    with np.load(tmp_path / "seg.npz") as z:
        assert np.array_equal(z["mask"], sel)
    assert rep["evaluation"]["voxels"]["precision"] > 0.9
    assert rep["timings"]["segmenter_wait"]["calls"] >= 1


def _write_prompts(path, prompts):
    prompts.write(path)
    return path


def test_segment_names_missing_segmenter_inputs_by_flag(scene_dir, tmp_path, capsys):
    """The engine's setup error, worded with this command's flags."""
    out, _ = scene_dir
    base = ["segment", str(out / "scene.ply"), "--prompts", str(out / "prompts.json")]
    base += ["--out", str(tmp_path / "x.ply"), "--no-progress"]
    assert cli.main(base + ["--segmenter", "sam-onnx", "--sam-decoder", "d.onnx"]) == 2
    err = capsys.readouterr().err
    assert "--segmenter sam-onnx needs --sam-encoder and --sam-decoder" in err
    assert cli.main(base + ["--segmenter", "sam-torch"]) == 2
    assert "--segmenter sam-torch needs --sam-checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "x.ply").exists()


def test_segment_bad_inputs(scene_dir, tmp_path, capsys):
    out, sc = scene_dir
    base = [
        "segment",
        str(out / "scene.ply"),
        "--out",
        str(tmp_path / "x.ply"),
        "--scale",
        "0.5",
        "--no-progress",
    ]
    # oracle without ground truth
    assert cli.main(base + ["--prompts", str(out / "prompts.json"), "--segmenter", "oracle"]) == 2
    assert "needs --gt-labels" in capsys.readouterr().err
    # out-of-image click names the entry
    p = _write_prompts(
        tmp_path / "oob.json",
        Prompts((AnchorPrompt("training_camera", sc.cameras[0].name, (Click((5000.0, 1.0)),)),)),
    )
    assert cli.main(base + ["--prompts", str(p)]) == 2
    err = capsys.readouterr().err
    assert "anchors[0].clicks[0].xy" in err and "outside" in err and "Traceback" not in err
    # unknown training camera
    p = _write_prompts(
        tmp_path / "cam.json",
        Prompts((AnchorPrompt("training_camera", "nope", (Click((5.0, 1.0)),)),)),
    )
    assert cli.main(base + ["--prompts", str(p)]) == 2
    assert "anchors[0].training_camera" in capsys.readouterr().err
    # a click on empty space: a camera looking away from the scene
    away = {
        "width": 160,
        "height": 120,
        "fx": 100,
        "fy": 100,
        "cx": 80,
        "cy": 60,
        "c2w": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 40], [0, 0, 0, 1]],
    }  # looks up, away
    (tmp_path / "empty.json").write_text(
        json.dumps({"version": 1, "anchors": [{"camera": away, "clicks": [{"xy": [80, 60]}]}]})
    )
    assert cli.main(base + ["--prompts", str(tmp_path / "empty.json")]) == 2
    err = capsys.readouterr().err
    assert "anchors[0].clicks[0]" in err and "no surface under the click" in err
    # malformed prompts file
    (tmp_path / "bad.json").write_text(json.dumps({"version": 1, "anchors": [{"clicks": []}]}))
    assert cli.main(base + ["--prompts", str(tmp_path / "bad.json")]) == 2
    assert "anchors[0]" in capsys.readouterr().err
    # ground truth of the wrong shape
    np.save(tmp_path / "gt.npy", np.zeros(7, bool))
    assert (
        cli.main(
            base
            + [
                "--prompts",
                str(out / "prompts.json"),
                "--segmenter",
                "oracle",
                "--gt-labels",
                str(tmp_path / "gt.npy"),
            ]
        )
        == 2
    )
    assert "ground-truth labels have shape" in capsys.readouterr().err


def test_demo_small(tmp_path, capsys):
    rc = cli.main(
        [
            "demo",
            "--out",
            str(tmp_path / "demo"),
            "--size",
            "20000",
            "--views-per-click",
            "1",
            "--scale",
            "0.5",
            "--no-progress",
            "--segmenter",
            "oracle",
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "IoU at 8 test cameras" in text
    d = tmp_path / "demo"
    assert (d / "segmented.ply").exists() and (d / "prompts.json").exists()
    assert len(list(d.glob("overlay_*.png"))) == 8
    rep = json.loads((d / "report.json").read_text())
    assert rep["evaluation"]["render"]["iou"] > 0.5
    assert len(rep["evaluation"]["render"]["per_camera"]) == 8

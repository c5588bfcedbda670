"""Real segment-anything graphs (random weights, reduced-depth ViT)
exported with the project's export code, run through ``SamOnnxSegmenter`` /
``SamTorchSegmenter`` and ``divas segment``, compared with segment-anything's own
``SamPredictor`` (tests/sam_reference.py). Needs the ``torch`` extra: ``make test-sam``."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra (make test-sam) runs these")

import divas_engine.cli as cli  # noqa: E402
from divas_engine.evaluation import demo_prompts  # noqa: E402
from divas_engine.segment import SamOnnxSegmenter, SamTorchSegmenter, select_mask  # noqa: E402
from divas_engine.segment.sam_common import sigmoid, upscale_low_res_masks  # noqa: E402
from divas_engine.segment.sam_export import (  # noqa: E402
    check_onnx_pair,
    export_onnx_pair,
)
from divas_engine.segment.sam_upstream import sam_package  # noqa: E402
from divas_engine.synthetic import generate_scene  # noqa: E402
from tests.sam_reference import reference_predict, sample_picture, tiny_sam  # noqa: E402


@pytest.fixture(scope="module")
def model():
    return tiny_sam(seed=0)


@pytest.fixture(scope="module")
def pairs(model, tmp_path_factory):
    d = tmp_path_factory.mktemp("sam_real")
    return {
        layout: export_onnx_pair(model, d / layout, layout=layout)
        for layout in ("preprocessed", "raw")
    }


def test_package_imports_without_torchvision():
    sa = sam_package()
    assert hasattr(sa, "SamPredictor") and "vit_b" in sa.sam_model_registry
    try:
        import torchvision  # noqa: F401
    except Exception:  # the CPU wheel has no working torchvision: the placeholder path ran
        assert sa.DIVAS_IMPORTED_WITHOUT_TORCHVISION
        with pytest.raises(ImportError, match="torchvision"):
            sa.SamPredictor(tiny_sam()).set_image(np.zeros((8, 8, 3), np.uint8))
        with pytest.raises(ImportError, match="torchvision"):
            sa.SamAutomaticMaskGenerator  # noqa: B018


def test_exported_signatures(pairs):
    import onnxruntime as ort

    for layout, (enc, dec) in pairs.items():
        seg = SamOnnxSegmenter(enc, dec)
        assert seg.encoder_layout == layout and seg.image_size == 1024
        ins = {i.name: i.shape for i in ort.InferenceSession(str(enc)).get_inputs()}
        assert ins == (
            {"image": [1, 3, 1024, 1024]}
            if layout == "preprocessed"
            else {"input_image": ["image_height", "image_width", 3]}
        )
        dins = [i.name for i in ort.InferenceSession(str(dec)).get_inputs()]
        assert dins == [
            "image_embeddings",
            "point_coords",
            "point_labels",
            "mask_input",
            "has_mask_input",
            "orig_im_size",
        ]


@pytest.mark.parametrize("layout", ["preprocessed", "raw"])
@pytest.mark.parametrize("hw", [(300, 460), (520, 240)])
def test_onnx_segmenter_matches_sam_predictor(model, pairs, layout, hw):
    """Shapes, preprocessing (embedding), coordinate transform, the 3 multimask
    channels and their scores, against SamPredictor on the same model."""
    rgb = sample_picture(*hw, seed=hw[0])
    pts = np.array([[0.31 * hw[1], 0.62 * hw[0]], [0.8 * hw[1] + 0.25, 0.1 * hw[0]]])
    labs = np.array([1, 0])
    ref_logits, ref_scores, ref_emb = reference_predict(model, rgb, pts, labs)
    seg = SamOnnxSegmenter(*pairs[layout])
    seg.set_image(rgb)
    emb = seg._state[0]
    assert emb.shape == (1, 256, 64, 64)
    # own resize vs PyTorch's antialiased bilinear: float-level agreement of embeddings
    np.testing.assert_allclose(emb, ref_emb, atol=2e-3 * float(np.abs(ref_emb).max()))
    masks, scores = seg.predict(pts, labs)
    assert masks.shape == (3, *hw) and masks.dtype == np.float32 and scores.shape == (3,)
    np.testing.assert_allclose(scores, ref_scores, atol=2e-4)
    np.testing.assert_allclose(masks, sigmoid(ref_logits), atol=2e-3)
    # a shifted click moves the result: the coordinate path is live, not ignored
    moved, _ = seg.predict(pts + [[40.0, 0.0], [0.0, 0.0]], labs)
    assert np.abs(moved - masks).max() > 1e-3


def test_torch_segmenter_matches_sam_predictor(model):
    hw = (300, 460)
    rgb = sample_picture(*hw, seed=7)
    pts, labs = np.array([[200.5, 120.25]]), np.array([1])
    ref_logits, ref_scores, _ = reference_predict(model, rgb, pts, labs)
    seg = SamTorchSegmenter.from_predictor(sam_package().SamPredictor(model))
    res = seg.segment(rgb, None, pts, labs)
    masks, scores = res.masks, res.scores
    np.testing.assert_allclose(scores, ref_scores, atol=2e-4)
    np.testing.assert_allclose(masks, sigmoid(ref_logits), atol=2e-3)


def test_decoder_crop_follows_the_image(model, pairs, tmp_path):
    """Our decoder's ``masks`` output is right for every aspect ratio; segment-anything
    1.0's plain SamOnnxModel export freezes the crop at its dummy (1500×2250) — and
    SamOnnxSegmenter is right with it anyway (it upscales ``low_res_masks`` itself)."""
    import onnxruntime as ort

    from divas_engine.segment.sam_export import _export_model

    sa = sam_package()
    plain = tmp_path / "plain_decoder.onnx"
    dummy = {
        "image_embeddings": torch.randn(1, 256, 64, 64),
        "point_coords": torch.randint(0, 1024, (1, 5, 2), dtype=torch.float),
        "point_labels": torch.randint(0, 4, (1, 5), dtype=torch.float),
        "mask_input": torch.randn(1, 1, 256, 256),
        "has_mask_input": torch.tensor([1], dtype=torch.float),
        "orig_im_size": torch.tensor([1500, 2250], dtype=torch.float),
    }
    _export_model(
        torch,
        sa.utils.onnx.SamOnnxModel(model, return_single_mask=False),
        tuple(dummy.values()),
        plain,
        input_names=list(dummy),
        output_names=["masks", "iou_predictions", "low_res_masks"],
        dynamic_axes={"point_coords": {1: "num_points"}, "point_labels": {1: "num_points"}},
    )
    feeds = {
        "image_embeddings": np.random.default_rng(1).normal(size=(1, 256, 64, 64)),
        "point_coords": np.array([[[300.0, 200.0], [0.0, 0.0]]]),
        "point_labels": np.array([[1.0, -1.0]]),
        "mask_input": np.zeros((1, 1, 256, 256)),
        "has_mask_input": np.zeros(1),
        "orig_im_size": np.array([480.0, 360.0]),  # portrait: not the dummy's aspect
    }
    feeds = {k: v.astype(np.float32) for k, v in feeds.items()}
    ours = ort.InferenceSession(str(pairs["preprocessed"][1])).run(None, feeds)
    theirs = ort.InferenceSession(str(plain)).run(None, feeds)
    np.testing.assert_allclose(ours[0][0], upscale_low_res_masks(ours[2][0], (480, 360)), atol=1e-4)
    assert np.abs(theirs[0][0] - upscale_low_res_masks(theirs[2][0], (480, 360))).max() > 0.05
    rgb = sample_picture(480, 360, seed=3)
    pts, labs = np.array([[100.5, 300.5]]), np.array([1])
    ref_logits, ref_scores, _ = reference_predict(model, rgb, pts, labs)
    res = SamOnnxSegmenter(pairs["preprocessed"][0], plain).segment(rgb, None, pts, labs)
    np.testing.assert_allclose(res.masks, sigmoid(ref_logits), atol=2e-3)
    np.testing.assert_allclose(res.scores, ref_scores, atol=2e-4)


def test_check_onnx_pair_agrees(model, pairs):
    c = check_onnx_pair(model, *pairs["raw"])
    assert c.ok and c.max_score_diff < 1e-4 and c.mask_iou > 0.999


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ribs_sam")
    sc = generate_scene("ribs", out, size=8_000, seed=0, grid_resolution=48)
    demo_prompts(sc.metadata, sc.cameras, views_per_click=1).write(out / "prompts.json")
    return out


def test_divas_segment_sam_onnx_end_to_end(scene_dir, tmp_path):
    """``divas segment --segmenter sam-onnx`` with both encoder layouts of one model:
    every view is segmented, accepted on the channel-1 score, fused and mapped; the two
    layouts agree view by view."""
    accepting = tiny_sam(seed=0, iou_bias=1.0)  # random weights, scores lifted over 0.5
    reports = {}
    for layout in ("preprocessed", "raw"):
        enc, dec = export_onnx_pair(accepting, tmp_path / layout, layout=layout)
        rep_path = tmp_path / f"{layout}.json"
        rc = cli.main(
            [
                "segment",
                str(scene_dir / "scene.ply"),
                "--prompts",
                str(scene_dir / "prompts.json"),
                "--scale",
                "0.5",
                "--no-progress",
                "--out",
                str(tmp_path / f"{layout}.ply"),
                "--segmenter",
                "sam-onnx",
                "--sam-encoder",
                str(enc),
                "--sam-decoder",
                str(dec),
                "--report",
                str(rep_path),
            ]
        )
        rep = json.loads(rep_path.read_text())
        assert rc == 0, rep.get("error")
        assert rep["segmenter"] == "sam-onnx" and rep["counts"]["selected"] > 0
        reports[layout] = rep
    a, b = reports["preprocessed"], reports["raw"]
    assert len(a["views"]) == len(b["views"]) == a["counts"]["centroid_views"] > 0
    sa = [v["score"] for v in a["views"]]
    sb = [v["score"] for v in b["views"]]
    assert all(s is not None and s >= 0.5 for s in sa)
    np.testing.assert_allclose(sa, sb, atol=1e-3)
    assert abs(a["counts"]["selected"] - b["counts"]["selected"]) <= 0.01 * a["counts"]["selected"]


def test_select_mask_on_real_decoder_output(model, pairs):
    rgb = sample_picture(256, 256, seed=5)
    seg = SamOnnxSegmenter(*pairs["preprocessed"])
    res = seg.segment(rgb, None, np.array([[128.0, 128.0]]), np.array([1]))
    sel = select_mask(res.masks, res.scores, np.array([1]), min_score=-1.0)
    assert sel.accepted and sel.mask.shape == (256, 256) and sel.score == res.scores[1]

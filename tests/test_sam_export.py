"""``divas sam-export`` and the checkpoint loading behind it.

CI runs these with the ``torch`` extra (``make test-sam``). The conversion is run on
checkpoints saved in the official format (``torch.save(sam.state_dict())``, as Meta's
``.pth``) with random weights. In CI the ``vit_b`` registry entry builds the reduced
ViT of tests/sam_reference.py (a full ViT-B export peaks at ~7 GB and minutes of CPU);
``make test-sam-full`` (``DIVAS_TEST_FULL_SAM=1``) runs the real ViT-B and MobileSAM."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra (make test-sam) runs these")

import divas_engine.cli as cli  # noqa: E402
from divas_engine.errors import DivasInputError  # noqa: E402
from divas_engine.segment import SamOnnxSegmenter, sam_export, sam_models  # noqa: E402
from divas_engine.segment.sam_common import sigmoid  # noqa: E402
from divas_engine.segment.sam_upstream import sam_package  # noqa: E402
from tests.sam_reference import reference_predict, sample_picture, tiny_sam  # noqa: E402

FULL = os.environ.get("DIVAS_TEST_FULL_SAM") == "1"


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    d = tmp_path_factory.mktemp("ckpt")
    model = tiny_sam(seed=4)
    torch.save(model.state_dict(), d / "sam_tiny.pth")  # the official file format
    return d / "sam_tiny.pth", model


@pytest.fixture
def tiny_is_vit_b(monkeypatch):
    """The ``vit_b`` entry builds the reduced ViT (CI size); everything else is real."""
    real = sam_models.build_sam_model

    def build(model_type):
        if sam_models.SamModelType.parse(model_type) is sam_models.SamModelType.VIT_B:
            return tiny_sam(seed=123)  # other weights: the checkpoint's must be loaded
        return real(model_type)

    monkeypatch.setattr(sam_models, "build_sam_model", build)
    monkeypatch.setattr(
        sam_models, "guess_model_type", lambda sd: "vit_b" if sd else None, raising=True
    )


def test_official_architectures_are_named_by_their_weights():
    for t in ("vit_b", "vit_l", "vit_h"):
        with torch.device("meta"):
            sd = sam_models.build_sam_model(t).state_dict()
        assert sam_models.guess_model_type(sd) == t
    assert sam_models.guess_model_type(tiny_sam().state_dict()) == "ViT, width 64, 2 blocks"
    assert sam_models.guess_model_type({"x": torch.zeros(1)}) is None


def test_checkpoint_reading_and_type_errors(tiny_ckpt, tmp_path):
    path, model = tiny_ckpt
    sd = sam_models.read_state_dict(path)
    assert set(sd) == set(model.state_dict())
    torch.save({"model": model.state_dict()}, tmp_path / "wrapped.pt")  # SAM 2 style
    assert set(sam_models.read_state_dict(tmp_path / "wrapped.pt")) == set(sd)
    with pytest.raises(DivasInputError, match=r"ViT, width 64, 2 blocks image encoder, not vit_b"):
        sam_models.load_sam_model(path, "vit_b")
    with pytest.raises(DivasInputError, match="not found"):
        sam_models.load_sam_model(tmp_path / "nope.pth", "vit_b")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(DivasInputError, match="not a PyTorch checkpoint"):
        sam_models.read_state_dict(tmp_path / "junk.pth")
    torch.save(torch.nn.Linear(2, 2), tmp_path / "module.pth")  # pickled code: refused
    with pytest.raises(DivasInputError, match="not a PyTorch checkpoint"):
        sam_models.read_state_dict(tmp_path / "module.pth")
    with pytest.raises(DivasInputError, match="unknown SAM model type"):
        sam_models.load_sam_model(path, "vit_x")
    # a SAM 2 checkpoint (Hiera trunk, saved under "model") is named and refused
    sam2 = {"image_encoder.trunk.patch_embed.proj.weight": torch.zeros(8, 3, 7, 7)}
    torch.save({"model": sam2}, tmp_path / "sam2.1_hiera_tiny.pt")
    with pytest.raises(DivasInputError, match=r"SAM 2 \(Hiera\)"):
        sam_models.load_sam_model(tmp_path / "sam2.1_hiera_tiny.pt", "vit_b")


@pytest.mark.parametrize("layout", ["preprocessed", "raw"])
def test_sam_export_cli_converts_and_checks(tiny_ckpt, tiny_is_vit_b, tmp_path, capsys, layout):
    path, model = tiny_ckpt
    out = tmp_path / "pair"
    rc = cli.main(
        ["sam-export", str(path), "--model-type", "vit_b", "--out", str(out)]
        + ["--encoder-layout", layout]
    )
    lines = capsys.readouterr().out.strip().splitlines()
    assert rc == 0
    assert lines[-2:] == [str(out / "sam_tiny_encoder.onnx"), str(out / "sam_tiny_decoder.onnx")]
    assert "mask IoU 1.0000" in lines[-3] or "mask IoU 0.999" in lines[-3]
    meta = json.loads((out / "export.json").read_text())
    assert meta["layout"] == layout and meta["check"]["mask_iou"] > 0.999
    assert sorted(p.name for p in out.iterdir()) == [
        "export.json",
        "sam_tiny_decoder.onnx",
        "sam_tiny_encoder.onnx",
    ]
    # the pair is the checkpoint's model: segment-anything's predictor on it agrees
    rgb = sample_picture(320, 480, seed=11)
    pts, labs = np.array([[150.5, 200.5], [400.0, 40.0]]), np.array([1, 0])
    ref_logits, ref_scores, _ = reference_predict(model, rgb, pts, labs)
    seg = SamOnnxSegmenter(*(out / f"sam_tiny_{p}.onnx" for p in ("encoder", "decoder")))
    assert seg.encoder_layout == layout
    res = seg.segment(rgb, None, pts, labs)
    np.testing.assert_allclose(res.scores, ref_scores, atol=2e-4)
    np.testing.assert_allclose(res.masks, sigmoid(ref_logits), atol=2e-3)


def test_failed_check_writes_nothing(tiny_ckpt, tiny_is_vit_b, tmp_path, monkeypatch):
    path, _ = tiny_ckpt
    out = tmp_path / "pair"
    out.mkdir()
    (out / "sam_tiny_encoder.onnx").write_bytes(b"the user's earlier file")
    bad = sam_export.PairCheck((1, 1), (0.0,) * 3, (0.5,) * 3, 0.5, 0.2, 1.0, 0.0, 0.0)
    monkeypatch.setattr(sam_export, "check_onnx_pair", lambda *a: bad)
    with pytest.raises(DivasInputError, match="disagrees"):
        sam_export.convert_checkpoint(path, "vit_b", out)
    assert [p.name for p in out.iterdir()] == ["sam_tiny_encoder.onnx"]
    assert (out / "sam_tiny_encoder.onnx").read_bytes() == b"the user's earlier file"


def test_cached_conversion_converts_once(tiny_ckpt, tiny_is_vit_b, tmp_path, monkeypatch):
    path, _ = tiny_ckpt
    ckpt = tmp_path / "sam_tiny.pth"
    ckpt.write_bytes(path.read_bytes())
    calls = []
    real = sam_export.export_onnx_pair
    monkeypatch.setattr(
        sam_export, "export_onnx_pair", lambda *a, **k: calls.append(1) or real(*a, **k)
    )
    first = sam_export.cached_conversion(ckpt, "vit_b", tmp_path / "cache")
    again = sam_export.cached_conversion(ckpt, "vit_b", tmp_path / "cache")
    assert len(calls) == 1 and again == first and first.check.ok
    os.utime(ckpt, ns=(1, 1))  # a replaced checkpoint converts again, into its own folder
    third = sam_export.cached_conversion(ckpt, "vit_b", tmp_path / "cache")
    assert len(calls) == 2 and third.encoder.parent != first.encoder.parent
    assert third.encoder.is_file() and first.encoder.is_file()


def test_sam_export_cli_errors(tiny_ckpt, tmp_path, capsys, monkeypatch):
    path, _ = tiny_ckpt
    argv = ["sam-export", str(path), "--model-type", "vit_b", "--out", str(tmp_path / "o")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not vit_b" in err
    assert cli.main([*argv[:1], str(tmp_path / "missing.pth"), *argv[2:]]) == 2
    assert "not found" in capsys.readouterr().err
    try:
        sam_package("mobile_sam")
    except ImportError:  # CI: MobileSAM's package (timm → torchvision) is not installed
        assert cli.main([*argv[:3], "mobile_sam", *argv[4:]]) == 2
        err = capsys.readouterr().err
        assert "'mobile_sam'" in err and "timm" in err
    monkeypatch.setitem(sys.modules, "torch", None)
    assert cli.main(argv) == 2
    assert "optional package 'torch'" in capsys.readouterr().err


def test_addon_preferences_use_a_checkpoint_converted_once(
    tiny_ckpt, tiny_is_vit_b, tmp_path, monkeypatch
):
    """The add-on's preferences take a checkpoint for SAM (ONNX): the engine converts it
    once into the cache folder, the active-model line says which model is used."""
    from types import SimpleNamespace

    prefs_mod = pytest.importorskip("blender_addon.preferences")
    from divas_engine.segment import sam_export as se

    monkeypatch.setattr(prefs_mod, "sam_cache_dir", lambda: tmp_path / "cache")
    path, _ = tiny_ckpt
    prefs = SimpleNamespace(
        segmenter="sam-onnx",
        sam_encoder_path="",
        sam_decoder_path="",
        sam_checkpoint_path=str(path),
        sam_model_type="vit_b",
    )
    assert prefs_mod.active_model(prefs).endswith("converted to ONNX at the next Start")
    assert prefs_mod.active_model_ready(prefs)  # a checkpoint alone is enough: no warning
    settings = prefs_mod.DivasSettings(
        segmenter="sam-onnx", sam_checkpoint_path=str(path), sam_model_type="vit_b"
    )
    s = prefs_mod.with_converted_checkpoint(settings)
    assert s.sam_encoder_path.startswith(str(tmp_path / "cache")) and s.sam_decoder_path
    assert SamOnnxSegmenter(s.sam_encoder_path, s.sam_decoder_path).encoder_layout
    assert prefs_mod.active_model(prefs) == "sam_tiny.pth (vit_b), converted to ONNX"
    calls = []
    monkeypatch.setattr(se, "convert_checkpoint", lambda *a, **k: calls.append(a))
    assert prefs_mod.with_converted_checkpoint(settings) == s and not calls  # cached
    prefs.sam_encoder_path, prefs.sam_decoder_path = "/m/enc.onnx", "/m/dec.onnx"
    assert prefs_mod.active_model(prefs) == "ONNX pair enc.onnx + dec.onnx"
    paired = prefs_mod.DivasSettings(
        segmenter="sam-onnx",
        sam_encoder_path="/m/e.onnx",
        sam_decoder_path="/m/d.onnx",
        sam_checkpoint_path=str(path),
    )
    assert prefs_mod.with_converted_checkpoint(paired) == paired  # a set pair wins
    prefs.sam_encoder_path = ""
    prefs.sam_checkpoint_path = str(tmp_path / "other.pth")
    monkeypatch.setattr(se, "torch_available", lambda: False)
    assert "needs torch" in prefs_mod.active_model(prefs)
    assert not prefs_mod.active_model_ready(prefs)  # unconverted and no torch: warned
    prefs.sam_checkpoint_path = str(path)  # converted above: usable without torch
    assert prefs_mod.active_model_ready(prefs)
    prefs.sam_checkpoint_path = ""
    assert not prefs_mod.active_model_ready(prefs)
    prefs.segmenter = "sam-torch"
    assert not prefs_mod.active_model_ready(prefs)


def test_addon_active_model_names_weight_free_segmenters():
    from types import SimpleNamespace

    prefs_mod = pytest.importorskip("blender_addon.preferences")
    for key, name, _ in prefs_mod.SEGMENTERS:
        if key.startswith("sam"):
            continue
        prefs = SimpleNamespace(
            segmenter=key, sam_encoder_path="", sam_decoder_path="", sam_checkpoint_path="/x.pth"
        )
        assert prefs_mod.active_model(prefs) == f"{name} (no model files)"

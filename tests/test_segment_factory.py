"""The engine's segmenter factory (:mod:`divas_engine.segment.factory`): one place that
builds a segmenter from settings, for the CLI and the add-on, with errors that say what
is missing (and which setting holds it) without naming any caller's flags."""

from __future__ import annotations

import numpy as np
import pytest

import divas_engine.segment.factory as factory
from divas_engine import DivasInputError
from divas_engine.segment import (
    ClassicSegmenter,
    OracleSegmenter,
    SamOnnxSegmenter,
    SegmenterKind,
    SegmenterSettings,
    SegmenterSetupError,
    build_segmenter,
)
from tests.test_segmenters import make_decoder, make_preprocessed_encoder


def test_kinds_are_the_segmenters_names_and_parse_both_spellings():
    assert [k.value for k in SegmenterKind] == [
        "graph3d",
        "classic",
        "sam-onnx",
        "sam-torch",
        "oracle",
    ]
    assert SegmenterKind.parse("sam_onnx") is SegmenterKind.SAM_ONNX
    assert SegmenterKind.parse("SAM-Torch") is SegmenterKind.SAM_TORCH
    assert SegmenterSettings("oracle").kind is SegmenterKind.ORACLE
    with pytest.raises(DivasInputError, match="unknown segmenter 'grabcut'.*classic"):
        SegmenterSettings("grabcut")


def test_classic_and_oracle_carry_the_seed():
    seg = build_segmenter(SegmenterSettings(SegmenterKind.CLASSIC, seed=7))
    assert isinstance(seg, ClassicSegmenter) and seg.config.seed == 7
    seg = build_segmenter(SegmenterSettings("oracle", seed=3), has_ground_truth=True)
    assert isinstance(seg, OracleSegmenter) and seg.config.seed == 3


@pytest.mark.parametrize(
    ("settings", "requires", "words"),
    [
        (SegmenterSettings("oracle"), ("ground_truth",), "oracle segmenter needs ground-truth"),
        (
            SegmenterSettings("sam-onnx", sam_encoder="e.onnx"),
            ("sam_encoder", "sam_decoder"),
            r"SAM \(ONNX\) segmenter needs the encoder and decoder",
        ),
        (SegmenterSettings("sam-torch"), ("sam_checkpoint",), r"SAM \(PyTorch\).*checkpoint"),
    ],
)
def test_missing_requirements_are_one_setup_error(settings, requires, words):
    with pytest.raises(SegmenterSetupError, match=words) as e:
        build_segmenter(settings)
    assert e.value.kind is settings.kind and e.value.requires == requires
    assert isinstance(e.value, DivasInputError) and "--" not in str(e.value)


def test_sam_onnx_is_built_from_its_model_files(tmp_path):
    enc = make_preprocessed_encoder(tmp_path / "enc.onnx")
    dec = make_decoder(tmp_path / "dec.onnx", n_masks=3)
    seg = build_segmenter(SegmenterSettings("sam_onnx", sam_encoder=enc, sam_decoder=dec))
    assert isinstance(seg, SamOnnxSegmenter)
    rgb = np.random.default_rng(0).random((48, 64, 3)).astype(np.float32)
    res = seg.segment(rgb, None, np.array([[32.0, 24.0]]), np.array([1]))
    assert res.masks.shape[1:] == (48, 64)


def test_sam_torch_device_and_missing_package(monkeypatch):
    calls = []

    class FakeSamTorch:
        def __init__(self, checkpoint, model_type, *, device):
            calls.append((checkpoint, model_type, device))

    monkeypatch.setattr(factory, "SamTorchSegmenter", FakeSamTorch)
    build_segmenter(SegmenterSettings("sam-torch", sam_checkpoint="m.pth", sam_model_type="vit_b"))
    build_segmenter(SegmenterSettings("sam-torch", sam_checkpoint="m.pth", device="cpu"))
    assert calls == [("m.pth", "vit_b", None), ("m.pth", "vit_h", "cpu")]

    class NoTorch:
        def __init__(self, *a, **k):
            raise ImportError("SamTorchSegmenter needs the optional package 'torch'")

    monkeypatch.setattr(factory, "SamTorchSegmenter", NoTorch)
    with pytest.raises(DivasInputError, match="'torch'") as e:
        build_segmenter(SegmenterSettings("sam-torch", sam_checkpoint="m.pth"))
    assert not isinstance(e.value, SegmenterSetupError)

"""Segmenters (paper Sec. 3.4): SAM-ONNX / SAM-torch plumbing, classic GrabCut, oracle.

The SAM tests use tiny ONNX stand-ins built here with ``onnx.helper`` that have
segment-anything's export signatures, so loading, preprocessing, the prompt
coordinate mapping and the postprocessing are checked against hand computations
without any weights:

* ``preprocessed`` encoder ``input_image [1,3,1024,1024]`` → 16×16 average pool →
  fixed 1×1 conv → ``image_embeddings [1,256,64,64]`` (channel ``c`` is
  ``(c // 3 + 1) / 86 · avgpool(x)[c % 3]``);
* ``raw`` encoder ``input_image [h,w,3]`` → mean broadcast to ``[1,256,64,64]``;
* decoder: with ``s = 1024 / max(H,W)`` and the first prompt point ``(px, py)``,
  ``logit_k = B[k] − d²/R[k]²``, ``d² = ((x+.5)s − (px+.5))² + ((y+.5)s − (py+.5))²``
  over pixel indices — SAM's own "+0.5" reading of prompt coordinates — so the
  logit peaks exactly at our continuous click when the wrapper maps ``u → u·s − .5``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from divas_engine import DivasInputError
from divas_engine.segment import (
    ClassicConfig,
    ClassicSegmenter,
    FloodFillSegmenter,
    OracleConfig,
    OracleSegmenter,
    SamOnnxSegmenter,
    SamTorchSegmenter,
    select_mask,
)
from divas_engine.segment.sam_common import (
    SAM_PIXEL_MEAN,
    SAM_PIXEL_STD,
    decoder_prompts,
    preprocess_shape,
    resize_antialiased,
    sigmoid,
)

# ----------------------------------------------------------------------------- tiny ONNX SAM
OPSET = 17
B = np.array([1.0, 2.0, 3.0, 4.0], np.float32)
R = np.array([8.0, 16.0, 32.0, 64.0], np.float32)
IOU = np.array([0.1, 0.6, 0.7, 0.8], np.float32)


def _save(graph: onnx.GraphProto, path: Path) -> Path:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def encoder_weights() -> np.ndarray:
    w = np.zeros((256, 3, 1, 1), np.float32)
    for c in range(256):
        w[c, c % 3] = (c // 3 + 1) / 86.0
    return w


def make_preprocessed_encoder(path: Path) -> Path:
    x = helper.make_tensor_value_info("input_image", TensorProto.FLOAT, [1, 3, 1024, 1024])
    y = helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])
    nodes = [
        helper.make_node(
            "AveragePool", ["input_image"], ["pooled"], kernel_shape=[16, 16], strides=[16, 16]
        ),
        helper.make_node("Conv", ["pooled", "w"], ["image_embeddings"]),
    ]
    g = helper.make_graph(nodes, "enc", [x], [y], [numpy_helper.from_array(encoder_weights(), "w")])
    return _save(g, path)


def make_raw_encoder(path: Path) -> Path:
    x = helper.make_tensor_value_info("input_image", TensorProto.FLOAT, ["h", "w", 3])
    y = helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])
    nodes = [
        helper.make_node("ReduceMean", ["input_image"], ["m"], keepdims=0),
        helper.make_node("Expand", ["m", "shape"], ["image_embeddings"]),
    ]
    init = [numpy_helper.from_array(np.array([1, 256, 64, 64], np.int64), "shape")]
    return _save(helper.make_graph(nodes, "enc_raw", [x], [y], init), path)


def make_decoder(path: Path, n_masks: int = 4, drop_input: str | None = None) -> Path:
    f = TensorProto.FLOAT
    ins = [
        helper.make_tensor_value_info("image_embeddings", f, [1, 256, 64, 64]),
        helper.make_tensor_value_info("point_coords", f, [1, "P", 2]),
        helper.make_tensor_value_info("point_labels", f, [1, "P"]),
        helper.make_tensor_value_info("mask_input", f, [1, 1, 256, 256]),
        helper.make_tensor_value_info("has_mask_input", f, [1]),
        helper.make_tensor_value_info("orig_im_size", f, [2]),
    ]
    outs = [
        helper.make_tensor_value_info("masks", f, [1, n_masks, "H", "W"]),
        helper.make_tensor_value_info("iou_predictions", f, [1, n_masks]),
        # no low_res_masks: given one, SamOnnxSegmenter upscales it itself instead of reading
        # "masks" (tests/test_sam_real_graphs.py covers that path on real graphs)
    ]
    c = {
        "i0": np.array(0, np.int64),
        "i1": np.array(1, np.int64),
        "zero": np.array(0.0, np.float32),
        "one": np.array(1.0, np.float32),
        "half": np.array(0.5, np.float32),
        "side": np.array(1024.0, np.float32),
        "b": B[:n_masks].reshape(1, n_masks, 1, 1),
        "invr2": (1.0 / R[:n_masks] ** 2).reshape(1, n_masks, 1, 1),
        "iou": IOU[:n_masks].reshape(1, n_masks),
        "ax0": np.array([0], np.int64),
        "ax1": np.array([1], np.int64),
    }
    n = helper.make_node
    nodes = [
        n("Gather", ["orig_im_size", "i0"], ["H"]),
        n("Gather", ["orig_im_size", "i1"], ["W"]),
        n("Max", ["H", "W"], ["S"]),
        n("Div", ["side", "S"], ["s"]),
        n("Range", ["zero", "H", "one"], ["ys"]),
        n("Range", ["zero", "W", "one"], ["xs"]),
        n("Gather", ["point_coords", "i0"], ["p0"], axis=1),  # [1,2]
        n("Gather", ["p0", "i0"], ["px"], axis=1),
        n("Gather", ["p0", "i1"], ["py"], axis=1),
        n("Add", ["xs", "half"], ["xh"]),
        n("Mul", ["xh", "s"], ["xs_s"]),
        n("Add", ["px", "half"], ["pxh"]),
        n("Sub", ["xs_s", "pxh"], ["dx"]),
        n("Add", ["ys", "half"], ["yh"]),
        n("Mul", ["yh", "s"], ["ys_s"]),
        n("Add", ["py", "half"], ["pyh"]),
        n("Sub", ["ys_s", "pyh"], ["dy"]),
        n("Mul", ["dx", "dx"], ["dx2"]),
        n("Mul", ["dy", "dy"], ["dy2"]),
        n("Unsqueeze", ["dx2", "ax0"], ["dx2r"]),
        n("Unsqueeze", ["dy2", "ax1"], ["dy2c"]),
        n("Add", ["dy2c", "dx2r"], ["d2"]),  # [H,W]
        n("Unsqueeze", ["d2", "ax0"], ["d2a"]),
        n("Unsqueeze", ["d2a", "ax0"], ["d2b"]),
        n("Mul", ["d2b", "invr2"], ["scaled"]),
        n("Sub", ["b", "scaled"], ["masks"]),
        n("ReduceMean", ["image_embeddings"], ["emean"], keepdims=0),
        n("Mul", ["emean", "zero"], ["ezero"]),
        n("Add", ["iou", "ezero"], ["iou1"]),
        n("Add", ["iou1", "has_mask_input"], ["iou_predictions"]),
        n("ReduceMean", ["mask_input"], ["mask_input_used"], keepdims=0),
        n("Identity", ["point_labels"], ["labels_used"]),
    ]
    if drop_input is not None:
        ins = [i for i in ins if i.name != drop_input]
        ins.append(helper.make_tensor_value_info("something_else", f, [1]))
        nodes = [nd for nd in nodes if drop_input not in nd.input]
        if drop_input == "orig_im_size":
            nodes.insert(0, n("Identity", ["something_else"], ["orig_im_size"]))
    inits = [numpy_helper.from_array(np.asarray(v), k) for k, v in c.items()]
    g = helper.make_graph(nodes, "dec", ins, outs, inits)
    return _save(g, path)


def decoder_reference(h: int, w: int, u: float, v: float, n_masks: int = 4) -> np.ndarray:
    """Hand formula: logits ``[n_masks,H,W]`` for our continuous click ``(u, v)``.

    If the wrapper maps ``u → u·s − 0.5`` (SAM reads ``coord + 0.5``), the decoder's
    distance is ``((x + .5)s − u s)``, zero exactly at the clicked point.
    """
    s = 1024.0 / max(h, w)
    x = (np.arange(w) + 0.5) * s - u * s
    y = (np.arange(h) + 0.5) * s - v * s
    d2 = y[:, None] ** 2 + x[None, :] ** 2
    return B[:n_masks, None, None] - d2[None] / R[:n_masks, None, None] ** 2


class Recorder:
    """Wraps an onnxruntime session and records every feed."""

    def __init__(self, sess):
        self.sess, self.feeds = sess, []

    def run(self, names, feeds):
        self.feeds.append({k: np.array(v, copy=True) for k, v in feeds.items()})
        return self.sess.run(names, feeds)

    def __getattr__(self, item):
        return getattr(self.sess, item)


@pytest.fixture(scope="module")
def onnx_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("sam_onnx")
    make_preprocessed_encoder(d / "enc.onnx")
    make_raw_encoder(d / "enc_raw.onnx")
    make_decoder(d / "dec.onnx")
    make_decoder(d / "dec3.onnx", n_masks=3)
    make_decoder(d / "dec1.onnx", n_masks=1)
    make_decoder(d / "dec_bad.onnx", drop_input="point_labels")
    return d


def _recording(seg):
    seg._enc, seg._dec = Recorder(seg._enc), Recorder(seg._dec)
    return seg


def _img(h, w, seed=0):
    return np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)


# ----------------------------------------------------------------------------- SAM common
def test_preprocess_shape_rounds_half_up():
    assert preprocess_shape(480, 640) == (768, 1024)
    assert preprocess_shape(200, 300) == (683, 1024)  # 682.67
    assert preprocess_shape(1080, 1920) == (576, 1024)
    assert preprocess_shape(1024, 1024) == (1024, 1024)


def test_antialiased_resize_hand_weights():
    # 2x downscale: triangle of half-width 2 input px → taps [1/8, 3/8, 3/8, 1/8]
    x = np.arange(8, dtype=np.float32)[None, :, None] ** 2
    out = resize_antialiased(x, (1, 4))[0, :, 0]
    v = x[0, :, 0]
    exp = [(v[0] * 3 / 8 + v[1] * 3 / 8 + v[2] / 8) / (7 / 8)]  # left tap dropped, renormalised
    exp += [
        v[2 * i - 1] / 8 + v[2 * i] * 3 / 8 + v[2 * i + 1] * 3 / 8 + v[2 * i + 2] / 8
        for i in (1, 2)
    ]
    exp += [(v[5] / 8 + v[6] * 3 / 8 + v[7] * 3 / 8) / (7 / 8)]
    np.testing.assert_allclose(out, exp, rtol=1e-6)
    # upscaling is plain half-pixel bilinear (= OpenCV INTER_LINEAR)
    img = _img(12, 16)
    np.testing.assert_allclose(
        resize_antialiased(img, (36, 48)),
        cv2.resize(img, (48, 36), interpolation=cv2.INTER_LINEAR),
        atol=1e-5,
    )


def test_resize_matches_torch_antialias():
    torch = pytest.importorskip("torch")
    import torch.nn.functional as F

    img = _img(300, 450) * 255
    nh, nw = preprocess_shape(300, 450, 256)
    ref = (
        F.interpolate(
            torch.from_numpy(img.transpose(2, 0, 1))[None],
            (nh, nw),
            mode="bilinear",
            align_corners=False,
            antialias=True,
        )[0]
        .numpy()
        .transpose(1, 2, 0)
    )
    np.testing.assert_allclose(resize_antialiased(img, (nh, nw)), ref, atol=2e-3)


def test_decoder_prompt_mapping_and_padding_point():
    coords, labels = decoder_prompts(
        np.array([[10.5, 20.0], [0.25, 95.5]]), np.array([1, 0]), (96, 128)
    )
    s = 1024 / 128
    np.testing.assert_allclose(
        coords,
        [[[10.5 * s - 0.5, 20.0 * s - 0.5], [0.25 * s - 0.5, 95.5 * s - 0.5], [0, 0]]],
        rtol=1e-6,
    )
    np.testing.assert_array_equal(labels, [[1, 0, -1]])
    assert coords.dtype == labels.dtype == np.float32
    # per-axis scale like ResizeLongestSide.apply_coords when the new size rounds
    c, _ = decoder_prompts(np.array([[100.0, 100.0]]), np.array([1]), (200, 300))
    np.testing.assert_allclose(c[0, 0], [100 * 1024 / 300 - 0.5, 100 * 683 / 200 - 0.5], rtol=1e-6)


# ----------------------------------------------------------------------------- SAM ONNX
def test_onnx_preprocessing_feed_and_embedding(onnx_dir):
    seg = _recording(SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec.onnx"))
    assert seg.encoder_layout == "preprocessed" and seg.image_size == 1024
    img = _img(96, 128)
    seg.set_image((img * 255).round().astype(np.uint8))  # uint8 input
    img = (img * 255).round().astype(np.float32)
    hand = np.zeros((1, 3, 1024, 1024), np.float32)
    up = cv2.resize(img, (1024, 768), interpolation=cv2.INTER_LINEAR)  # 8x bilinear upsample
    hand[0, :, :768] = ((up - SAM_PIXEL_MEAN) / SAM_PIXEL_STD).transpose(2, 0, 1)
    fed = seg._enc.feeds[0]["input_image"]
    assert fed.shape == (1, 3, 1024, 1024) and fed.dtype == np.float32
    np.testing.assert_allclose(fed, hand, atol=2e-4)
    assert np.all(fed[0, :, 768:] == 0)
    emb = seg._state[0]
    pooled = hand[0].reshape(3, 64, 16, 64, 16).mean(axis=(2, 4))
    c = np.arange(256)
    np.testing.assert_allclose(
        emb[0], pooled[c % 3] * ((c // 3 + 1) / 86.0)[:, None, None], atol=1e-4
    )


def test_onnx_prompts_and_postprocessing(onnx_dir):
    seg = _recording(SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec.onnx"))
    seg.set_image(_img(96, 128), view_id="v0")
    pts, labs = np.array([[40.5, 30.25], [100.0, 80.0]]), np.array([1, 0])
    masks, scores = seg.predict(pts, labs)
    feed = seg._dec.feeds[-1]
    np.testing.assert_allclose(
        feed["point_coords"],
        [[[40.5 * 8 - 0.5, 30.25 * 8 - 0.5], [100 * 8 - 0.5, 80 * 8 - 0.5], [0, 0]]],
    )
    np.testing.assert_array_equal(feed["point_labels"], [[1, 0, -1]])
    assert feed["mask_input"].shape == (1, 1, 256, 256) and not feed["mask_input"].any()
    np.testing.assert_array_equal(feed["has_mask_input"], [0])
    np.testing.assert_array_equal(feed["orig_im_size"], [96, 128])
    np.testing.assert_array_equal(feed["image_embeddings"], seg._state[0])
    # 4-mask export: channels 1..3 kept, logits → sigmoid, peak at our continuous click
    ref = sigmoid(decoder_reference(96, 128, 40.5, 30.25)[1:])
    assert masks.shape == (3, 96, 128) and masks.dtype == np.float32
    np.testing.assert_allclose(masks, ref, atol=1e-5)
    np.testing.assert_allclose(scores, IOU[1:])
    assert np.unravel_index(np.argmax(masks[0]), masks[0].shape) == (30, 40)
    # a 3-mask export is used as is
    seg3 = SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec3.onnx")
    seg3.set_image(_img(96, 128))
    m3, s3 = seg3.predict(pts, labs)
    np.testing.assert_allclose(m3, sigmoid(decoder_reference(96, 128, 40.5, 30.25, 3)), atol=1e-5)
    np.testing.assert_allclose(s3, IOU[:3])


def test_onnx_embedding_cache(onnx_dir):
    seg = _recording(SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec.onnx", cache_size=2))
    a, b, c = _img(48, 64, 1), _img(48, 64, 2), _img(48, 64, 3)
    seg.set_image(a, view_id=7)
    seg.set_image(b, view_id=7)  # the view id is the key: no re-encode
    seg.set_image(a)
    seg.set_image(a.copy())  # same bytes → same hash
    assert len(seg._enc.feeds) == 2
    seg.set_image(b)
    seg.set_image(c)  # evicts view 7 (LRU of 2)
    seg.set_image(a, view_id=7)
    assert len(seg._enc.feeds) == 5 and seg.cached_views == 2


def test_onnx_raw_encoder_variant(onnx_dir):
    seg = _recording(SamOnnxSegmenter(onnx_dir / "enc_raw.onnx", onnx_dir / "dec.onnx"))
    assert seg.encoder_layout == "raw"
    img = _img(64, 48)
    seg.set_image(img)
    fed = seg._enc.feeds[0]["input_image"]
    assert fed.shape == (1024, 768, 3)  # resized, unnormalised, unpadded (dims are dynamic)
    np.testing.assert_allclose(fed, resize_antialiased(img * 255, (1024, 768)), atol=1e-4)
    np.testing.assert_allclose(seg._state[0], fed.mean(), rtol=1e-4)
    masks, _ = seg.predict(np.array([[10.0, 20.0]]), np.array([1]))
    np.testing.assert_allclose(masks, sigmoid(decoder_reference(64, 48, 10.0, 20.0)[1:]), atol=1e-5)


def test_onnx_bad_models(onnx_dir, tmp_path):
    with pytest.raises(DivasInputError, match="not found"):
        SamOnnxSegmenter(tmp_path / "nope.onnx", onnx_dir / "dec.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a protobuf at all")
    with pytest.raises(DivasInputError, match="cannot load"):
        SamOnnxSegmenter(onnx_dir / "enc.onnx", junk)
    with pytest.raises(DivasInputError, match="missing inputs.*point_labels"):
        SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec_bad.onnx")
    with pytest.raises(DivasInputError, match="return-single-mask"):
        SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "dec1.onnx")
    with pytest.raises(DivasInputError, match="missing inputs"):  # encoder given as decoder
        SamOnnxSegmenter(onnx_dir / "enc.onnx", onnx_dir / "enc.onnx")
    with pytest.raises(DivasInputError, match="encoder must take one image input"):
        SamOnnxSegmenter(onnx_dir / "dec.onnx", onnx_dir / "dec.onnx")  # decoder given as encoder
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 1, 1024, 1024])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 1, 1024, 1024])
    gray = _save(
        helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", [x], [y]),
        tmp_path / "gray.onnx",
    )
    with pytest.raises(DivasInputError, match="unrecognised SAM encoder input"):
        SamOnnxSegmenter(gray, onnx_dir / "dec.onnx")


# ----------------------------------------------------------------------------- selection
def test_select_mask_channel_one_and_rejections():
    masks = np.stack([np.full((4, 5), v, np.float32) for v in (0.1, 0.5, 0.9)])
    sel = select_mask(masks, np.array([0.9, 0.7, 0.2]), np.array([1, 0]))
    assert sel.accepted and sel.score == pytest.approx(0.7)
    np.testing.assert_array_equal(sel.mask, masks[1])
    sel = select_mask(masks, np.array([0.9, 0.7, 0.2]), np.array([0, 0]))
    assert not sel.accepted and sel.mask is None and "positive" in sel.reason
    sel = select_mask(masks, np.array([0.9, 0.49, 0.99]), np.array([1]))
    assert not sel.accepted and "0.49" in sel.reason
    assert select_mask(masks, np.array([0, 0.5, 0]), np.array([1])).accepted  # 0.5 is enough


# ----------------------------------------------------------------------------- SAM torch
class FakePredictor:
    """The parts of segment-anything's SamPredictor the wrapper uses."""

    def __init__(self, torch):
        self.torch = torch
        lin = torch.nn.Linear(1, 1)
        self.model = type(
            "M",
            (),
            {"image_encoder": type("E", (), {"img_size": 1024})(), "parameters": lin.parameters},
        )()
        self.set_calls, self.predict_calls = [], []

    def set_torch_image(self, img, original_size):
        self.set_calls.append((img.clone(), tuple(original_size)))
        self.features = img.mean() * self.torch.ones(1, 256, 64, 64)
        self.original_size, self.input_size = tuple(original_size), tuple(img.shape[-2:])
        self.is_image_set = True

    def predict_torch(
        self,
        coords,
        labels,
        boxes=None,
        mask_input=None,
        multimask_output=True,
        return_logits=False,
    ):
        self.predict_calls.append(
            (
                coords.clone(),
                labels.clone(),
                multimask_output,
                return_logits,
                float(self.features.mean()),
            )
        )
        h, w = self.original_size
        logits = self.torch.arange(3, dtype=self.torch.float32)[:, None, None] - 1.0
        return logits.expand(3, h, w)[None], self.torch.tensor([[0.3, 0.8, 0.6]]), None


def test_sam_torch_wrapper_plumbing():
    torch = pytest.importorskip("torch")
    fake = FakePredictor(torch)
    seg = SamTorchSegmenter.from_predictor(fake)
    a, b = _img(96, 128, 1), _img(96, 128, 2)
    seg.set_image(a, view_id="a")
    seg.set_image(b, view_id="b")
    seg.set_image(a, view_id="a")  # cached: no third encoder call, features restored
    img, size = fake.set_calls[0]
    assert len(fake.set_calls) == 2 and size == (96, 128) and tuple(img.shape) == (1, 3, 768, 1024)
    np.testing.assert_allclose(
        img[0].numpy().transpose(1, 2, 0),
        cv2.resize(a * 255, (1024, 768), interpolation=cv2.INTER_LINEAR),
        atol=2e-3,
    )
    masks, scores = seg.predict(np.array([[40.5, 30.25], [1.0, 2.0]]), np.array([1, 0]))
    coords, labels, multi, logits, feat = fake.predict_calls[-1]
    np.testing.assert_allclose(coords.numpy(), [[[40.5 * 8 - 0.5, 30.25 * 8 - 0.5], [7.5, 15.5]]])
    np.testing.assert_array_equal(labels.numpy(), [[1, 0]])
    assert multi and logits and feat == pytest.approx(float(img.mean()), rel=1e-5)
    np.testing.assert_allclose(masks[:, 0, 0], sigmoid(np.array([-1.0, 0.0, 1.0])), rtol=1e-6)
    np.testing.assert_allclose(scores, [0.3, 0.8, 0.6])
    assert select_mask(masks, scores, np.array([1, 0])).score == pytest.approx(0.8)


def test_sam_torch_missing_package_message(monkeypatch):
    try:
        import torch  # noqa: F401
    except ImportError:
        with pytest.raises(ImportError, match="'torch'"):
            SamTorchSegmenter("sam.pth", "vit_b")
        return
    monkeypatch.setitem(sys.modules, "segment_anything", None)
    with pytest.raises(ImportError, match="segment-anything"):
        SamTorchSegmenter("sam.pth", "vit_b")


def test_sam_torch_real_tiny_model_matches_sam_convention():
    """A randomly initialised tiny SAM: at s = 1, our ``u`` equals SAM's pixel index ``u − 0.5``."""
    torch = pytest.importorskip("torch")
    from functools import partial

    from divas_engine.segment.sam_upstream import sam_package

    try:  # without torchvision too (the torch extra's CPU wheel): sam_upstream
        sa = sam_package()
    except ImportError as e:
        pytest.skip(f"segment-anything not installed: {e}")

    from segment_anything.modeling import (
        ImageEncoderViT,
        MaskDecoder,
        PromptEncoder,
        Sam,
        TwoWayTransformer,
    )

    torch.manual_seed(0)
    enc = ImageEncoderViT(
        depth=1,
        embed_dim=32,
        img_size=1024,
        mlp_ratio=2,
        num_heads=1,
        norm_layer=partial(torch.nn.LayerNorm, eps=1e-6),
        patch_size=16,
        qkv_bias=True,
        use_rel_pos=False,
        global_attn_indexes=(),
        window_size=0,
        out_chans=256,
    )
    sam = Sam(
        image_encoder=enc,
        prompt_encoder=PromptEncoder(
            embed_dim=256,
            image_embedding_size=(64, 64),
            input_image_size=(1024, 1024),
            mask_in_chans=16,
        ),
        mask_decoder=MaskDecoder(
            num_multimask_outputs=3,
            transformer_dim=256,
            transformer=TwoWayTransformer(depth=1, embedding_dim=256, mlp_dim=256, num_heads=8),
            iou_head_depth=3,
            iou_head_hidden_dim=256,
        ),
    ).eval()
    pred = sa.SamPredictor(sam)
    seg = SamTorchSegmenter.from_predictor(pred)
    img = (_img(1024, 768) * 255).astype(np.uint8)
    seg.set_image(img)
    pts, labs = np.array([[300.5, 400.5], [100.5, 50.5]]), np.array([1, 0])
    masks, scores = seg.predict(pts, labs)
    ref, ref_scores, _ = pred.predict(pts - 0.5, labs, multimask_output=True, return_logits=True)
    np.testing.assert_allclose(masks, sigmoid(ref), atol=1e-5)
    np.testing.assert_allclose(scores, ref_scores, atol=1e-6)


# ------------------------------------------------------------------------ classic vs flood fill
def _texture(h, w, seed, amp=45.0):
    """One noise texture for the whole view: colour cannot tell object from background."""
    n = np.random.default_rng(seed).normal(0, 1, (h, w, 3)).astype(np.float32)
    n = cv2.GaussianBlur(n, (0, 0), 1.0)
    n /= n.std()
    return np.clip(np.array([0.45, 0.5, 0.4], np.float32) + amp / 255 * n, 0, 1)


def _scene(kind, h=240, w=320):
    rgb = _texture(h, w, seed=len(kind))
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    gt = np.zeros((h, w), np.uint8)
    if kind == "ellipse":  # flat object 1.5x nearer than the wall
        cv2.ellipse(gt, (w // 2, h // 2), (w // 5, h // 4), 20, 0, 360, 1, -1)
        depth, click = np.where(gt > 0, 2.0, 3.0), (w / 2, h / 2)
    elif kind == "slanted":  # object depth 2.0..2.2 across, background 2.6..2.9 down
        pts = np.array([[0.3, 0.2], [0.75, 0.3], [0.7, 0.8], [0.45, 0.65], [0.25, 0.75]]) * [w, h]
        cv2.fillPoly(gt, [pts.astype(np.int32)], 1)
        depth, click = np.where(gt > 0, 2.0 + 0.2 * xx / w, 2.6 + 0.3 * yy / h), (w / 2, h / 2)
    else:  # "near": disk + bar only 25 % in front of the background
        cv2.circle(gt, (int(w * 0.4), h // 2), h // 4, 1, -1)
        cv2.rectangle(gt, (int(w * 0.4), int(h * 0.4)), (int(w * 0.8), int(h * 0.6)), 1, -1)
        depth, click = np.where(gt > 0, 2.0, 2.5), (w * 0.4, h / 2)
    return rgb, depth.astype(np.float32), gt.astype(bool), np.array([click])


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


@pytest.mark.parametrize("kind", ["ellipse", "slanted", "near"])
def test_classic_depth_beats_colour_flood_fill(kind):
    rgb, depth, gt, click = _scene(kind)
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    masks, scores = seg.predict(click, np.array([1]))
    assert masks.shape == (3, 240, 320) and masks.dtype == np.float32
    assert masks.min() >= 0 and masks.max() <= 1
    iou = _iou(masks[1] >= 0.5, gt)
    assert iou > 0.9 and scores[1] >= 0.5
    flood = FloodFillSegmenter()
    flood.set_image(rgb, depth)
    fm, _ = flood.predict(click, np.array([1]))
    best_flood = max(_iou(fm[k] >= 0.5, gt) for k in range(3))
    assert best_flood < iou - 0.3
    # colour alone cannot do it either, and the score says so
    no_depth = ClassicSegmenter()
    no_depth.set_image(rgb)
    nm, ns = no_depth.predict(click, np.array([1]))
    assert _iou(nm[1] >= 0.5, gt) < 0.5 and ns[1] < 0.5
    print(f"{kind}: classic IoU {iou:.3f}, flood fill best {best_flood:.3f}")


def test_classic_soft_boundary_and_determinism():
    rgb, depth, gt, click = _scene("ellipse")
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth, view_id=0)
    m1, s1 = seg.predict(click, np.array([1]))
    res = ClassicSegmenter().segment(rgb, depth, click, np.array([1]))
    np.testing.assert_array_equal(m1, res.masks)
    np.testing.assert_array_equal(s1, res.scores)
    edge = cv2.morphologyEx(gt.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3))).astype(bool)
    soft = (m1[1] > 0.02) & (m1[1] < 0.98)
    assert (
        soft.any()
        and soft[~cv2.dilate(edge.astype(np.uint8), np.ones((9, 9))).astype(bool)].sum() == 0
    )


def test_classic_negative_click_removes_region():
    h, w = 240, 320
    rgb = _texture(h, w, 1, amp=20)
    obj = np.zeros((h, w), bool)
    obj[60:180, 80:240] = True
    right = np.zeros((h, w), bool)
    right[60:180, 160:240] = True
    rgb[obj & ~right] += np.array([0.3, -0.2, -0.2], np.float32)  # same depth, two colours
    rgb[right] += np.array([-0.2, -0.2, 0.35], np.float32)
    rgb = np.clip(rgb, 0, 1)
    depth = np.where(obj, 2.0, 3.0).astype(np.float32)
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, _ = seg.predict(np.array([[120.0, 120.0]]), np.array([1]))
    assert _iou(m[1] >= 0.5, obj) > 0.95
    m, s = seg.predict(np.array([[120.0, 120.0], [200.0, 120.0]]), np.array([1, 0]))
    assert _iou(m[1] >= 0.5, obj & ~right) > 0.95 and s[1] >= 0.5
    assert (m[:, right] >= 0.5).mean() < 0.02
    # a negative on the background (same texture, other depth) does not hurt the object
    rgb, depth, gt, click = _scene("slanted")
    seg.set_image(rgb, depth)
    m, s = seg.predict(np.vstack([click, [[10.0, 10.0]]]), np.array([1, 0]))
    assert _iou(m[1] >= 0.5, gt) > 0.9 and s[1] >= 0.5


def test_classic_granularities_ordered_and_no_positive():
    """Depth-band granularities (``edge_regions=False``, the pre-depth-edge path)."""
    h, w = 240, 320
    rgb = _texture(h, w, 2)
    box = np.zeros((h, w), bool)
    box[100:140, 140:190] = True
    plat = np.zeros((h, w), bool)
    plat[60:190, 70:260] = True  # box sits on a platform 10 % farther, wall far behind
    depth = np.where(box, 2.0, np.where(plat, 2.2, 3.5)).astype(np.float32)
    seg = ClassicSegmenter(ClassicConfig(edge_regions=False))
    seg.set_image(rgb, depth)
    m, s = seg.predict(np.array([[165.0, 120.0]]), np.array([1]))
    areas = (m >= 0.5).sum(axis=(1, 2))
    assert areas[0] <= areas[1] <= areas[2]
    assert _iou(m[0] >= 0.5, box) > 0.9 and _iou(m[1] >= 0.5, plat) > 0.9
    assert np.all(s >= 0.5)
    m, s = seg.predict(np.array([[165.0, 120.0]]), np.array([0]))
    assert not m.any() and not s.any()
    assert not select_mask(m, s, np.array([0])).accepted


def test_classic_edge_granularities_follow_jump_size():
    """Depth-edge path: a 6 % step is an edge for the small/medium jump tolerances
    (2 %, 4 %) but not for the large one (8 %): box, box, box + platform."""
    h, w = 240, 320
    rgb = _texture(h, w, 2)
    box = np.zeros((h, w), bool)
    box[100:140, 140:190] = True
    plat = np.zeros((h, w), bool)
    plat[60:190, 70:260] = True
    depth = np.where(box, 2.0, np.where(plat, 2.12, 3.5)).astype(np.float32)
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, s = seg.predict(np.array([[165.0, 120.0]]), np.array([1]))
    assert _iou(m[0] >= 0.5, box) > 0.95 and _iou(m[1] >= 0.5, box) > 0.95
    assert _iou(m[2] >= 0.5, plat) > 0.95 and np.all(s >= 0.5)


def _edge_case(kind, h=240, w=320):
    """Hand-made depth images for the depth-edge region path (same texture everywhere
    unless a colour difference is the point)."""
    rgb = _texture(h, w, seed=7, amp=20.0)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    gt = np.zeros((h, w), bool)
    if kind == "touching":  # two boxes side by side in the image, 2.0 vs 2.3, wall at 4
        a = np.zeros((h, w), bool)
        a[60:180, 60:160] = True
        b = np.zeros((h, w), bool)
        b[60:180, 160:260] = True
        depth = np.where(a, 2.0, np.where(b, 2.3, 4.0))
        gt, click, other = a, (110.0, 120.0), b
    elif kind == "bar":  # a 6-px bar 10 % in front of a wall spanning the view
        gt[:, 157:163] = True
        depth = np.where(gt, 2.7, 3.0)
        click, other = (160.0, 120.0), ~gt
    elif kind == "support":  # red box resting on a grey slab: contact, no depth jump
        gt[40:140, 120:200] = True
        slab = np.zeros((h, w), bool)
        slab[140:200, 40:280] = True
        depth = np.where(gt | slab, 2.0, 3.0)
        rgb[gt] = np.clip(rgb[gt] + np.array([0.35, -0.25, -0.2], np.float32), 0, 1)
        click, other = (160.0, 90.0), slab
    else:  # "slanted": a steep plane (depth 1.5 → 3.0 across the view) with a box in front
        gt[80:160, 120:200] = True
        plane = 1.0 / (1 / 1.5 + (1 / 3.0 - 1 / 1.5) * xx / w)  # disparity affine in x
        depth = np.where(gt, 1.2, plane)
        click, other = (40.0, 120.0), gt  # click the plane, not the box
        gt = ~gt
    return rgb, depth.astype(np.float32), gt, np.array([click]), other


def test_classic_edges_split_touching_objects():
    rgb, depth, gt, click, other = _edge_case("touching")
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, s = seg.predict(click, np.array([1]))
    assert _iou(m[1] >= 0.5, gt) > 0.95 and s[1] >= 0.5
    assert (m[1][other] >= 0.5).mean() < 0.02


def test_classic_edges_keep_thin_bar_in_front_of_wall():
    rgb, depth, gt, click, _ = _edge_case("bar")
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, s = seg.predict(click, np.array([1]))
    assert _iou(m[1] >= 0.5, gt) > 0.8 and s[1] >= 0.5


def test_classic_edges_object_on_support_stays_inside_the_jumps():
    """No depth jump between box and slab: the edge region holds both and must not
    leak past the depth jumps around them into the wall."""
    rgb, depth, gt, click, slab = _edge_case("support")
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, s = seg.predict(click, np.array([1]))
    mask = m[1] >= 0.5
    assert mask[gt].mean() > 0.95 and not mask[~(gt | slab)].any()


def test_classic_edges_do_not_cut_a_slanted_plane():
    rgb, depth, gt, click, box = _edge_case("slanted")
    seg = ClassicSegmenter()
    seg.set_image(rgb, depth)
    m, s = seg.predict(click, np.array([1]))
    mask = m[2] >= 0.5  # the large channel: the whole plane, not a depth band of it
    assert _iou(mask, gt) > 0.9
    assert (mask[box]).mean() < 0.02


def test_depth_edges_plane_invariant_and_jump():
    """A steep slanted plane has no disparity jump and no crease; a 10 % step is a jump."""
    from divas_engine.segment import depth_edges as de

    h, w = 60, 80
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    q = (1 / 1.5 + (1 / 3.0 - 1 / 1.5) * xx / w + 0.05 * yy / h).astype(np.float32)
    jh, jv = de.pair_jumps(q)
    ch, cv = de.pair_creases(q, float(w), 1)
    inner = (slice(4, -4), slice(4, -4))  # creases: the blur/Sobel rim aside
    assert max(jh.max(), jv.max()) < 1e-3 and max(ch[inner].max(), cv[inner].max()) < 1e-2
    step = np.where(xx < 40, 1 / 2.0, 1 / 2.2).astype(np.float32)
    jh, _ = de.pair_jumps(step)
    assert jh[:, 39].min() > 0.08 and np.delete(jh, 39, axis=1).max() < 1e-6


def test_classic_speed_at_640x480_reported():
    """Timings are reported, not asserted (BENCHMARKS.md rule)."""
    rgb, depth, gt, click = _scene("near", 480, 640)
    seg = ClassicSegmenter()
    t = time.perf_counter()
    seg.set_image(rgb, depth)
    m, _ = seg.predict(click, np.array([1]))
    print(f"classic 640x480: {time.perf_counter() - t:.3f} s")
    assert _iou(m[1] >= 0.5, gt) > 0.9


# ----------------------------------------------------------------------------- oracle
def _oracle(**kw):
    base = dict(bleed_prob=0.0, dropout_prob=0.0, fp_prob=0.0)
    base.update(kw)
    return OracleSegmenter(config=OracleConfig(**base))


def test_oracle_clean_downsample_logits_scores():
    h, w = 512, 384
    gt = np.zeros((h, w), np.float32)
    gt[100:300, 80:240] = 1.0
    gt[400:440, 40:80] = 0.75  # partial coverage: logit 8·0.25 = 2
    seg = _oracle()
    seg.set_image(np.zeros((h, w, 3), np.uint8), gt=gt, view_id="v")
    m, s = seg.predict(np.array([[100.0, 200.0]]), np.array([1]))
    assert seg.last_report["grid"] == (256, 192)
    np.testing.assert_allclose(s, 0.9)
    np.testing.assert_array_equal(m[0], m[1])
    np.testing.assert_allclose(m[1, 200, 160], sigmoid(np.float32(4.0)), rtol=1e-6)
    np.testing.assert_allclose(m[1, 10, 10], sigmoid(np.float32(-4.0)), rtol=1e-6)
    np.testing.assert_allclose(m[1, 420, 60], sigmoid(np.float32(2.0)), rtol=1e-5)
    assert _iou(m[1] >= 0.5, gt >= 0.5) > 0.98
    seg.set_image(np.zeros((h, w, 3), np.uint8), gt=np.zeros((h, w)))
    m, s = seg.predict(np.array([[1.0, 1.0]]), np.array([1]))
    np.testing.assert_allclose(s, 0.2)
    assert m.max() < 0.5


def test_oracle_boundary_bleed_depth_gated():
    n = 128  # below 256: the grid is the image, errors are in image pixels
    gt = np.zeros((n, n), np.float32)
    gt[40:90, 40:90] = 1
    depth = np.full((n, n), 3.0, np.float32)
    depth[:, :64] = 2.1  # left background within 10 % of the object's 2.0
    depth[gt > 0] = 2.0
    seg = _oracle(bleed_prob=1.0, bleed_min_px=4.0, bleed_max_px=4.0)
    seg.set_image(np.zeros((n, n, 3), np.uint8), depth, gt=gt)
    m = seg.predict(np.zeros((0, 2)), np.zeros(0))[0][1] >= 0.5
    row = m[65]
    assert row[36:40].all() and not row[35]  # 4 px bleed to the left
    assert not row[90:].any()  # depth 3.0 on the right: no bleed
    assert m[36:40, 45:60].all() and not m[35, 45:60].any()  # above, left half (depth 2.1)
    assert m[90:94, 45:60].all() and not m[94:, :].any()  # below, left half
    assert not m[90:, 64:].any() and not m[:40, 64:].any()  # right half never bleeds
    assert seg.last_report["bleed_px"] == 4.0
    # without depth every background within 4 px bleeds
    seg.set_image(np.zeros((n, n, 3), np.uint8), None, gt=gt)
    m = seg.predict(np.zeros((0, 2)), np.zeros(0))[0][1] >= 0.5
    assert m[65, 90:94].all() and not m[65, 94]


def test_oracle_thin_part_dropout():
    n = 160
    gt = np.zeros((n, n), np.float32)
    gt[40:100, 40:100] = 1  # body
    gt[68:70, 100:150] = 1  # 2-px arm: thin
    gt[120:121, 20:80] = 1  # 1-px wire: thin, separate
    gt[130:133, 20:80] = 1  # 3-px bar: not thin
    rgb = np.zeros((n, n, 3), np.uint8)
    seg = _oracle(dropout_prob=1.0)
    seg.set_image(rgb, gt=gt)
    m = seg.predict(np.zeros((0, 2)), np.zeros(0))[0][1] >= 0.5
    assert seg.last_report["dropped_parts"] == seg.last_report["thin_parts"] == 2
    assert not m[68:70, 101:150].any() and not m[120, 20:80].any()
    assert m[131, 20:80].all() and m[45:95, 45:95].all()
    seg = _oracle(dropout_prob=0.0)
    seg.set_image(rgb, gt=gt)
    m = seg.predict(np.zeros((0, 2)), np.zeros(0))[0][1] >= 0.5
    assert m[68:70, 101:150].all() and m[120, 20:80].all()
    # the probability: 0.3 of many independent thin parts
    many = np.zeros((200, 200), np.float32)
    many[::4, :] = 1  # 50 one-pixel lines
    fr = []
    for v in range(6):
        seg = OracleSegmenter(config=OracleConfig(bleed_prob=0, fp_prob=0, seed=v))
        seg.set_image(np.zeros((200, 200, 3), np.uint8), gt=many, view_id=v)
        fr.append(seg.last_report["dropped_parts"] / seg.last_report["thin_parts"])
    assert 0.2 < np.mean(fr) < 0.4


def test_oracle_false_positive_blob_seeded():
    n = 200
    gt = np.zeros((n, n), np.float32)
    gt[80:120, 80:120] = 1
    rgb = np.zeros((n, n, 3), np.uint8)
    seg = _oracle(fp_prob=1.0, seed=5)
    seg.set_image(rgb, gt=gt, view_id=3)
    m = seg.predict(np.zeros((0, 2)), np.zeros(0))[0][1] >= 0.5
    ncomp, lab = cv2.connectedComponents(m.astype(np.uint8))
    assert ncomp == 3  # background + object + one blob
    blob = seg.last_report["fp_blob"]
    assert 3.0 <= blob["radius"] <= 8.0
    assert m[int(blob["y"]), int(blob["x"])] and not gt[int(blob["y"]), int(blob["x"])]
    assert seg.report()["config"]["seed"] == 5
    again = _oracle(fp_prob=1.0, seed=5)
    again.set_image(rgb, gt=gt, view_id=3)
    assert again.last_report["fp_blob"] == blob
    other = _oracle(fp_prob=1.0, seed=6)
    other.set_image(rgb, gt=gt, view_id=3)
    assert other.last_report["fp_blob"] != blob
    seg = _oracle(fp_prob=0.0)
    seg.set_image(rgb, gt=gt)
    assert seg.last_report["fp_blob"] is None


def test_oracle_gt_render_callable_and_defaults():
    calls = []

    def render(view_id):
        calls.append(view_id)
        g = np.zeros((64, 64), np.float32)
        g[10:40, 10:40] = 1
        return g

    seg = OracleSegmenter(gt_render=render)
    res = seg.segment(
        np.zeros((64, 64, 3), np.uint8), None, np.array([[20.0, 20.0]]), np.array([1]), view_id="c3"
    )
    assert (
        calls == ["c3"] and res.masks.shape == (3, 64, 64) and res.scores[1] == pytest.approx(0.9)
    )
    assert OracleConfig().dropout_prob == 0.3 and OracleConfig().fp_prob == 0.2
    with pytest.raises(ValueError, match="gt"):
        OracleSegmenter().set_image(np.zeros((8, 8, 3), np.uint8))


def test_oracle_answers_prompts_on_its_own_errors():
    n = 128  # the grid is the image: a cell is a pixel
    gt = np.zeros((n, n), np.float32)
    gt[40:90, 40:90] = 1
    gt[60:62, 90:120] = 1  # a 2-px arm: thin, dropped
    seg = _oracle(dropout_prob=1.0, fp_prob=1.0, seed=5)
    seg.set_image(np.zeros((n, n, 3), np.uint8), gt=gt, view_id="v")
    blob = seg.last_report["fp_blob"]
    bx, by = blob["x"], blob["y"]
    base = seg.predict(np.array([[65.0, 65.0]]), np.array([1]))[0][1] >= 0.5
    assert base[int(by), int(bx)] and not base[61, 100:119].any()  # a blob, no arm
    # a negative point on the blob takes the whole blob back, nothing else
    m = seg.predict(np.array([[65.0, 65.0], [bx, by]]), np.array([1, 0]))[0][1] >= 0.5
    blob_px = base & ~(gt >= 0.5)
    assert not m[blob_px].any() and np.array_equal(m[~blob_px], base[~blob_px])
    # a positive point on the dropped arm brings the arm back
    m = seg.predict(np.array([[65.0, 65.0], [110.5, 60.5]]), np.array([1, 1]))[0][1] >= 0.5
    assert m[60:62, 92:118].all() and np.array_equal(m[:, :88], base[:, :88])
    # a negative point on the object itself, or a positive one on the background: nothing
    m = seg.predict(np.array([[65.0, 65.0], [50.5, 50.5], [5.5, 120.5]]), np.array([1, 0, 1]))
    np.testing.assert_array_equal(m[0][1] >= 0.5, base)
    # off: prompts are ignored, as in NOTES
    off = _oracle(dropout_prob=1.0, fp_prob=1.0, seed=5, respond_to_prompts=False)
    off.set_image(np.zeros((n, n, 3), np.uint8), gt=gt, view_id="v")
    m = off.predict(np.array([[65.0, 65.0], [bx, by]]), np.array([1, 0]))[0][1] >= 0.5
    np.testing.assert_array_equal(m, base)

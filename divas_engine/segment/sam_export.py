"""An official SAM checkpoint → the ONNX encoder/decoder pair ``sam-onnx`` runs.

Needs the ``torch`` extra (PyTorch, ``segment-anything``, ``onnx``); the pair it writes runs
with onnxruntime only. Steps of :func:`convert_checkpoint`:

1. :func:`.sam_models.load_sam_model` — tensors-only load, type checked;
2. :func:`export_onnx_pair` — the decoder through the family's own ``SamOnnxModel`` (multimask
   output, opset 17, dynamic point count, padding crop kept dynamic by :func:`_dynamic_crop`);
   the encoder in one of the layouts :class:`.sam_onnx.SamOnnxSegmenter` reads
   (:class:`EncoderLayout`);
3. :func:`check_onnx_pair` — one prediction through the ONNX pair and the PyTorch model; the
   export is refused when they disagree.

Files are written under temporary names and renamed into place; an encoder over ~1.8 GB keeps
its weights in one ``.onnx.data`` file beside it (protobuf's 2 GB limit).
:func:`cached_conversion` is the add-on's entry: one conversion per checkpoint, reused after.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import shutil
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass
from enum import StrEnum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError
from ..output_paths import file_mode, write_json_atomic
from .sam_models import FAMILIES, SamModelType, import_torch, load_sam_model
from .sam_upstream import sam_package

__all__ = [
    "EncoderLayout",
    "PairCheck",
    "SamExport",
    "export_onnx_pair",
    "check_onnx_pair",
    "convert_checkpoint",
    "cached_conversion",
    "find_cached_conversion",
    "torch_available",
    "check_image",
]

#: ONNX opset of segment-anything's decoder export script.
OPSET = 17
#: Encoders with more weight bytes than this keep them in a ``.onnx.data`` file.
EXTERNAL_DATA_BYTES = 1_800_000_000
#: ``check_onnx_pair`` limits: channel scores and the channel-1 mask (IoU at p = 0.5).
MAX_SCORE_DIFF = 0.02
MIN_MASK_IOU = 0.98
_META = "export.json"


class EncoderLayout(StrEnum):
    """Image-encoder input layouts (:mod:`.sam_onnx` reads both).

    ``PREPROCESSED``: ``image [1,3,S,S]`` float32, resized, normalised and zero-padded
    by the caller → ``image_embeddings [1,256,64,64]``. ``RAW``: ``input_image [h,w,3]``
    float32 on 0..255, longest side resized to S by the caller; normalisation
    (SAM's pixel mean/std) and bottom/right zero padding happen inside the graph.
    """

    PREPROCESSED = "preprocessed"
    RAW = "raw"


@dataclass(frozen=True)
class PairCheck:
    """One prediction through the ONNX pair and through the PyTorch model.

    Attributes:
        image_hw: the check picture's size (not square: exercises padding).
        onnx_scores, torch_scores: the 3 multimask scores of each.
        max_score_diff: largest score difference.
        mask_iou: IoU of channel 1 (DivAS's channel) thresholded at probability 0.5.
        max_prob_diff: largest per-pixel probability difference over the 3 masks.
        onnx_encode_s, torch_encode_s: encoder time of each (s).
    """

    image_hw: tuple[int, int]
    onnx_scores: tuple[float, ...]
    torch_scores: tuple[float, ...]
    max_score_diff: float
    mask_iou: float
    max_prob_diff: float
    onnx_encode_s: float
    torch_encode_s: float

    @property
    def ok(self) -> bool:
        return self.max_score_diff <= MAX_SCORE_DIFF and self.mask_iou >= MIN_MASK_IOU


@dataclass(frozen=True)
class SamExport:
    """A written encoder/decoder pair and what it came from."""

    encoder: Path
    decoder: Path
    model_type: str
    layout: str
    checkpoint: str | None = None
    check: PairCheck | None = None


def _export_model(torch: Any, module: Any, args: tuple, path: Path, **kw: Any) -> None:
    with warnings.catch_warnings():  # tracer chatter about shape-dependent Python ifs
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            args,
            str(path),
            opset_version=OPSET,
            do_constant_folding=True,
            dynamo=False,  # the TorchScript exporter segment-anything's script targets
            **kw,
        )


def _raw_encoder(torch: Any, model: Any) -> Any:
    """``input_image [h,w,3]`` (0..255) → normalise, pad to S×S, ``image_encoder``."""
    F = torch.nn.functional

    class RawImageEncoder(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = model.image_encoder
            self.size = int(model.image_encoder.img_size)
            self.register_buffer("mean", model.pixel_mean.detach().clone().view(1, 3, 1, 1))
            self.register_buffer("std", model.pixel_std.detach().clone().view(1, 3, 1, 1))

        def forward(self, input_image: Any) -> Any:
            x = (input_image.permute(2, 0, 1).unsqueeze(0) - self.mean) / self.std
            h, w = x.shape[-2], x.shape[-1]
            return self.encoder(F.pad(x, (0, self.size - w, 0, self.size - h)))

    return RawImageEncoder().eval()


def _dynamic_crop(torch: Any, sam_onnx_model: type) -> type:
    """``SamOnnxModel`` whose padding crop stays a graph computation.

    segment-anything 1.0 slices with ``int(prepadded_size[i])``, which the exporter
    freezes at the dummy image's size; slicing with the tensors themselves (as later
    segment-anything sources do) keeps the ``masks`` output right for every image.
    """
    F = torch.nn.functional

    class SamOnnxModelDynamicCrop(sam_onnx_model):
        def mask_postprocessing(self, masks: Any, orig_im_size: Any) -> Any:
            s = self.img_size
            masks = F.interpolate(masks, size=(s, s), mode="bilinear", align_corners=False)
            pre = self.resize_longest_image_size(orig_im_size, s).to(torch.int64)
            masks = masks[..., : pre[0], : pre[1]]
            hw = orig_im_size.to(torch.int64)
            return F.interpolate(masks, size=(hw[0], hw[1]), mode="bilinear", align_corners=False)

    return SamOnnxModelDynamicCrop


def _replace(src: Path, dst: Path) -> None:
    """Move a finished model file into place (fsynced first, normal permissions)."""
    with open(src, "rb+") as f:
        os.fsync(f.fileno())
    os.chmod(src, file_mode())
    os.replace(src, dst)


def export_onnx_pair(
    model: Any,
    out_dir: str | PathLike,
    *,
    layout: EncoderLayout | str = EncoderLayout.PREPROCESSED,
    stem: str = "sam",
) -> tuple[Path, Path]:
    """Write ``<stem>_encoder.onnx`` and ``<stem>_decoder.onnx`` for a SAM ``model``.

    ``model`` is a ``Sam`` of segment-anything or MobileSAM (any image encoder with
    ``img_size`` producing ``[1,256,64,64]``). Returns the two paths.
    """
    torch = import_torch("exporting SAM to ONNX")
    onnx_utils = importlib.import_module(f"{_package_of(model)}.utils.onnx")
    layout = EncoderLayout(layout)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    enc_path, dec_path = out / f"{stem}_encoder.onnx", out / f"{stem}_decoder.onnx"
    size = int(model.image_encoder.img_size)
    emb_hw = tuple(model.prompt_encoder.image_embedding_size)
    with tempfile.TemporaryDirectory(dir=out, prefix=".sam-export-") as tmp_s:
        tmp = Path(tmp_s)
        # decoder: segment-anything's SamOnnxModel, as its export script calls it
        # eval() first: the exporter puts the wrapper back in its own mode afterwards, and a
        # new module is in training mode — which would leave the model training (TinyViT's
        # BatchNorm and attention-bias cache behave differently then)
        dec = _dynamic_crop(torch, onnx_utils.SamOnnxModel)(model, return_single_mask=False)
        dec.eval()
        dummy = {
            "image_embeddings": torch.randn(1, model.prompt_encoder.embed_dim, *emb_hw),
            "point_coords": torch.randint(0, size, (1, 5, 2), dtype=torch.float),
            "point_labels": torch.randint(0, 4, (1, 5), dtype=torch.float),
            "mask_input": torch.randn(1, 1, 4 * emb_hw[0], 4 * emb_hw[1]),
            "has_mask_input": torch.tensor([1], dtype=torch.float),
            "orig_im_size": torch.tensor([1500, 2250], dtype=torch.float),
        }
        _export_model(
            torch,
            dec,
            tuple(dummy.values()),
            tmp / dec_path.name,
            input_names=list(dummy),
            output_names=["masks", "iou_predictions", "low_res_masks"],
            dynamic_axes={"point_coords": {1: "num_points"}, "point_labels": {1: "num_points"}},
        )
        # encoder
        raw_dir = tmp / "encoder"
        raw_dir.mkdir()
        if layout is EncoderLayout.PREPROCESSED:
            wrapped, name = model.image_encoder, "image"
            args = (torch.zeros(1, 3, size, size),)
            axes = None
        else:
            wrapped, name = _raw_encoder(torch, model), "input_image"
            args = (torch.full((size * 3 // 4, size, 3), 128.0),)
            axes = {"input_image": {0: "image_height", 1: "image_width"}}
        with torch.no_grad():
            _export_model(
                torch,
                wrapped,
                args,
                raw_dir / enc_path.name,
                input_names=[name],
                output_names=["image_embeddings"],
                dynamic_axes=axes,
            )
        nbytes = sum(p.numel() * p.element_size() for p in model.image_encoder.parameters())
        _finish_encoder(raw_dir / enc_path.name, tmp / enc_path.name, nbytes)
        model.eval()
        for f in sorted(tmp.glob(f"{enc_path.name}.data")):  # weights first, then graphs
            _replace(f, out / f.name)
        _replace(tmp / dec_path.name, dec_path)
        _replace(tmp / enc_path.name, enc_path)
    return enc_path, dec_path


def _finish_encoder(exported: Path, final: Path, nbytes: int) -> None:
    """Move the encoder into place; a large one gets its weights in one ``.data`` file."""
    if nbytes <= EXTERNAL_DATA_BYTES and not any(p != exported for p in exported.parent.iterdir()):
        _replace(exported, final)
        return
    import onnx  # the torch extra's: only for >2 GB graphs

    m = onnx.load(str(exported))  # the exporter's per-tensor files are read back
    onnx.save_model(
        m,
        str(final),
        save_as_external_data=True,
        all_tensors_to_one_file=True,
        location=f"{final.name}.data",
        size_threshold=1024,
    )


def check_image(h: int = 384, w: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fixed check picture (a lit disc on a gradient) and its prompts.

    Returns ``rgb [h,w,3]`` uint8, ``points [2,2]`` (a positive on the disc, a negative
    on the background) and ``labels [2]``.
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    rgb = np.stack([0.2 + 0.5 * xx / w, 0.3 + 0.4 * yy / h, 0.5 - 0.3 * xx / w], axis=-1)
    cx, cy, r = 0.6 * w, 0.45 * h, 0.22 * min(h, w)
    disc = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    rgb[disc] = (0.9, 0.35, 0.2)
    rgb8 = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    return rgb8, np.array([[cx, cy], [0.12 * w, 0.85 * h]]), np.array([1, 0])


def check_onnx_pair(model: Any, encoder: str | PathLike, decoder: str | PathLike) -> PairCheck:
    """Run :func:`check_image` through the ONNX pair and through ``model`` (PyTorch)."""
    from .sam_onnx import SamOnnxSegmenter
    from .sam_torch import SamTorchSegmenter

    sam_package(_package_of(model))
    rgb, pts, labs = check_image()
    onnx_seg = SamOnnxSegmenter(encoder, decoder, cache_size=1)
    t0 = time.perf_counter()
    onnx_seg.set_image(rgb)
    t1 = time.perf_counter()
    m_onnx, s_onnx = onnx_seg.predict(pts, labs)
    predictor = sam_package(_package_of(model)).SamPredictor(model)
    torch_seg = SamTorchSegmenter.from_predictor(predictor, cache_size=1)
    t2 = time.perf_counter()
    torch_seg.set_image(rgb)
    t3 = time.perf_counter()
    m_torch, s_torch = torch_seg.predict(pts, labs)
    a, b = m_onnx[1] >= 0.5, m_torch[1] >= 0.5
    union = int(np.count_nonzero(a | b))
    return PairCheck(
        image_hw=rgb.shape[:2],
        onnx_scores=tuple(float(x) for x in s_onnx),
        torch_scores=tuple(float(x) for x in s_torch),
        max_score_diff=float(np.max(np.abs(s_onnx - s_torch))),
        mask_iou=1.0 if union == 0 else float(np.count_nonzero(a & b)) / union,
        max_prob_diff=float(np.max(np.abs(m_onnx - m_torch))),
        onnx_encode_s=t1 - t0,
        torch_encode_s=t3 - t2,
    )


def _package_of(model: Any) -> str:
    """The package that defines ``model`` (and so its ``SamOnnxModel``, ``SamPredictor``)."""
    pkg = type(model).__module__.split(".")[0]
    return sam_package(pkg).__name__


def convert_checkpoint(
    checkpoint: str | PathLike,
    model_type: SamModelType | str,
    out_dir: str | PathLike,
    *,
    layout: EncoderLayout | str = EncoderLayout.PREPROCESSED,
    check: bool = True,
) -> SamExport:
    """Checkpoint → checked ONNX pair in ``out_dir`` (module docstring).

    Raises:
        DivasInputError: bad checkpoint, or the ONNX pair disagrees with the model (nothing
            is written then; files already in ``out_dir`` are kept).
        ImportError: the ``torch`` extra (or MobileSAM's package) is missing.
    """
    path = Path(checkpoint)
    t = SamModelType.parse(model_type, path)
    model = load_sam_model(path, t)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = path.stem or t.value
    # exported and checked in a temporary folder: only a pair that passed replaces files
    with tempfile.TemporaryDirectory(dir=out, prefix=".sam-convert-") as tmp_s:
        enc, dec = export_onnx_pair(model, tmp_s, layout=layout, stem=stem)
        result = check_onnx_pair(model, enc, dec) if check else None
        if result is not None and not result.ok:
            raise DivasInputError(
                path,
                f"the exported ONNX pair disagrees with the PyTorch model (score difference "
                f"{result.max_score_diff:.4f}, channel-1 mask IoU {result.mask_iou:.4f}); "
                "nothing was written",
            )
        for f in sorted(Path(tmp_s).glob(f"{enc.name}.data")):
            _replace(f, out / f.name)
        _replace(dec, out / dec.name)
        _replace(enc, out / enc.name)
    export = SamExport(
        out / enc.name,
        out / dec.name,
        t.value,
        EncoderLayout(layout).value,
        str(path.resolve()),
        result,
    )
    _write_meta(out / _META, export, _source_key(path, t))
    return export


def _source_key(path: Path, t: SamModelType) -> dict[str, Any]:
    st = path.stat()
    return {
        "checkpoint": str(path.resolve()),
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "model_type": t.value,
    }


def _write_meta(path: Path, export: SamExport, key: dict[str, Any]) -> None:
    doc = {
        "source": key,
        "encoder": export.encoder.name,
        "decoder": export.decoder.name,
        "layout": export.layout,
        "check": None if export.check is None else asdict(export.check),
    }
    write_json_atomic(path, doc)


def _cache_folder(path: Path, t: SamModelType, cache_root: str | PathLike) -> Path:
    key = _source_key(path, t)
    digest = hashlib.blake2b(json.dumps(key, sort_keys=True).encode(), digest_size=8).hexdigest()
    return Path(cache_root) / f"{path.stem}-{t.value}-{digest}"


def find_cached_conversion(
    checkpoint: str | PathLike, model_type: SamModelType | str, cache_root: str | PathLike
) -> SamExport | None:
    """The cached pair of ``checkpoint`` if it was converted already, else None (no work)."""
    path = Path(checkpoint)
    try:
        t = SamModelType.parse(model_type, path)
        return _read_cached(_cache_folder(path, t, cache_root), _source_key(path, t))
    except (OSError, DivasInputError):
        return None


def cached_conversion(
    checkpoint: str | PathLike, model_type: SamModelType | str, cache_root: str | PathLike
) -> SamExport:
    """The pair of ``checkpoint`` under ``cache_root``, converting it the first time.

    One folder per (resolved path, size, modification time, type): a changed or
    replaced checkpoint converts again; an unchanged one returns at once.
    """
    path = Path(checkpoint)
    t = SamModelType.parse(model_type, path)
    if not path.is_file():
        raise DivasInputError(path, "SAM checkpoint file not found")
    folder = _cache_folder(path, t, cache_root)
    cached = _read_cached(folder, _source_key(path, t))
    if cached is not None:
        return cached
    if folder.exists():
        shutil.rmtree(folder)  # a stale or interrupted conversion of this exact source
    return convert_checkpoint(path, t, folder)


def _read_cached(folder: Path, key: dict[str, Any]) -> SamExport | None:
    try:
        doc = json.loads((folder / _META).read_text())
    except (OSError, ValueError):
        return None
    enc, dec = folder / str(doc.get("encoder")), folder / str(doc.get("decoder"))
    if doc.get("source") != key or not (enc.is_file() and dec.is_file()):
        return None
    chk = doc.get("check")
    return SamExport(
        enc,
        dec,
        key["model_type"],
        str(doc.get("layout")),
        key["checkpoint"],
        None
        if chk is None
        else PairCheck(**{k: tuple(v) if isinstance(v, list) else v for k, v in chk.items()}),
    )


def torch_available() -> bool:
    """Whether ``torch`` is installed (without importing it)."""
    return importlib.util.find_spec("torch") is not None


def official_checkpoint_name(model_type: SamModelType | str) -> str:
    """The file name the model's authors publish for ``model_type``."""
    return FAMILIES[SamModelType.parse(model_type)].checkpoint

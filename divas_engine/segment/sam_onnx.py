"""SAM (ViT-H/L/B) and MobileSAM through onnxruntime — no PyTorch needed.

Two files: an image encoder (a *preprocessed* ``[1,3,S,S]`` input that :mod:`.sam_common`
resizes, normalises and pads, or a *raw* ``[h,w,3]`` input that normalises inside the model)
and the prompt decoder with segment-anything's ``scripts/export_onnx_model.py`` signature.
The decoder's ``low_res_masks`` are upscaled here (:func:`.sam_common.upscale_low_res_masks`)
rather than its ``masks`` trusted: segment-anything 1.0's export crops the padding at the
export dummy's aspect ratio. Of a 4-mask output, masks 1..3 (the multimask output) are kept;
a single-mask export is refused. Inputs and outputs in full: docs/design-notes.md.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DivasInputError
from .base import Segmenter
from .sam_common import (
    SAM_CACHE_VIEWS,
    SAM_IMAGE_SIZE,
    SAM_PIXEL_MEAN,
    decoder_prompts,
    normalize_pad,
    resize_longest_side,
    sigmoid,
    upscale_low_res_masks,
)

__all__ = ["SamOnnxSegmenter", "DECODER_INPUTS"]

#: Input names of segment-anything's ONNX decoder export.
DECODER_INPUTS = (
    "image_embeddings",
    "point_coords",
    "point_labels",
    "mask_input",
    "has_mask_input",
    "orig_im_size",
)

_ORT_TYPES = {
    "tensor(float)": np.float32,
    "tensor(double)": np.float64,
    "tensor(int64)": np.int64,
    "tensor(int32)": np.int32,
    "tensor(uint8)": np.uint8,
}


def _open_session(path: Path, providers: Sequence[str] | None, what: str) -> Any:
    try:
        import onnxruntime as ort
    except ImportError as exc:  # pragma: no cover - onnxruntime is a core dependency
        raise DivasInputError(path, f"the SAM {what} needs the 'onnxruntime' package") from exc
    if not path.is_file():
        raise DivasInputError(path, f"SAM {what} model file not found")
    try:
        return ort.InferenceSession(
            str(path), providers=list(providers or ["CPUExecutionProvider"])
        )
    except Exception as exc:  # onnxruntime raises its own Fail/InvalidGraph types
        raise DivasInputError(path, f"cannot load the SAM {what} as an ONNX model: {exc}") from exc


def _static(dim: Any) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


class SamOnnxSegmenter(Segmenter):
    """SAM / MobileSAM from an ONNX encoder + decoder pair (module docstring).

    Args:
        encoder_path: image encoder ``.onnx``.
        decoder_path: prompt decoder ``.onnx`` (official export signature).
        providers: onnxruntime execution providers (default CPU).
        cache_size: views whose embeddings are kept (:data:`.sam_common.SAM_CACHE_VIEWS`:
            a click that corrects a fused view runs the decoder only).
    """

    name = "sam-onnx"

    def __init__(
        self,
        encoder_path: str | PathLike,
        decoder_path: str | PathLike,
        providers: Sequence[str] | None = None,
        cache_size: int = SAM_CACHE_VIEWS,
    ):
        super().__init__(cache_size)
        self.encoder_path, self.decoder_path = Path(encoder_path), Path(decoder_path)
        self._enc = _open_session(self.encoder_path, providers, "encoder")
        self._dec = _open_session(self.decoder_path, providers, "decoder")
        self._inspect_encoder()
        self._inspect_decoder()

    # -- signature checks ------------------------------------------------------
    def _inspect_encoder(self) -> None:
        ins = self._enc.get_inputs()
        if len(ins) != 1:
            raise DivasInputError(
                self.encoder_path,
                f"SAM encoder must take one image input, has {[i.name for i in ins]}",
            )
        inp, shape = ins[0], list(ins[0].shape)
        self._enc_input, self._enc_dtype = inp.name, _ORT_TYPES.get(inp.type)
        if len(shape) == 4 and shape[1] == 3:
            self.encoder_layout = "preprocessed"
            self.image_size = _static(shape[2]) or _static(shape[3]) or SAM_IMAGE_SIZE
            if self._enc_dtype not in (np.float32, np.float64):
                raise DivasInputError(
                    self.encoder_path,
                    f"preprocessed SAM encoder input must be float, is {inp.type}",
                )
        elif len(shape) in (3, 4) and shape[-1] == 3:
            self.encoder_layout = "raw"
            self._raw_hw = (_static(shape[-3]), _static(shape[-2]))
            fixed = [d for d in self._raw_hw if d is not None]
            self.image_size = max(fixed) if fixed else SAM_IMAGE_SIZE
            if self._enc_dtype not in (np.float32, np.float64, np.uint8):
                raise DivasInputError(
                    self.encoder_path,
                    f"raw SAM encoder input must be float or uint8, is {inp.type}",
                )
        else:
            raise DivasInputError(
                self.encoder_path,
                f"unrecognised SAM encoder input {inp.name!r} "
                f"{shape}: expected [1,3,1024,1024] (preprocessed) or "
                f"[H,W,3] (preprocessing inside)",
            )
        self._enc_rank = len(shape)
        outs = self._enc.get_outputs()
        out = next((o for o in outs if o.name == "image_embeddings"), outs[0])
        if len(out.shape) != 4:
            raise DivasInputError(
                self.encoder_path,
                f"SAM encoder output {out.name!r} has shape {out.shape}, expected [1,256,64,64]",
            )
        self._enc_output = out.name

    def _inspect_decoder(self) -> None:
        ins = {i.name: i for i in self._dec.get_inputs()}
        missing = [n for n in DECODER_INPUTS if n not in ins]
        if missing:
            raise DivasInputError(
                self.decoder_path,
                f"not a SAM ONNX decoder: missing inputs {missing} (has {sorted(ins)})",
            )
        extra = sorted(set(ins) - set(DECODER_INPUTS))
        if extra:
            raise DivasInputError(self.decoder_path, f"SAM decoder has unexpected inputs {extra}")
        self._dec_types = {n: _ORT_TYPES.get(ins[n].type, np.float32) for n in DECODER_INPUTS}
        mshape = list(ins["mask_input"].shape)
        self._mask_input_hw = (
            (_static(mshape[-2]) or 256, _static(mshape[-1]) or 256)
            if len(mshape) == 4
            else (256, 256)
        )
        outs = self._dec.get_outputs()
        names = [o.name for o in outs]
        if len(outs) < 2:
            raise DivasInputError(
                self.decoder_path,
                f"SAM decoder needs masks and iou_predictions outputs, has {names}",
            )
        self._mask_out = "masks" if "masks" in names else names[0]
        self._iou_out = "iou_predictions" if "iou_predictions" in names else names[1]
        self._low_res_out = "low_res_masks" if "low_res_masks" in names else None
        mo = next(o for o in outs if o.name == self._mask_out)
        if len(mo.shape) == 4 and _static(mo.shape[1]) == 1:
            raise DivasInputError(
                self.decoder_path,
                "SAM decoder was exported with "
                "--return-single-mask; DivAS needs the 3 multimask outputs — "
                "re-export without that flag",
            )

    # -- Segmenter hooks --------------------------------------------------------
    def preprocess(self, rgb01: np.ndarray) -> np.ndarray:
        """The exact encoder feed for ``rgb01 [H,W,3]`` float in [0,1] (module docstring)."""
        resized = resize_longest_side(rgb01, self.image_size)
        if self.encoder_layout == "preprocessed":
            return normalize_pad(resized, self.image_size).astype(self._enc_dtype)
        fh, fw = self._raw_hw
        h, w = resized.shape[:2]
        if fh is not None or fw is not None:
            ph, pw = max(fh or h, h), max(fw or w, w)
            padded = np.empty((ph, pw, 3), np.float32)
            padded[:] = SAM_PIXEL_MEAN
            padded[:h, :w] = resized
            resized = padded
        if self._enc_dtype == np.uint8:
            resized = np.clip(np.rint(resized), 0, 255)
        feed = resized.astype(self._enc_dtype)
        return feed[None] if self._enc_rank == 4 else feed

    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        emb = self._enc.run([self._enc_output], {self._enc_input: self.preprocess(rgb)})[0]
        emb = np.asarray(emb, dtype=np.float32)
        if emb.ndim != 4 or emb.shape[0] != 1:
            raise DivasInputError(
                self.encoder_path, f"SAM encoder produced {emb.shape}, expected [1,256,64,64]"
            )
        return emb, rgb.shape[:2]

    def _predict(
        self, state: Any, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        emb, (h, w) = state
        coords, labs = decoder_prompts(points, labels, (h, w), self.image_size)
        t = self._dec_types
        feeds = {
            "image_embeddings": emb.astype(t["image_embeddings"], copy=False),
            "point_coords": coords.astype(t["point_coords"]),
            "point_labels": labs.astype(t["point_labels"]),
            "mask_input": np.zeros((1, 1, *self._mask_input_hw), t["mask_input"]),
            "has_mask_input": np.zeros((1,), t["has_mask_input"]),
            "orig_im_size": np.array([h, w], t["orig_im_size"]),
        }
        if self._low_res_out is not None:  # upscaled here: see upscale_low_res_masks
            low, iou = self._dec.run([self._low_res_out, self._iou_out], feeds)
            low = np.asarray(low, dtype=np.float32)
            masks = upscale_low_res_masks(low.reshape(-1, *low.shape[-2:]), (h, w), self.image_size)
        else:
            masks, iou = self._dec.run([self._mask_out, self._iou_out], feeds)
        masks = (
            np.asarray(masks, dtype=np.float32).reshape(-1, h, w)
            if np.size(masks) % (h * w) == 0
            else np.asarray(masks)
        )
        iou = np.asarray(iou, dtype=np.float32).reshape(-1)
        if masks.ndim != 3 or masks.shape[1:] != (h, w) or masks.shape[0] != iou.shape[0]:
            raise DivasInputError(
                self.decoder_path,
                f"SAM decoder returned masks "
                f"{np.shape(masks)} / scores {iou.shape} for image {h}x{w}",
            )
        if masks.shape[0] == 4:
            masks, iou = masks[1:], iou[1:]
        elif masks.shape[0] != 3:
            raise DivasInputError(
                self.decoder_path,
                f"SAM decoder returned {masks.shape[0]} masks; need the 3-mask multimask output",
            )
        return sigmoid(masks), iou

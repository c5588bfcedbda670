"""SAM through its own PyTorch package (optional: the ``torch`` extra).

``torch`` and the family's package (``segment-anything``; MobileSAM's ``mobile_sam``)
are imported lazily, only when this segmenter is built, through
:mod:`.sam_upstream` (no torchvision needed); a clear error names what is missing.
The checkpoint is read by :func:`.sam_models.load_sam_model` (tensors only, its type
checked). Preprocessing and prompt mapping are *ours*
(:mod:`.sam_common`, shared with the ONNX back end), handed to the predictor's
tensor-level API:

* ``set_image``: longest-side resize (float, antialiased) →
  ``predictor.set_torch_image(image [1,3,h,w] on 0..255, (H, W))``, which
  normalises, pads and runs the encoder; the features are cached per view.
* ``predict``: ``predictor.predict_torch(coords [1,P,2], labels [1,P],
  multimask_output=True, return_logits=True)`` with coordinates already in the
  resized frame, ``u · s − 0.5`` (SAM adds 0.5 and pads the no-box point itself);
  logits → sigmoid.
"""

from __future__ import annotations

from collections.abc import Hashable
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from .base import Segmenter
from .sam_common import SAM_CACHE_VIEWS, resize_longest_side, sam_point_coords, sigmoid
from .sam_models import FAMILIES, SamModelType, import_torch, load_sam_model
from .sam_upstream import sam_package

__all__ = ["SamTorchSegmenter", "SAM_MODEL_TYPES"]

#: ``model_type`` values (``default`` is ``vit_h``, as in ``sam_model_registry``).
SAM_MODEL_TYPES = (*(t.value for t in SamModelType), "default")


def _import_torch() -> Any:
    return import_torch("SamTorchSegmenter")


class SamTorchSegmenter(Segmenter):
    """SAM via the family's own ``SamPredictor`` (module docstring).

    Args:
        checkpoint: official checkpoint (``sam_vit_*.pth``, ``mobile_sam.pt``).
        model_type: ``vit_h``, ``vit_l``, ``vit_b`` or ``mobile_sam``.
        device: torch device (default: CUDA when available, else CPU).
        cache_size: views whose embeddings are kept (:data:`.sam_common.SAM_CACHE_VIEWS`:
            a click that corrects a fused view runs the decoder only).
    """

    name = "sam-torch"

    def __init__(
        self,
        checkpoint: str | PathLike,
        model_type: str = "vit_h",
        device: str | None = None,
        cache_size: int = SAM_CACHE_VIEWS,
    ):
        torch = _import_torch()
        t = SamModelType.parse(model_type, Path(checkpoint))
        try:
            predictor_cls = sam_package(FAMILIES[t].package).SamPredictor
        except ImportError as exc:
            raise ImportError(
                f"SamTorchSegmenter ({t.value}) needs the optional package "
                f"{FAMILIES[t].package.replace('_', '-')!r} ({FAMILIES[t].install}): {exc}"
            ) from exc
        model = load_sam_model(checkpoint, t)
        dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
        model.to(device=dev).eval()
        self._init_from_predictor(predictor_cls(model), cache_size)

    @classmethod
    def from_predictor(cls, predictor: Any, cache_size: int = SAM_CACHE_VIEWS) -> SamTorchSegmenter:
        """Wrap an existing ``SamPredictor``-like object (custom builds, tests)."""
        _import_torch()
        self = cls.__new__(cls)
        self._init_from_predictor(predictor, cache_size)
        return self

    def _init_from_predictor(self, predictor: Any, cache_size: int) -> None:
        Segmenter.__init__(self, cache_size)
        self.predictor = predictor
        self.image_size = int(predictor.model.image_encoder.img_size)

    def _device(self) -> Any:
        return next(iter(self.predictor.model.parameters())).device

    def _encode(self, rgb: np.ndarray, depth: np.ndarray | None, view_id: Hashable | None) -> Any:
        torch = _import_torch()
        resized = resize_longest_side(rgb, self.image_size)
        img = torch.from_numpy(np.ascontiguousarray(resized.transpose(2, 0, 1)))[None]
        with torch.no_grad():
            self.predictor.set_torch_image(img.to(self._device()), tuple(rgb.shape[:2]))
        p = self.predictor
        return {
            "features": p.features,
            "original_size": tuple(p.original_size),
            "input_size": tuple(p.input_size),
        }

    def _predict(
        self, state: Any, points: np.ndarray, labels: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        torch = _import_torch()
        p = self.predictor
        p.features = state["features"]  # restore the cached view (cheap when unchanged)
        p.original_size, p.input_size = state["original_size"], state["input_size"]
        p.is_image_set = True
        h, w = state["original_size"]
        dev = self._device()
        coords = torch.as_tensor(
            sam_point_coords(points, (h, w), self.image_size)[None], dtype=torch.float32, device=dev
        )
        labs = torch.as_tensor(labels[None], dtype=torch.int64, device=dev)
        with torch.no_grad():
            masks, iou, _ = p.predict_torch(coords, labs, multimask_output=True, return_logits=True)
        masks = masks[0].detach().float().cpu().numpy()
        iou = iou[0].detach().float().cpu().numpy()
        return sigmoid(masks), iou

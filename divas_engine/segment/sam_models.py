"""Official SAM checkpoints → PyTorch models (optional: needs the ``torch`` extra).

A checkpoint is the file the model's authors publish — a ``state_dict`` saved with
``torch.save`` (Meta's ``sam_vit_{b,l,h}_*.pth``, MobileSAM's ``mobile_sam.pt``; a dict
holding it under ``"model"`` is accepted too). It is read with
``torch.load(weights_only=True)``: tensors only, no pickled code runs. The model is
built by the family's own package (:mod:`.sam_upstream`): ``segment-anything``'s
``sam_model_registry`` for ViT-B/L/H, MobileSAM's ``mobile_sam`` (``vit_t``, TinyViT)
for ``mobile_sam``. A checkpoint of another type than the one named is refused with
the type its image encoder actually has.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from os import PathLike
from pathlib import Path
from typing import Any

from ..errors import DivasInputError
from .sam_upstream import sam_package

__all__ = [
    "SamModelType",
    "SamFamily",
    "import_torch",
    "read_state_dict",
    "guess_model_type",
    "build_sam_model",
    "load_sam_model",
]


class SamModelType(StrEnum):
    """Checkpoint types ``divas sam-export`` converts (``--model-type``)."""

    VIT_B = "vit_b"
    VIT_L = "vit_l"
    VIT_H = "vit_h"
    MOBILE_SAM = "mobile_sam"

    @classmethod
    def parse(cls, name: str, path: Path | None = None) -> SamModelType:
        key = str(name).strip().lower().replace("-", "_")
        key = {"default": "vit_h", "vit_t": "mobile_sam", "mobilesam": "mobile_sam"}.get(key, key)
        try:
            return cls(key)
        except ValueError:
            kinds = ", ".join(k.value for k in cls)
            raise DivasInputError(
                path, f"unknown SAM model type {name!r} (one of {kinds})"
            ) from None


@dataclass(frozen=True)
class SamFamily:
    """Where a model type's architecture comes from.

    Attributes:
        package: the Python package that defines it (:data:`.sam_upstream.SAM_PACKAGES`).
        registry_key: its key in that package's ``sam_model_registry``.
        install: what to install when the package is missing.
        checkpoint: the official file name.
    """

    package: str
    registry_key: str
    install: str
    checkpoint: str


FAMILIES = {
    SamModelType.VIT_B: SamFamily(
        "segment_anything", "vit_b", 'pip install -e ".[torch]"', "sam_vit_b_01ec64.pth"
    ),
    SamModelType.VIT_L: SamFamily(
        "segment_anything", "vit_l", 'pip install -e ".[torch]"', "sam_vit_l_0b3195.pth"
    ),
    SamModelType.VIT_H: SamFamily(
        "segment_anything", "vit_h", 'pip install -e ".[torch]"', "sam_vit_h_4b8939.pth"
    ),
    SamModelType.MOBILE_SAM: SamFamily(
        "mobile_sam",
        "vit_t",
        "MobileSAM's package (its repository, or PyPI's mobilesam-mirror) with timm "
        "and a torchvision matching your torch",
        "mobile_sam.pt",
    ),
}

#: Image-encoder width (``patch_embed.proj.weight`` rows) of each ViT type.
_VIT_WIDTH = {768: SamModelType.VIT_B, 1024: SamModelType.VIT_L, 1280: SamModelType.VIT_H}


def import_torch(what: str = "this") -> Any:
    """``torch``, or an ImportError saying how to install the ``torch`` extra."""
    try:
        import torch
    except ImportError as exc:
        raise ImportError(
            f"{what} needs the optional package 'torch': pip install -e \".[torch]\" (its CPU "
            "wheel is enough); without it use an ONNX encoder/decoder pair (sam-onnx)"
        ) from exc
    return torch


def read_state_dict(path: str | PathLike) -> dict[str, Any]:
    """The checkpoint's ``state_dict`` (tensors only: ``weights_only=True``)."""
    torch = import_torch("reading a SAM checkpoint")
    p = Path(path)
    if not p.is_file():
        raise DivasInputError(p, "SAM checkpoint file not found")
    try:
        obj = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # not a zip/pickle, or pickled code weights_only refuses
        raise DivasInputError(p, f"not a PyTorch checkpoint of tensors: {exc}") from exc
    if isinstance(obj, dict) and isinstance(obj.get("model"), dict):
        obj = obj["model"]
    if not isinstance(obj, dict) or not obj or not all(torch.is_tensor(v) for v in obj.values()):
        raise DivasInputError(p, "not a SAM checkpoint: expected a state_dict of tensors")
    return obj


def guess_model_type(state_dict: dict[str, Any]) -> str | None:
    """The type a state dict's image encoder has, or None when it is not SAM's.

    ViT-B/L/H by width (768/1024/1280) *and* depth (12/24/32 blocks); MobileSAM by
    TinyViT's convolutional patch embedding. A ViT of another size is named by its
    shape (``"ViT, width 64, 2 blocks"``).
    """
    w = state_dict.get("image_encoder.patch_embed.proj.weight")
    if w is not None:
        width = int(w.shape[0])
        blocks = {k.split(".")[2] for k in state_dict if k.startswith("image_encoder.blocks.")}
        depth = {SamModelType.VIT_B: 12, SamModelType.VIT_L: 24, SamModelType.VIT_H: 32}
        t = _VIT_WIDTH.get(width)
        if t is not None and depth[t] == len(blocks):
            return t.value
        return f"ViT, width {width}, {len(blocks)} blocks"
    if "image_encoder.patch_embed.seq.0.c.weight" in state_dict:
        return SamModelType.MOBILE_SAM.value
    if any(k.startswith("image_encoder.trunk.") for k in state_dict):
        return "SAM 2 (Hiera)"
    return None


def build_sam_model(model_type: SamModelType | str) -> Any:
    """A randomly initialised model of ``model_type`` from its family's package."""
    t = SamModelType.parse(model_type)
    fam = FAMILIES[t]
    try:
        pkg = sam_package(fam.package)
    except ImportError as exc:
        raise ImportError(
            f"SAM model type {t.value} needs the package {fam.package!r} ({fam.install}): {exc}"
        ) from exc
    return pkg.sam_model_registry[fam.registry_key]().eval()


def load_sam_model(checkpoint: str | PathLike, model_type: SamModelType | str) -> Any:
    """The model of an official checkpoint, in eval mode on the CPU.

    Raises:
        DivasInputError: missing file, not a checkpoint, or a checkpoint of another type
            (the message names the type it holds).
        ImportError: torch or the family's package is not installed.
    """
    path = Path(checkpoint)
    t = SamModelType.parse(model_type, path)
    import_torch(f"SAM model type {t.value}")
    state = read_state_dict(path)
    found = guess_model_type(state)
    if found is None:
        raise DivasInputError(path, "not a SAM checkpoint (no image_encoder weights)")
    model = build_sam_model(t)
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    got = {k: tuple(v.shape) for k, v in state.items()}
    if expected != got:  # another model type (or another model altogether)
        raise DivasInputError(
            path,
            f"this checkpoint holds a {found} image encoder, not {t.value}: pass the "
            "matching --model-type"
            if found != t.value
            else f"weights do not fit the {t.value} model ({len(set(expected) ^ set(got))} "
            "keys differ)",
        )
    model.load_state_dict(state, strict=True)
    return model.eval()

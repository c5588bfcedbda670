"""Building the 2D segmenter a session uses, for every caller (CLI, add-on, scripts).

:func:`build_segmenter` turns a :class:`SegmenterSettings` into a
:class:`~.base.Segmenter`. What a kind needs and does not have is one
:class:`SegmenterSetupError`: a plain sentence naming the segmenter and what it needs,
plus :attr:`SegmenterSetupError.requires` (the :class:`SegmenterSettings` fields, or
``"ground_truth"``) so a host can say where its user sets them (a command-line flag, a
preference) without repeating the check.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from ..errors import DivasInputError
from .base import Segmenter
from .classic import ClassicConfig, ClassicSegmenter
from .graph3d import Graph3DSegmenter
from .oracle import OracleConfig, OracleSegmenter
from .sam_onnx import SamOnnxSegmenter
from .sam_torch import SamTorchSegmenter

__all__ = [
    "DEFAULT_SEGMENTER",
    "SegmenterKind",
    "SegmenterSettings",
    "SegmenterSetupError",
    "build_segmenter",
]


class SegmenterKind(StrEnum):
    """The 2D mask sources a session can use (values: the segmenters' ``name``).

    ``GRAPH3D`` weight-free 3D cut over the scene's primitives (the default);
    ``CLASSIC`` weight-free GrabCut on colour + depth; ``SAM_ONNX`` SAM / MobileSAM via
    onnxruntime; ``SAM_TORCH`` SAM via ``segment-anything``; ``ORACLE`` ground truth with
    SAM-like errors (evaluation only).
    """

    GRAPH3D = "graph3d"
    CLASSIC = "classic"
    SAM_ONNX = "sam-onnx"
    SAM_TORCH = "sam-torch"
    ORACLE = "oracle"

    @classmethod
    def parse(cls, name: str) -> SegmenterKind:
        """The kind named ``name`` (``_`` and ``-`` alike: ``sam_onnx`` is ``sam-onnx``)."""
        try:
            return cls(str(name).strip().lower().replace("_", "-"))
        except ValueError:
            kinds = ", ".join(k.value for k in cls)
            raise DivasInputError(None, f"unknown segmenter {name!r} (one of {kinds})") from None

    @property
    def label(self) -> str:
        """The segmenter's name in a sentence."""
        return _LABELS[self]


#: The segmenter every host starts with when none is named (weight-free, scene-aware).
DEFAULT_SEGMENTER = SegmenterKind.GRAPH3D

_LABELS = {
    SegmenterKind.GRAPH3D: "3D graph",
    SegmenterKind.CLASSIC: "classic",
    SegmenterKind.SAM_ONNX: "SAM (ONNX)",
    SegmenterKind.SAM_TORCH: "SAM (PyTorch)",
    SegmenterKind.ORACLE: "oracle",
}


@dataclass(frozen=True)
class SegmenterSettings:
    """What :func:`build_segmenter` needs.

    Attributes:
        kind: which segmenter (a name is parsed: :meth:`SegmenterKind.parse`).
        seed: seed of the classic and oracle segmenters (their only randomness).
        sam_encoder, sam_decoder: ``SAM_ONNX`` image encoder / prompt decoder ``.onnx``.
        sam_checkpoint: ``SAM_TORCH`` checkpoint (``sam_vit_*.pth`` or MobileSAM's
            ``mobile_sam.pt``); hosts also convert it once to an ONNX pair for ``SAM_ONNX``.
        sam_model_type: the checkpoint's :class:`~.sam_models.SamModelType` (``vit_b`` /
            ``vit_l`` / ``vit_h`` / ``mobile_sam``; ``default`` is ``vit_h``, ``vit_t``
            is ``mobile_sam``).
        device: ``auto`` / ``cpu`` / ``cuda`` (``SAM_TORCH``'s torch device; ``auto``:
            CUDA when torch sees one, else CPU).
    """

    kind: SegmenterKind = DEFAULT_SEGMENTER
    seed: int = 0
    sam_encoder: Path | None = None
    sam_decoder: Path | None = None
    sam_checkpoint: Path | None = None
    sam_model_type: str = "vit_h"
    device: str = "auto"

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", SegmenterKind.parse(self.kind))


class SegmenterSetupError(DivasInputError):
    """A segmenter that cannot be built from its settings.

    Attributes:
        kind: the segmenter asked for.
        requires: what it needs, all of it (:class:`SegmenterSettings` field names, or
            ``"ground_truth"`` for the oracle's labels).
    """

    def __init__(self, kind: SegmenterKind, requires: tuple[str, ...], problem: str):
        super().__init__(None, problem)
        self.kind = kind
        self.requires = requires


def build_segmenter(settings: SegmenterSettings, *, has_ground_truth: bool = False) -> Segmenter:
    """The segmenter of ``settings``.

    Args:
        has_ground_truth: ground-truth labels go to the session (the oracle's target).

    Raises:
        SegmenterSetupError: a model file or the ground truth the kind needs is missing.
        DivasInputError: an optional package of the kind is not installed.
    """
    kind = settings.kind
    if kind is SegmenterKind.GRAPH3D:
        return Graph3DSegmenter()
    if kind is SegmenterKind.CLASSIC:
        return ClassicSegmenter(ClassicConfig(seed=settings.seed))
    if kind is SegmenterKind.ORACLE:
        if not has_ground_truth:
            raise SegmenterSetupError(
                kind, ("ground_truth",), f"the {kind.label} segmenter needs ground-truth labels"
            )
        return OracleSegmenter(config=OracleConfig(seed=settings.seed))
    if kind is SegmenterKind.SAM_ONNX:
        if settings.sam_encoder is None or settings.sam_decoder is None:
            raise SegmenterSetupError(
                kind,
                ("sam_encoder", "sam_decoder"),
                f"the {kind.label} segmenter needs the encoder and decoder .onnx files",
            )
        return SamOnnxSegmenter(settings.sam_encoder, settings.sam_decoder)
    if settings.sam_checkpoint is None:
        raise SegmenterSetupError(
            kind, ("sam_checkpoint",), f"the {kind.label} segmenter needs a checkpoint (.pth)"
        )
    try:
        return SamTorchSegmenter(
            settings.sam_checkpoint,
            settings.sam_model_type,
            device=None if settings.device == "auto" else settings.device,
        )
    except ImportError as e:
        raise DivasInputError(None, str(e)) from None

"""2D mask sources for DivAS (paper Sec. 3.4) behind one interface.

* :class:`SamOnnxSegmenter` — SAM / MobileSAM via onnxruntime (encoder + decoder files).
* :class:`SamTorchSegmenter` — SAM via the optional ``segment-anything`` + ``torch``.
* :class:`Graph3DSegmenter` — the weight-free default: a 3D cut over the scene's own
  primitives (:mod:`.graph3d`), rendered into each view; it is a
  :class:`SceneAwareSegmenter` the session binds to its scene (:mod:`.scene_aware`).
* :class:`ClassicSegmenter` — weight-free GrabCut on colour + depth (2D only).
* :class:`FloodFillSegmenter` — colour flood-fill baseline (comparison only).
* :class:`OracleSegmenter` — ground truth with SAM-like errors (evaluation only).

:func:`build_segmenter` (:mod:`.factory`) builds one of the first five from
:class:`SegmenterSettings`, for the CLI and the add-on alike.

Plus :func:`select_mask` (channel 1 or rejection), the depth weighting of
eq:nerf-depthweight / eq:gs-bandpass, and :class:`SamWorker` (async NeRF /
sync 2DGS scheduling).
"""

from .base import MaskSelection, Rejection, Segmenter, SegResult, select_mask
from .classic import ClassicConfig, ClassicSegmenter
from .context import ObjectClicks, SceneBinding, ViewContext
from .depth_weighting import (
    DepthBand,
    GsBandpassConfig,
    NerfDepthWeightConfig,
    apply_gs_bandpass,
    apply_nerf_depth_weight,
    depth_band,
    gs_bandpass_weight,
    nerf_depth_weight,
)
from .factory import (
    DEFAULT_SEGMENTER,
    SegmenterKind,
    SegmenterSettings,
    SegmenterSetupError,
    build_segmenter,
)
from .flood_fill import FloodFillConfig, FloodFillSegmenter
from .graph3d import Graph3DConfig, Graph3DSegmenter
from .oracle import OracleConfig, OracleSegmenter
from .sam_onnx import SamOnnxSegmenter
from .sam_torch import SamTorchSegmenter
from .scene_aware import SceneAwareSegmenter
from .worker import SamWorker, SegmentationJobError

__all__ = [
    "Rejection",
    "Segmenter",
    "SegResult",
    "MaskSelection",
    "select_mask",
    "Graph3DConfig",
    "Graph3DSegmenter",
    "SceneAwareSegmenter",
    "SceneBinding",
    "ViewContext",
    "ObjectClicks",
    "ClassicConfig",
    "ClassicSegmenter",
    "FloodFillConfig",
    "FloodFillSegmenter",
    "OracleConfig",
    "OracleSegmenter",
    "SamOnnxSegmenter",
    "SamTorchSegmenter",
    "NerfDepthWeightConfig",
    "GsBandpassConfig",
    "DepthBand",
    "nerf_depth_weight",
    "apply_nerf_depth_weight",
    "depth_band",
    "gs_bandpass_weight",
    "apply_gs_bandpass",
    "SamWorker",
    "SegmentationJobError",
    "DEFAULT_SEGMENTER",
    "SegmenterKind",
    "SegmenterSettings",
    "SegmenterSetupError",
    "build_segmenter",
]

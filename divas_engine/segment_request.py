"""What one headless segmentation does: :class:`SegmentRequest`.

One request is one run of ``divas segment`` (a scene, a prompts file, the outputs and
the settings). It is built three ways, all checked the same:

* from ``divas segment``'s arguments (:func:`add_request_arguments` declares them,
  :meth:`SegmentRequest.from_args` reads them back) — ``blender_scripts/segment.py``
  declares the same arguments through the same function;
* from a mapping (:meth:`SegmentRequest.from_mapping`: a ``divas batch`` manifest
  row's options, keyed by field name; relative paths against the manifest's folder);
* in Python, as a dataclass.

:meth:`SegmentRequest.to_dict` is its JSON form (paths as strings), recorded in a
batch job's report so that a rerun can tell whether the outputs on disk were made
by the same request.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import numpy as np

from .errors import DivasInputError

__all__ = [
    "SEGMENTERS",
    "DEVICES",
    "PRESETS",
    "SegmentRequest",
    "add_request_arguments",
    "parse_up",
    "request_path",
]

#: the ``--segmenter`` names (the values of ``segment.factory.SegmenterKind``).
SEGMENTERS = ("graph3d", "classic", "sam-onnx", "sam-torch", "oracle")
DEVICES = ("auto", "cpu", "cuda")
PRESETS = ("llff", "mip360")

_PATHS = (
    "scene",
    "prompts",
    "cameras",
    "out",
    "labels_out",
    "report",
    "session",
    "sam_encoder",
    "sam_decoder",
    "sam_checkpoint",
    "gt_labels",
)


@dataclass(frozen=True)
class SegmentRequest:
    """One headless segmentation: inputs, outputs and settings (``divas segment``'s flags).

    Attributes:
        scene: the scene file (or SOG folder, or ``lod-meta.json``).
        prompts: the prompts file (``docs/prompts-file.md``).
        cameras: training cameras (None: ``cameras.json`` beside the scene, if any).
        out, labels_out, report, session: the outputs (None: not written).
        resume: continue the run saved at ``session``.
        segmenter: one of :data:`SEGMENTERS`; ``sam_*`` its model files.
        gt_labels: ground truth (the oracle's target, a 3D score in the report).
        preset: NeRF fusion preset (None: from the training cameras).
        scale: render scale of every view; device: Warp device.
        seed: the segmenter's seed; mask_channel: the SAM channel kept (paper: 1).
        up: the scene's up for planned anchors (unit vector; None: estimated).
        completion: 3DGS scenes: complete the selection beyond the paper.
        widening: fuse wider views of an object a close-up cuts off (beyond the paper;
            ``WideningConfig``); False: one centroid view per click, as the paper.
        lod: level of a streamed-LOD scene (``lod-meta.json``; None: level 0, the finest;
            negative: counted from the coarsest).
        grid_views, network_views: instant-ngp snapshots: march the density grid (the
            network's colour baked in), or render views from the network; neither: the
            network on CUDA, the grid on a CPU (``RenderConfig.nerf_network``).
    """

    scene: Path
    prompts: Path
    cameras: Path | None = None
    out: Path | None = None
    labels_out: Path | None = None
    report: Path | None = None
    session: Path | None = None
    resume: bool = False
    segmenter: str = "graph3d"
    sam_encoder: Path | None = None
    sam_decoder: Path | None = None
    sam_checkpoint: Path | None = None
    sam_model_type: str = "vit_h"
    gt_labels: Path | None = None
    preset: str | None = None
    scale: float = 1.0
    device: str = "auto"
    seed: int = 0
    mask_channel: int = 1
    up: tuple[float, float, float] | None = None
    completion: bool = True
    widening: bool = True
    lod: int | None = None
    grid_views: bool = False
    network_views: bool = False

    def __post_init__(self) -> None:
        for name in _PATHS:
            v = getattr(self, name)
            if v is not None and not isinstance(v, Path):
                object.__setattr__(self, name, Path(v))
        if self.up is not None:
            object.__setattr__(self, "up", tuple(float(x) for x in self.up))
        object.__setattr__(self, "segmenter", str(self.segmenter).strip().lower().replace("_", "-"))

    def check(self) -> None:
        """Raise :class:`DivasInputError` for settings no run could use (before any work)."""
        if not (
            isinstance(self.scale, (int, float)) and self.scale > 0 and math.isfinite(self.scale)
        ):
            raise DivasInputError(None, f"--scale must be positive, got {self.scale}")
        if self.resume and self.session is None:
            raise DivasInputError(None, "--resume needs --session (the session to continue)")
        if self.mask_channel not in (0, 1, 2):
            raise DivasInputError(
                None, f"--mask-channel must be 0, 1 or 2, got {self.mask_channel}"
            )
        if self.segmenter not in SEGMENTERS:
            raise DivasInputError(
                None, f"unknown segmenter {self.segmenter!r} (one of {', '.join(SEGMENTERS)})"
            )
        if self.preset is not None and self.preset not in PRESETS:
            raise DivasInputError(None, f"--preset must be one of {', '.join(PRESETS)}")
        if self.grid_views and self.network_views:
            raise DivasInputError(None, "--grid-views and --network-views exclude each other")

    @property
    def nerf_network(self) -> bool | None:
        """``RenderConfig.nerf_network`` for this request (None: by device)."""
        if self.grid_views:
            return False
        return True if self.network_views else None

    def to_dict(self) -> dict[str, Any]:
        """JSON form: paths as strings, ``up`` as a list."""
        d = asdict(self)
        for k, v in d.items():
            if isinstance(v, Path):
                d[k] = str(v)
            elif isinstance(v, tuple):
                d[k] = list(v)
        return d

    @classmethod
    def from_args(cls, ns: argparse.Namespace) -> SegmentRequest:
        """The request of arguments declared by :func:`add_request_arguments` (flags it
        left out take their defaults)."""
        kw: dict[str, Any] = {}
        for f in fields(cls):
            if f.name in ("completion", "widening"):
                if hasattr(ns, f"no_{f.name}"):
                    kw[f.name] = not getattr(ns, f"no_{f.name}")
            elif f.name == "up":
                if getattr(ns, "up", None) is not None:
                    kw["up"] = tuple(parse_up(ns.up))
            elif hasattr(ns, f.name):
                kw[f.name] = getattr(ns, f.name)
        return cls(**kw)

    @classmethod
    def from_mapping(
        cls, values: dict[str, Any], *, base: Path | None = None, where: str | None = None
    ) -> SegmentRequest:
        """A request from field names and JSON values (a manifest row): paths relative to
        ``base`` (or ``file://`` URIs), every value's type checked; ``where`` names the
        row in errors."""
        known = {f.name: f for f in fields(cls)}
        kw: dict[str, Any] = {}
        for key, v in values.items():
            name = key.replace("-", "_")
            at = f"{where}.{key}" if where else key
            if name not in known:
                allowed = ", ".join(sorted(known))
                raise DivasInputError(None, f"{at}: unknown option (allowed: {allowed})")
            if v is None:
                continue
            kw[name] = _coerce(name, v, base, at)
        for need in ("scene", "prompts"):
            if need not in kw:
                raise DivasInputError(None, f"{where + ': ' if where else ''}missing '{need}'")
        req = cls(**kw)
        try:
            req.check()
        except DivasInputError as e:
            raise DivasInputError(None, f"{where}: {e.problem}" if where else e.problem) from None
        return req


def _coerce(name: str, v: Any, base: Path | None, at: str) -> Any:
    """A JSON value as the type of field ``name``."""
    if name in _PATHS:
        if not isinstance(v, str) or not v:
            raise DivasInputError(None, f"{at}: must be a path, got {v!r}")
        return request_path(v, base, at)
    if name in ("resume", "completion", "widening", "grid_views", "network_views"):
        if not isinstance(v, bool):
            raise DivasInputError(None, f"{at}: must be true or false, got {v!r}")
        return v
    if name in ("seed", "mask_channel", "lod"):
        if not (isinstance(v, int) and not isinstance(v, bool)):
            raise DivasInputError(None, f"{at}: must be an integer, got {v!r}")
        return v
    if name == "scale":
        if not (isinstance(v, (int, float)) and not isinstance(v, bool)):
            raise DivasInputError(None, f"{at}: must be a number, got {v!r}")
        return float(v)
    if name == "up":
        text = ",".join(str(x) for x in v) if isinstance(v, list) else v
        if not isinstance(text, str):
            raise DivasInputError(None, f"{at}: must be [x, y, z] or 'x,y,z', got {v!r}")
        try:
            return tuple(parse_up(text))
        except DivasInputError as e:
            raise DivasInputError(None, f"{at}: {e.problem}") from None
    if not isinstance(v, str):
        raise DivasInputError(None, f"{at}: must be a string, got {v!r}")
    return v


def request_path(text: str, base: Path | None, where: str) -> Path:
    """A path or ``file://`` URI as given in a manifest, relative to ``base``. Other
    schemes are refused: a job reads its files where its worker runs (mount object
    stores on the workers), and nothing is fetched from the network."""
    if "://" in text:
        u = urlparse(text)
        if u.scheme != "file" or u.netloc not in ("", "localhost"):
            raise DivasInputError(
                None,
                f"{where}: {text!r}: only paths and file:// URIs are read (mount remote "
                "storage where the workers run)",
            )
        return Path(unquote(u.path))
    p = Path(text).expanduser()
    return p if p.is_absolute() or base is None else base / p


def parse_up(text: str | None) -> np.ndarray | None:
    """``--up X,Y,Z`` as a unit vector (None: not given)."""
    if text is None:
        return None
    try:
        v = np.array([float(t) for t in text.split(",")], dtype=np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise DivasInputError(None, f"--up must be three numbers X,Y,Z, not all zero; got {text!r}")
    return v / np.linalg.norm(v)


def add_request_arguments(
    p: argparse.ArgumentParser, *, scene_option: bool = False, omit: frozenset[str] = frozenset()
) -> None:
    """Declare the request's arguments on ``p`` (``divas segment`` and the Blender script).

    ``scene_option``: the scene as ``--scene`` rather than a positional argument;
    ``omit``: field names a host does not offer (they keep their defaults).
    """

    def want(name: str) -> bool:
        return name not in omit

    scene_help = "scene: .ply (2DGS/3DGS/compressed), .splat, .spz, SOG, lod-meta.json or .npz grid"
    if scene_option:
        p.add_argument("--scene", type=Path, required=True, help=scene_help)
    else:
        p.add_argument("scene", type=Path, help=scene_help)
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="training cameras (default: cameras.json beside the scene, if any)",
    )
    p.add_argument("--prompts", type=Path, required=True, help="prompts file (JSON, version 1)")
    p.add_argument(
        "--out",
        type=Path,
        required=True,
        help="output: the selected primitives (PLY subset / same format), or the "
        "masked grid .npz for NeRF scenes",
    )
    p.add_argument(
        "--labels-out", type=Path, default=None, help="bool .npy per input row (NeRF: [D,H,W] bool)"
    )
    p.add_argument(
        "--segmenter",
        choices=SEGMENTERS,
        default="graph3d",
        help="mask source (default graph3d: weight-free 3D cut over the scene's primitives; "
        "classic: GrabCut on colour + depth; oracle is for evaluation only)",
    )
    p.add_argument("--sam-encoder", type=Path, default=None, help="SAM ONNX image encoder")
    p.add_argument("--sam-decoder", type=Path, default=None, help="SAM ONNX prompt decoder")
    p.add_argument("--sam-checkpoint", type=Path, default=None, help="SAM PyTorch checkpoint")
    p.add_argument("--sam-model-type", default="vit_h", help="SAM model type (default vit_h)")
    p.add_argument(
        "--gt-labels",
        type=Path,
        default=None,
        help="ground truth .npy (bool per surfel / input row; NeRF [D,H,W] bool): "
        "the oracle's target, and a 3D score in the report",
    )
    p.add_argument(
        "--preset",
        choices=PRESETS,
        default=None,
        help="NeRF fusion preset (default: llff for forward-facing captures)",
    )
    p.add_argument(
        "--scale", type=float, default=1.0, help="render scale of every view (default 1)"
    )
    p.add_argument("--device", choices=DEVICES, default="auto", help="Warp device (default auto)")
    p.add_argument("--report", type=Path, default=None, help="write a JSON report here")
    p.add_argument(
        "--session",
        type=Path,
        default=None,
        help="save the session here (JSON + a content-addressed .npz; autosaved after "
        "open, every click and every accept)",
    )
    if want("resume"):
        p.add_argument(
            "--resume",
            action="store_true",
            help="continue the run killed while saving to --session: replay what it saved, "
            "then run the remaining prompts (a missing session file starts afresh)",
        )
    p.add_argument(
        "--mask-channel",
        type=int,
        default=1,
        choices=(0, 1, 2),
        help="segmenter channel kept (default 1, the paper's mid granularity)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the segmenter (default 0)")
    if want("up"):
        p.add_argument(
            "--up",
            default=None,
            metavar="X,Y,Z",
            help="scene up for the planned (fibonacci) anchors (default: estimated)",
        )
    if want("completion"):
        p.add_argument(
            "--no-completion",
            action="store_true",
            help="3DGS scenes: the paper's selection only, without the completion of "
            "volumetric scenes (beyond the paper)",
        )
    if want("widening"):
        p.add_argument(
            "--no-widening",
            action="store_true",
            help="one centroid view per click, as the paper: no wider views of an object "
            "whose close-up cuts it off (beyond the paper)",
        )
    if want("grid_views"):
        p.add_argument(
            "--grid-views",
            action="store_true",
            help="instant-ngp snapshots: march the density grid (the network's colour baked "
            "in) instead of rendering views from the network (the default on a CPU)",
        )
    if want("network_views"):
        p.add_argument(
            "--network-views",
            action="store_true",
            help="instant-ngp snapshots: render views from the network even on a CPU (the "
            "default on CUDA; on a CPU each view takes seconds)",
        )
    if want("lod"):
        p.add_argument(
            "--lod",
            type=int,
            default=None,
            metavar="N",
            help="streamed LOD scenes (lod-meta.json): the level to load (default 0, the "
            "finest; -1 the coarsest)",
        )

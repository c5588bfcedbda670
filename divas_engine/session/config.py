"""Session configuration (paper Sec. 3.4 scheduling, Sec. 3.7 propagation) and the
JSON (de)serialisation of config dataclasses.

Every sub-config is a dataclass of the package that owns it (fusion, views, depth
weighting); :class:`SessionConfig` only adds the constants of the interaction loop.
The whole tree round-trips through plain JSON (:func:`config_to_dict` /
:func:`config_from_dict`), which is what a saved session stores.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..fusion.config import NERF_PRESETS, GridConfig, GsFusionConfig
from ..mapping.config import MappingConfig
from ..render.config import RenderConfig
from ..segment.depth_weighting import GsBandpassConfig, NerfDepthWeightConfig
from ..segment.worker import SYNC_PENDING
from ..views.config import ViewConfig

__all__ = [
    "CorrectionConfig",
    "WideningConfig",
    "SessionConfig",
    "config_to_dict",
    "config_from_dict",
]


@dataclass(frozen=True)
class CorrectionConfig:
    """Clicks as 3D constraints (beyond the paper; :mod:`.corrections`).

    Attributes:
        enabled: every click is a constraint on its object: a prompt of every view
            where its point is visible and the view's mask disagrees with it, and its
            surface patch forced in (positive) or out (negative) of the selection.
            False: the paper's loop (a positive click prompts its own centroid view; a
            negative one the later centroid views of its anchor).
        patch_px: the patch radius, in pixels of the clicked image at the click's depth.
        negative_sigmas, positive_sigmas: a primitive is in the patch when the point
            lies within this many standard deviations of it (its ellipsoid grown by the
            patch radius): generous for a negative click (everything that draws the
            spot goes), strict for a positive one (no large background splat comes in).
        positive_pixel_share, negative_pixel_share: a click's patch also takes,
            nearest the click's point first, the primitives that draw the clicked pixel,
            until a positive patch draws at least this share of the pixel's blending
            weight and a negative one leaves less than it (:func:`.corrections.pixel_patch`):
            at 0.5, the threshold of the selection's indicator, the clicked pixel shows
            selected (unselected) whatever else is. 0 (the default for both): the
            ellipsoid patch alone — the rule also takes what the click did not mean
            when the clicked surface draws less than the share (translucent haze in
            front of it, a large splat behind it: docs/corrections.md).
        negative_views: a negative anchor click that no view of its object sees fuses a
            view of its own, the click's centroid view (:mod:`.negative_views`).
            False: it prompts the views that see it and forces its patch out, no more.
    """

    enabled: bool = True
    patch_px: float = 2.0
    negative_sigmas: float = 2.0
    positive_sigmas: float = 1.0
    positive_pixel_share: float = 0.0
    negative_pixel_share: float = 0.0
    negative_views: bool = True

    def __post_init__(self) -> None:
        for name in ("patch_px", "negative_sigmas", "positive_sigmas"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"CorrectionConfig.{name} must be positive, got {v}")
        for name in ("positive_pixel_share", "negative_pixel_share"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise ValueError(f"CorrectionConfig.{name} must be in [0, 1], got {v}")


@dataclass(frozen=True)
class WideningConfig:
    """Wider views of an object the centroid view cuts off (beyond the paper;
    :mod:`.widening`).

    The paper frames a centroid view on the click's neighbourhood (alg:centroid-gs), so a
    click on a large object (a ribcage that fills the anchor) fuses one close-up of a
    patch of it. When a fused mask covers more than ``border_fraction`` of its view's
    image border — or, with a segmenter whose masks render a 3D selection (graph3d),
    when more than ``outside_fraction`` of that selection lies out of the view's image
    and no other view of the object shows it (a guitar's neck leaving a close-up of its
    headstock is thin on the border, yet most of the guitar is out of view) — the
    session fuses one more view of the same click: the same look-at point and
    direction, ``factor`` times as far, never past the anchor's own distance to the
    point; again while the new mask is cut off, at most ``max_views`` per click.

    Attributes:
        enabled: widen cut-off views (False: the paper's single centroid view).
        border_fraction: τ_b, the fraction of the border pixels a mask (≥ 0.5) may cover
            before the object counts as running out of the view.
        outside_fraction: τ_o, the opacity share of the segmenter's 3D selection that
            may lie out of the view's image, shown by no other view of the object, before
            the object counts as running out of the view
            (:func:`~.widening.unseen_outside`; ignored for an image segmenter).
        factor: distance ratio of each wider view to the one it widens (> 1).
        max_views: wider views one click may add.
    """

    enabled: bool = True
    border_fraction: float = 0.25
    outside_fraction: float = 0.25
    factor: float = 2.0
    max_views: int = 2

    def __post_init__(self) -> None:
        if not (0.0 <= self.border_fraction < 1.0):
            raise ValueError(
                f"WideningConfig.border_fraction must be in [0, 1), got {self.border_fraction}"
            )
        if not (0.0 <= self.outside_fraction < 1.0):
            raise ValueError(
                f"WideningConfig.outside_fraction must be in [0, 1), got {self.outside_fraction}"
            )
        if not (math.isfinite(self.factor) and self.factor > 1.0):
            raise ValueError(f"WideningConfig.factor must be > 1, got {self.factor}")
        if int(self.max_views) < 0:
            raise ValueError(f"WideningConfig.max_views must be ≥ 0, got {self.max_views}")


@dataclass(frozen=True)
class SessionConfig:
    """Constants of one interactive DivAS session.

    Attributes:
        render_scale: every view (anchors, centroid views, overlays) is rendered at
            this fraction of its camera's resolution; Session pixel coordinates are in
            the rendered images (the prompts file is in full-camera pixels and is
            converted by its reader).
        anchor_long_side: anchors render with this many pixels on their long side
            (their camera resized, then rendered at ``render_scale``); 0 (default):
            the camera's own size × ``render_scale``. Centroid views take their
            anchor's size. Not in the paper: a host lets its user choose how sharp the
            images to click on are.
        grid: 2DGS occupancy config; None → :class:`GridConfig` with ``g_max`` 512 for a
            forward-facing capture (NOTES "Occupancy"), 1024 otherwise.
        gs_fusion: 2DGS fusion constants.
        nerf_preset: ``"llff"`` / ``"mip360"``; None → llff when forward-facing.
        mapping: voxel-to-surfel mapping constants (2DGS).
        view: anchor / centroid-view constants.
        render: renderer constants.
        bandpass: eq:gs-bandpass constants (2DGS); nerf_weight: eq:nerf-depthweight (NeRF).
        min_score: a view is rejected below this channel-1 score (Sec. 3.4, 0.5).
        mask_channel: SAM channel kept (1, the mid granularity).
        min_mask_pixels: a depth-weighted mask with fewer pixels ≥ 0.5 is rejected as
            empty (an empty mask would fuse as pure negative evidence; not in the paper).
        sync_pending: NeRF asynchronous SAM: synchronise once this many masks are
            pending (Sec. 3.4 condition (ii), 3).
        nerf_async: NeRF uses the background SAM worker (Sec. 3.4); False runs it
            synchronously like 2DGS (debugging).
        nerf_zoom: λ of the NeRF centroid view (None: 0.67 forward-facing / 0.47 360°).
        all_views: offer every Fibonacci anchor (unsupported included).
        overwrite_labels: a later object may take surfels already labelled by an earlier one.
        negative_occlusion_tol: a click's point is projected into a view only where it
            is on the surface the view shows: its depth within ``tol · D_ref`` of the
            view's D_ref (neither hidden behind it nor floating before it).
        corrections: clicks as 3D constraints (:class:`CorrectionConfig`).
        widening: wider views of an object a centroid view cuts off
            (:class:`WideningConfig`).
        overlay_color, overlay_alpha: overlay of the selection on a view.
        overlay_threshold: coverage threshold of the binary overlay mask (NOTES
            "Evaluation": 0.1).
        autosave: path of the session JSON written after open, every click and every
            accept (None: off).
        seed: recorded in saved sessions and reports.
    """

    render_scale: float = 1.0
    anchor_long_side: int = 0
    grid: GridConfig | None = None
    gs_fusion: GsFusionConfig = field(default_factory=GsFusionConfig)
    nerf_preset: str | None = None
    mapping: MappingConfig = field(default_factory=MappingConfig)
    view: ViewConfig = field(default_factory=ViewConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    bandpass: GsBandpassConfig = field(default_factory=GsBandpassConfig)
    nerf_weight: NerfDepthWeightConfig = field(default_factory=NerfDepthWeightConfig)
    min_score: float = 0.5
    mask_channel: int = 1
    min_mask_pixels: int = 1
    sync_pending: int = SYNC_PENDING
    nerf_async: bool = True
    nerf_zoom: float | None = None
    all_views: bool = False
    overwrite_labels: bool = False
    negative_occlusion_tol: float = 0.05
    corrections: CorrectionConfig = field(default_factory=CorrectionConfig)
    widening: WideningConfig = field(default_factory=WideningConfig)
    overlay_color: tuple[float, float, float] = (1.0, 0.25, 0.1)
    overlay_alpha: float = 0.6
    overlay_threshold: float = 0.1
    autosave: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.render_scale) and self.render_scale > 0):
            raise ValueError(
                f"SessionConfig.render_scale must be positive, got {self.render_scale}"
            )
        if self.nerf_preset is not None and self.nerf_preset not in NERF_PRESETS:
            raise ValueError(
                f"SessionConfig.nerf_preset must be one of {sorted(NERF_PRESETS)} "
                f"or None, got {self.nerf_preset!r}"
            )
        if int(self.anchor_long_side) < 0:
            raise ValueError("SessionConfig.anchor_long_side must be ≥ 0")
        if self.sync_pending < 1:
            raise ValueError("SessionConfig.sync_pending must be ≥ 1")
        if self.autosave is not None:
            object.__setattr__(self, "autosave", str(Path(self.autosave)))

    def to_dict(self) -> dict[str, Any]:
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SessionConfig:
        return config_from_dict(cls, d)


def config_to_dict(obj: Any) -> Any:
    """JSON-ready tree of a (nested) config dataclass (tuples become lists)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: config_to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [config_to_dict(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): config_to_dict(v) for k, v in obj.items()}
    if isinstance(obj, float) and not math.isfinite(obj):
        return {"float": repr(obj)}  # inf / nan survive JSON
    return obj


def _decode(tp: Any, value: Any, where: str) -> Any:
    if isinstance(value, dict) and set(value) == {"float"}:
        return float(value["float"])
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        if value is None:
            return None
        for a in args:
            if a is type(None):
                continue
            if dataclasses.is_dataclass(a) and isinstance(value, dict):
                return config_from_dict(a, value, where)
        return _decode(next(a for a in args if a is not type(None)), value, where)
    if dataclasses.is_dataclass(tp) and isinstance(value, dict):
        return config_from_dict(tp, value, where)
    if origin is tuple or tp is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{where}: expected a list, got {type(value).__name__}")
        return tuple(_decode(args[0] if args else Any, v, where) for v in value)
    return value


def config_from_dict(cls: type, d: dict[str, Any], where: str | None = None) -> Any:
    """Inverse of :func:`config_to_dict` for dataclass ``cls``; unknown keys are an error."""
    where = where or cls.__name__
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object, got {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(unknown)}")
    kw = {k: _decode(hints[k], v, f"{where}.{k}") for k, v in d.items()}
    return cls(**kw)

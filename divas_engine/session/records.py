"""The records of an interactive session: anchors, clicks, corrections, centroid views,
previews, overlays, accept and correction results and objects — plain data (the loop
is :mod:`.session`).

An anchor or a view holds its render once the session has rendered it
(:meth:`~divas_engine.session.Session.render`); reading a record never renders.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..camera import Camera
from ..kinds import ClickOrigin, ViewStatus
from ..render.buffers import RenderBuffers
from ..segment.base import MaskSelection, Rejection
from ..segment.depth_weighting import DepthBand
from ..views.centroid_common import CentroidView

__all__ = [
    "AnchorView",
    "AnchorClick",
    "ClickSource",
    "Correction",
    "CorrectionResult",
    "MaskPreview",
    "SessionView",
    "Overlay",
    "AcceptResult",
    "ObjectRecord",
]


class _Rendered:
    """``rendered`` and ``rgb`` of a record with a ``buffers`` field."""

    buffers: RenderBuffers | None

    @property
    def rendered(self) -> bool:
        """Whether the session has rendered it (``buffers`` is set)."""
        return self.buffers is not None

    @property
    def rgb(self) -> np.ndarray:
        """The render's RGB (the session renders it: ``Session.render``)."""
        if self.buffers is None:
            raise RuntimeError(f"{self!r} is not rendered yet: Session.render() it first")
        return self.buffers.rgb


@dataclass(eq=False, repr=False)
class AnchorView(_Rendered):
    """An anchor offered to the user.

    Attributes:
        index: position in :attr:`Session.anchors`.
        camera: the rendered (working-resolution) camera; full_camera: as given.
        source: ``"fibonacci"``, ``"training"`` or ``"camera"``; source_index: its index.
        buffers: its render, once rendered.
    """

    index: int
    camera: Camera
    full_camera: Camera
    source: str
    source_index: int
    buffers: RenderBuffers | None = None

    def __repr__(self) -> str:
        return f"anchor {self.index}"


@dataclass(eq=False)
class AnchorClick:
    """One click on an anchor (numbered per anchor and object, in click order)."""

    anchor: int
    index: int
    xy: tuple[float, float]
    positive: bool
    point: np.ndarray | None = None  # back-projected 3D point
    view_id: str | None = None  # the view it spawned (positive; negative: .negative_views)

    def to_dict(self) -> dict[str, Any]:
        return {
            "anchor": self.anchor,
            "index": self.index,
            "xy": list(self.xy),
            "positive": self.positive,
            "point": None if self.point is None else self.point.tolist(),
            "view": self.view_id,
        }


@dataclass(frozen=True, eq=False)
class ClickSource:
    """Where a click was made: ``origin`` (:class:`~divas_engine.kinds.ClickOrigin`) and
    ``xy`` (pixels of that image) with, by origin, the ``anchor`` and its ``click``
    number, the ``view`` id, or the ``camera`` (working resolution); ``POINT``: none."""

    origin: ClickOrigin
    xy: tuple[float, float] | None = None
    anchor: int | None = None
    click: int | None = None
    view: str | None = None
    camera: Camera | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "origin": str(self.origin),
            "xy": None if self.xy is None else [float(self.xy[0]), float(self.xy[1])],
            "anchor": self.anchor,
            "click": self.click,
            "view": self.view,
            "camera": None if self.camera is None else self.camera.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ClickSource:
        xy = d.get("xy")
        cam = d.get("camera")
        return cls(
            ClickOrigin(d["origin"]),
            None if xy is None else (float(xy[0]), float(xy[1])),
            None if d.get("anchor") is None else int(d["anchor"]),
            None if d.get("click") is None else int(d["click"]),
            d.get("view"),
            None if cam is None else Camera.from_dict(cam),
        )


@dataclass(frozen=True, eq=False)
class Correction:
    """A click as a 3D constraint on its object (beyond the paper;
    :mod:`~divas_engine.session.corrections`).

    Attributes:
        index: its number in the object (click order).
        positive: the click's sign.
        point: ``[3]`` the back-projected point (world units).
        radius: the patch radius (world units: ``patch_px`` pixels at the click's depth).
        patch: sorted flat indices (into a selection) of the primitives or voxels under
            the click — forced in (positive) or out (negative) of the selection.
        source: the :class:`ClickSource`.
        views: the views it prompted when it was made (segmented again).
        spawned: the centroid view a positive anchor click spawned (Sec. 3.3): that
            click stands for its view, so its patch holds once the view is accepted —
            fused, or refused at accept (its mask could not be fused; the click stands).
    """

    index: int
    positive: bool
    point: np.ndarray
    radius: float
    patch: np.ndarray
    source: ClickSource
    views: tuple[str, ...] = ()
    spawned: str | None = None

    def to_dict(self, patch_key: str) -> dict[str, Any]:
        return {
            "index": self.index,
            "positive": self.positive,
            "point": [float(v) for v in self.point],
            "radius": float(self.radius),
            "patch": patch_key,
            "source": self.source.to_dict(),
            "views": list(self.views),
            "spawned": self.spawned,
        }


@dataclass(eq=False)
class MaskPreview:
    """SAM output for one prompt set on a view, after channel selection and depth weighting.

    Attributes:
        masks, scores: the segmenter's ``[3,H,W]`` probabilities and ``[3]`` scores.
        selection: :func:`~divas_engine.segment.select_mask` outcome.
        mask: the depth-weighted mask M̃ (None when rejected by ``select_mask``).
        band: the 2DGS depth band (eq:depthband), None for NeRF.
        rejection: why the view would be rejected (:class:`Rejection`), None when it
            would be fused; ``reason`` is its sentence.
        advice: the segmenter's plain-language hint when it was unsure (what to click
            next: a click on what is missing, a negative click on what spilled over),
            None when it is confident or gives no hints (SAM, the oracle).
        asked: the prompt set :meth:`Session.prompt` was asked for, when ``points``
            also hold the object's clicks its first mask disagreed with (None: the same).
    """

    view_id: str
    points: np.ndarray
    labels: np.ndarray
    masks: np.ndarray
    scores: np.ndarray
    selection: MaskSelection
    mask: np.ndarray | None
    band: DepthBand | None
    rejection: Rejection | None
    seconds: float = 0.0
    advice: str | None = None
    asked: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def accepted(self) -> bool:
        return self.rejection is None

    @property
    def reason(self) -> str | None:
        return None if self.rejection is None else self.rejection.message

    @property
    def score(self) -> float:
        return self.selection.score


@dataclass(eq=False, repr=False)
class SessionView(_Rendered):
    """A centroid view of the session.

    Attributes:
        id: ``"o<object>:a<anchor>:c<click>"``.
        centroid: the :class:`~divas_engine.views.CentroidView` (camera, d_cam, target,
            anchor box …).
        status: a :class:`~divas_engine.kinds.ViewStatus` — ``"open"`` (spawned),
            ``"pending"`` (NeRF: accepted, SAM running), ``"fused"`` or ``"rejected"``.
        reason: why it was rejected (the engine's sentence); rejection: the same as data
            (:class:`Rejection`; None in sessions saved before it was kept); advice: the
            segmenter's hint of its last preview, rejection or fused mask (what to click
            next), None when it was sure.
        points, labels: the prompt set of the last preview / accept.
        mask: the depth-weighted mask that was fused.
        raw_mask: the segmenter's own mask of that accept, restored from a saved
            session (a live view reads it from ``preview``); the 3DGS completion's
            evidence, so a replay completes exactly as the live session did.
        fusion_id: the fusion slot (2DGS: view-bitmask bit).
        buffers: its render, once rendered.
    """

    id: str
    object_index: int
    anchor: int
    click: int
    centroid: CentroidView
    status: ViewStatus = ViewStatus.OPEN
    reason: str | None = None
    rejection: Rejection | None = None
    advice: str | None = None
    score: float = float("nan")
    points: np.ndarray | None = None
    labels: np.ndarray | None = None
    preview: MaskPreview | None = None
    mask: np.ndarray | None = None
    raw_mask: np.ndarray | None = None
    fusion_id: int | None = None
    fusion_view: Any = None
    timings: dict = field(default_factory=dict)
    buffers: RenderBuffers | None = None

    def __repr__(self) -> str:
        return f"view {self.id}"

    @property
    def camera(self) -> Camera:
        return self.centroid.camera

    @property
    def box(self) -> tuple[float, float, float, float] | None:
        """Strategy-1 box on the anchor view (2DGS), None otherwise."""
        return self.centroid.box

    def to_dict(self, mask_key: str | None) -> dict[str, Any]:
        c = self.centroid
        return {
            "id": self.id,
            "anchor": self.anchor,
            "click": self.click,
            "status": self.status,
            "reason": self.reason,
            "rejection": None if self.rejection is None else self.rejection.to_dict(),
            "advice": self.advice,
            "score": None if not np.isfinite(self.score) else float(self.score),
            "camera": c.camera.to_dict(),
            "d_cam": c.d_cam,
            "target": c.target.tolist(),
            "xy": list(c.click),
            "depth": c.depth,
            "box": None if c.box is None else list(c.box),
            "strategy": c.strategy,
            "r_init": c.r_init,
            "neighbours": c.neighbours,
            "points": None if self.points is None else self.points.tolist(),
            "labels": None if self.labels is None else self.labels.tolist(),
            "mask": mask_key,
            "fusion_id": self.fusion_id,
        }


@dataclass(eq=False)
class Overlay:
    """The selection rendered over one view.

    Attributes:
        coverage: ``[H,W]`` composited selection indicator (render_values).
        mask: ``coverage ≥ overlay_threshold``.
        image: ``[H,W,3]`` float32 RGB with the selection recoloured.
    """

    camera: Camera
    coverage: np.ndarray
    mask: np.ndarray
    image: np.ndarray
    view_id: str | None = None


@dataclass(eq=False)
class AcceptResult:
    """What one :meth:`Session.accept` (or :meth:`Session.sync`) did.

    Attributes:
        view: the accepted view (None for a bare sync).
        status: the view's status afterwards.
        reason: rejection reason of that view.
        fused, rejected: view ids fused / rejected by this call (NeRF: the whole group).
        pending: masks still pending (NeRF).
        synced: a fusion (and propagation) happened in this call.
        selection: the current selection (per-surfel bool, NeRF ``[D,H,W]`` bool).
        overlay, next_view, next_overlay: propagation feedback (Sec. 3.7); the two
            overlays are rendered when first read (``overlay_source`` /
            ``next_overlay_source`` hold the :class:`Overlay` or the callable that
            renders it), so an accept itself renders nothing.
        timings: seconds of this update by stage.
    """

    view: SessionView | None
    status: ViewStatus | None
    reason: str | None
    fused: list[str]
    rejected: list[tuple[str, str]]
    pending: int
    synced: bool
    selection: np.ndarray
    overlay_source: Overlay | Callable[[], Overlay] | None = None
    next_view: SessionView | None = None
    next_overlay_source: Overlay | Callable[[], Overlay] | None = None
    timings: dict = field(default_factory=dict)

    @property
    def overlay(self) -> Overlay | None:
        if callable(self.overlay_source):
            self.overlay_source = self.overlay_source()
        return self.overlay_source

    @property
    def next_overlay(self) -> Overlay | None:
        if callable(self.next_overlay_source):
            self.next_overlay_source = self.next_overlay_source()
        return self.next_overlay_source


@dataclass(eq=False)
class CorrectionResult:
    """What one click did as a correction (:mod:`~divas_engine.session.corrections`).

    Attributes:
        correction: the :class:`Correction` made.
        resegmented: the views segmented again with the click as a prompt (fused,
            pending or previewed views where its point is visible and their mask
            disagrees with it).
        refused: those of them fused again in their slots; rejected: ``(id, reason)``
            of fused views whose corrected mask was rejected (they left the fusion).
        added, removed: flat indices of the primitives or voxels the click selected /
            deselected (the selection delta).
        selection: the selection afterwards.
        view: the centroid view a positive anchor click spawned, else None.
        timings: seconds by stage (``segmenter_s``, ``kernel_s``, ``mapping_s``,
            ``update_s`` the whole correction).
    """

    correction: Correction
    resegmented: list[str]
    refused: list[str]
    rejected: list[tuple[str, str]]
    added: np.ndarray
    removed: np.ndarray
    selection: np.ndarray
    view: SessionView | None = None
    timings: dict = field(default_factory=dict)

    @property
    def views_changed(self) -> int:
        """How many views the click changed (segmented again)."""
        return len(self.resegmented)


@dataclass(eq=False)
class ObjectRecord:
    """One object of a multi-object session; ``corrections``: its clicks as 3D
    constraints, in click order."""

    index: int
    label: int
    name: str
    views: list[SessionView] = field(default_factory=list)
    clicks: dict[int, list[AnchorClick]] = field(default_factory=dict)
    corrections: list[Correction] = field(default_factory=list)
    accept_order: list[str] = field(default_factory=list)
    finished: bool = False
    selection: np.ndarray | None = None

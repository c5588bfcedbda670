"""The interactive DivAS session: the engine API of the loop of paper Sec. 3 (no ``bpy``).

Loop (Sec. 3.1 "Overview"): anchors → a click on an anchor spawns a centroid view
(Sec. 3.3) → point prompts give a SAM mask, depth weighted (Sec. 3.4) → accepting
the view fuses it (Sec. 3.5) and, for 2DGS, maps the voxels to surfels (Sec. 3.6) →
the selection is overlaid on the current and the next pending view (Sec. 3.7).

Scheduling (Sec. 3.4 "Execution scheduling", Sec. 3.7):

* 2DGS — synchronous: :meth:`Session.accept` runs SAM (or reuses the preview of the
  same prompts), fuses, maps and returns the overlays at once.
* NeRF — asynchronous: :meth:`Session.accept` hands the view to a background
  :class:`~divas_engine.segment.SamWorker` and returns; the pending masks are
  collected and fused together when the view ends its anchor group (no other open
  centroid view of the same anchor in the current object) or ``sync_pending`` (3)
  masks are pending. Propagation feedback (selection, overlays) happens at that sync.
  :meth:`Session.sync` forces it (``finish_object``, ``export`` and ``save`` of the
  final state call it).

Coordinates: every pixel coordinate of this API is in the images the session renders
(the cameras scaled by ``SessionConfig.render_scale``).

Undo is exact (fixed-point fusion ``remove_view``; the mapping is recomputed from the
same live views and slots). A session is serialised as JSON + npz (the accepted,
depth-weighted masks), autosaved after every accept when ``config.autosave`` is set,
and :meth:`Session.load` replays it — re-rendering the stored camera poses and fusing
the stored masks — to identical labels, without running SAM again.

Multiple objects: :meth:`Session.finish_object` commits the selection as the next
integer label (0 = unlabelled; earlier labels are kept unless
``overwrite_labels``) and starts an empty object.

Decisions not in the paper:

* an accepted view whose depth-weighted mask holds fewer than ``min_mask_pixels``
  pixels ≥ 0.5 is rejected ("empty mask"), like a low SAM score;
* a negative click on an anchor is back-projected (like a positive one) and becomes
  a negative prompt of every centroid view of that anchor where its 3D point is
  visible (in the image, in front, not hidden by more than ``negative_occlusion_tol``);
* the default prompt of a centroid view is the click's 3D point projected into it
  (NOTES "Headless prompts file"); extra points are added to it.
"""

from __future__ import annotations

import contextlib
import hashlib
import threading
import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..render import make_renderer
from ..render.buffers import RenderBuffers
from ..scene import DensityGrid, Scene, SurfelScene
from ..segment.base import MaskSelection, Segmenter, SegResult, select_mask
from ..segment.depth_weighting import DepthBand, apply_gs_bandpass, apply_nerf_depth_weight
from ..segment.worker import SamWorker, SegmentationJobError
from ..views import Anchor, AnchorPlan, plan_scene_anchors
from ..views.centroid_common import CentroidView, click_point
from .config import SessionConfig
from .store import SESSION_FORMAT, SESSION_VERSION, load_state, save_state
from .timing import Timings, memory_report

__all__ = [
    "Session",
    "SessionView",
    "AnchorView",
    "AnchorClick",
    "MaskPreview",
    "AcceptResult",
    "Overlay",
    "ObjectRecord",
    "anchor_plan",
    "scene_kind",
]


def scene_kind(scene: Scene) -> str:
    if isinstance(scene, SurfelScene):
        return "2dgs"
    if isinstance(scene, DensityGrid):
        return "nerf"
    raise TypeError(f"unsupported scene type {type(scene).__name__}")


def anchor_plan(
    scene: Scene, cameras: Sequence[Camera] | None, config: SessionConfig | None = None
) -> AnchorPlan:
    """The anchor plan of a scene (Sec. 3.2): what :meth:`Session.open` offers by default."""
    cfg = config or SessionConfig()
    return plan_scene_anchors(
        scene, list(cameras or []), kind=scene_kind(scene), config=cfg.view, all_views=cfg.all_views
    )


def _scene_fingerprint(scene: Scene) -> str:
    h = hashlib.blake2b(digest_size=16)
    arr = scene.means if isinstance(scene, SurfelScene) else scene.density
    a = np.ascontiguousarray(arr)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a).cast("B"))
    return h.hexdigest()


# ----------------------------------------------------------------------------- records
class _RenderedOnDemand:
    """``buffers``/``rgb`` of a view's ``camera``, rendered by its session on first use
    (the dataclass provides ``camera``, ``_buffers`` and ``_session``)."""

    @property
    def buffers(self) -> RenderBuffers:
        if self._buffers is None:
            assert self._session is not None
            self._buffers = self._session._render(self.camera)
        return self._buffers

    @property
    def rgb(self) -> np.ndarray:
        return self.buffers.rgb


@dataclass(eq=False)
class AnchorView(_RenderedOnDemand):
    """An anchor offered to the user.

    Attributes:
        index: position in :attr:`Session.anchors`.
        camera: the rendered (working-resolution) camera; full_camera: as given.
        source: ``"fibonacci"``, ``"training"`` or ``"camera"``; source_index: its index.
    """

    index: int
    camera: Camera
    full_camera: Camera
    source: str
    source_index: int
    _buffers: RenderBuffers | None = None
    _session: Session | None = None


@dataclass(eq=False)
class AnchorClick:
    """One click on an anchor (numbered per anchor and object, in click order)."""

    anchor: int
    index: int
    xy: tuple[float, float]
    positive: bool
    point: np.ndarray | None = None  # back-projected 3D point
    view_id: str | None = None  # centroid view it spawned (positive clicks)

    def to_dict(self) -> dict[str, Any]:
        return {
            "anchor": self.anchor,
            "index": self.index,
            "xy": list(self.xy),
            "positive": self.positive,
            "point": None if self.point is None else self.point.tolist(),
            "view": self.view_id,
        }


@dataclass(eq=False)
class MaskPreview:
    """SAM output for one prompt set on a view, after channel selection and depth weighting.

    Attributes:
        masks, scores: the segmenter's ``[3,H,W]`` probabilities and ``[3]`` scores.
        selection: :func:`~divas_engine.segment.select_mask` outcome.
        mask: the depth-weighted mask M̃ (None when rejected by ``select_mask``).
        band: the 2DGS depth band (eq:depthband), None for NeRF.
        reason: why the view would be rejected, None when it would be fused.
    """

    view_id: str
    points: np.ndarray
    labels: np.ndarray
    masks: np.ndarray
    scores: np.ndarray
    selection: MaskSelection
    mask: np.ndarray | None
    band: DepthBand | None
    reason: str | None
    seconds: float = 0.0

    @property
    def accepted(self) -> bool:
        return self.reason is None

    @property
    def score(self) -> float:
        return self.selection.score


@dataclass(eq=False)
class SessionView(_RenderedOnDemand):
    """A centroid view of the session.

    Attributes:
        id: ``"o<object>:a<anchor>:c<click>"``.
        centroid: the :class:`~divas_engine.views.CentroidView` (camera, d_cam, target,
            anchor box …).
        status: ``"open"`` (spawned), ``"pending"`` (NeRF: accepted, SAM running),
            ``"fused"`` or ``"rejected"``.
        points, labels: the prompt set of the last preview / accept.
        mask: the depth-weighted mask that was fused.
        fusion_id: the fusion slot (2DGS: view-bitmask bit).
    """

    id: str
    object_index: int
    anchor: int
    click: int
    centroid: CentroidView
    status: str = "open"
    reason: str | None = None
    score: float = float("nan")
    points: np.ndarray | None = None
    labels: np.ndarray | None = None
    preview: MaskPreview | None = None
    mask: np.ndarray | None = None
    fusion_id: int | None = None
    fusion_view: Any = None
    timings: dict = field(default_factory=dict)
    _buffers: RenderBuffers | None = None
    _session: Session | None = None

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
        overlay, next_view, next_overlay: propagation feedback (Sec. 3.7).
        timings: seconds of this update by stage.
    """

    view: SessionView | None
    status: str | None
    reason: str | None
    fused: list[str]
    rejected: list[tuple[str, str]]
    pending: int
    synced: bool
    selection: np.ndarray
    overlay: Overlay | None = None
    next_view: SessionView | None = None
    next_overlay: Overlay | None = None
    timings: dict = field(default_factory=dict)


@dataclass(eq=False)
class ObjectRecord:
    """One object of a multi-object session."""

    index: int
    label: int
    name: str
    views: list[SessionView] = field(default_factory=list)
    clicks: dict[int, list[AnchorClick]] = field(default_factory=dict)
    accept_order: list[str] = field(default_factory=list)
    finished: bool = False
    selection: np.ndarray | None = None


class _TimedSegmenter:
    """What the worker and the previews call: ``segment`` under the session's timer."""

    def __init__(self, seg: Segmenter, timings: Timings):
        self.seg, self.timings = seg, timings

    def segment(self, rgb, depth, points, labels, *, view_id: Hashable | None = None) -> SegResult:
        with self.timings.measure("segmenter"):
            return self.seg.segment(rgb, depth, points, labels, view_id=view_id)


def _as_prompt_arrays(points, labels) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2) if np.size(points) else np.zeros((0, 2))
    lab = (
        np.asarray(labels, dtype=np.int64).reshape(-1) if np.size(labels) else np.zeros(0, np.int64)
    )
    if len(p) != len(lab):
        raise DivasInputError(None, f"{len(p)} prompt points but {len(lab)} labels")
    if np.any((lab != 0) & (lab != 1)):
        raise DivasInputError(None, "prompt labels must be 1 (positive) or 0 (negative)")
    if not np.all(np.isfinite(p)):
        raise DivasInputError(None, "prompt points contain NaN/Inf")
    return p, lab


# ----------------------------------------------------------------------------- session
class Session:
    """One interactive segmentation session over a scene (module docstring).

    Create with :meth:`open` (fresh) or :meth:`load` (saved session, replayed).
    """

    def __init__(
        self,
        scene: Scene,
        cameras: Sequence[Camera] | None,
        config: SessionConfig,
        segmenter: Segmenter | None,
        device,
        anchors: list[tuple[Camera, str, int]],
        forward_facing: bool,
        *,
        gt_values: np.ndarray | None = None,
        renderer=None,
    ) -> None:
        from divas_kernels import resolve_device

        self.scene = scene
        self.kind = scene_kind(scene)
        self.cameras = list(cameras or [])
        self.config = config
        self.device = resolve_device(device)
        self.forward_facing = bool(forward_facing)
        self.timings = Timings()
        self.updates: list[dict[str, Any]] = []
        self.segmenter = segmenter
        self._render_lock = threading.RLock()
        self.renderer = (
            renderer
            if renderer is not None
            else make_renderer(scene, device=self.device, config=config.render)
        )
        self._seg = None if segmenter is None else _TimedSegmenter(segmenter, self.timings)
        self._gt_values = None
        if gt_values is not None:
            self.set_ground_truth(gt_values)
        s = config.render_scale
        self.anchors: list[AnchorView] = [
            AnchorView(i, cam if s == 1.0 else cam.scaled(s), cam, src, idx, None, self)
            for i, (cam, src, idx) in enumerate(anchors)
        ]
        # representation adapters
        self._planner = None
        self._mapper = None
        if self.kind == "2dgs":
            from ..fusion import GridConfig, GsFusion, build_occupancy

            gcfg = config.grid or (
                GridConfig.forward_facing() if self.forward_facing else GridConfig()
            )
            self.grid_config = gcfg
            self.grid = build_occupancy(scene, gcfg, self.device)
            self.fusion = GsFusion(self.grid, config.gs_fusion, self.device)
            self.nerf_config = None
        else:
            from ..fusion import NerfFusion, build_nerf_occupancy, nerf_preset

            self.preset = config.nerf_preset or ("llff" if self.forward_facing else "mip360")
            self.nerf_config = nerf_preset(self.preset)
            self.grid = build_nerf_occupancy(scene, self.nerf_config, self.device)
            self.fusion = NerfFusion(self.grid, self.nerf_config, self.device)
            self.grid_config = None
        self._worker: SamWorker | None = None
        self._pending: list[SessionView] = []
        self._views: dict[str, SessionView] = {}
        self.objects: list[ObjectRecord] = [ObjectRecord(0, 1, "object_1")]
        shape = (len(scene),) if self.kind == "2dgs" else scene.density.shape
        self.labels = np.zeros(shape, np.int32)
        self._selection = np.zeros(shape, bool)
        self.replay_matches: bool | None = None
        self.plan: AnchorPlan | None = None
        self.last_mapping = None
        self._closed = False

    # ------------------------------------------------------------------ construction
    @classmethod
    def open(
        cls,
        scene: Scene,
        cameras: Sequence[Camera] | None = None,
        config: SessionConfig | None = None,
        segmenter: Segmenter | None = None,
        device=None,
        *,
        anchors: Sequence[Any] | None = None,
        gt_values: np.ndarray | None = None,
        render_anchors: bool = True,
        renderer=None,
    ) -> Session:
        """Start a session.

        Args:
            scene: a :class:`SurfelScene` (2DGS/3DGS) or :class:`DensityGrid` (NeRF).
            cameras: training cameras (anchor planning, capture type); may be empty.
            segmenter: the 2D mask source (default: :class:`ClassicSegmenter`).
            device: Warp device (None/"auto": CUDA when present).
            anchors: the anchors to offer instead of the planned ones — each an
                :class:`~divas_engine.views.Anchor`, a :class:`Camera`, or a
                ``(camera, source, index)`` tuple (full-resolution cameras).
            gt_values: evaluation only — ground-truth per surfel ``[N]`` (NeRF ``[D,H,W]``);
                wired into an :class:`OracleSegmenter` that has no ``gt_render``.
            render_anchors: render every anchor now (else on first use).
        """
        cfg = config or SessionConfig()
        if segmenter is None:
            from ..segment import ClassicSegmenter

            segmenter = ClassicSegmenter()
        plan = anchor_plan(scene, cameras, cfg)
        if anchors is None:
            items = [(a.camera, a.source, a.index) for a in plan.anchors]
        else:
            items = [cls._anchor_item(a) for a in anchors]
        s = cls(
            scene,
            cameras,
            cfg,
            segmenter,
            device,
            items,
            plan.forward_facing,
            gt_values=gt_values,
            renderer=renderer,
        )
        s.plan = plan
        if render_anchors:
            for a in s.anchors:
                _ = a.buffers
        return s

    @staticmethod
    def _anchor_item(a: Any) -> tuple[Camera, str, int]:
        if isinstance(a, Anchor):
            return a.camera, a.source, int(a.index)
        if isinstance(a, Camera):
            return a, "camera", -1
        if hasattr(a, "camera") and hasattr(a, "source"):
            return a.camera, str(a.source), int(getattr(a, "index", -1))
        cam, src, idx = a
        return cam, str(src), int(idx)

    def set_ground_truth(self, values: np.ndarray) -> None:
        """Evaluation only: ground truth rendered as the oracle's target at each view."""
        v = np.asarray(values, dtype=np.float32)
        shape = (len(self.scene),) if self.kind == "2dgs" else self.scene.density.shape
        if v.shape != shape:
            raise DivasInputError(
                None, f"ground-truth labels have shape {v.shape}, the scene needs {shape}"
            )
        self._gt_values = v
        from ..segment.oracle import OracleSegmenter

        if isinstance(self.segmenter, OracleSegmenter) and self.segmenter.gt_render is None:
            self.segmenter.gt_render = self._gt_render

    def _gt_render(self, view_id: Hashable) -> np.ndarray:
        cam = self._views[str(view_id)].camera
        return self._render_values(cam, self._gt_values)

    # ------------------------------------------------------------------ rendering
    def _render(self, camera: Camera) -> RenderBuffers:
        with self._render_lock, self.timings.measure("render"):
            return self.renderer.render(camera)

    def _render_values(self, camera: Camera, values: np.ndarray) -> np.ndarray:
        with self._render_lock:
            return self.renderer.render_values(camera, values)

    def working_camera(self, camera: Camera) -> Camera:
        """``camera`` at the session's render scale."""
        s = self.config.render_scale
        return camera if s == 1.0 else camera.scaled(s)

    def indicator(self, selection: np.ndarray | None = None) -> np.ndarray:
        """Float per-primitive indicator of a selection (current by default)."""
        sel = self._selection if selection is None else selection
        return np.asarray(sel, dtype=np.float32)

    def overlay(
        self,
        target: SessionView | Camera,
        selection: np.ndarray | None = None,
        *,
        full_camera: bool = True,
    ) -> Overlay:
        """The selection recoloured over a view (a session view, or any camera — scaled to
        the render scale when ``full_camera``)."""
        cfg = self.config
        if isinstance(target, SessionView):
            cam, rgb, vid = target.camera, target.buffers.rgb, target.id
        else:
            cam = self.working_camera(target) if full_camera else target
            rgb, vid = self._render(cam).rgb, None
        with self.timings.measure("overlay"):
            cov = self._render_values(cam, self.indicator(selection))
            a = (np.clip(cov, 0.0, 1.0) * np.float32(cfg.overlay_alpha))[..., None]
            img = rgb * (1.0 - a) + np.asarray(cfg.overlay_color, np.float32) * a
        return Overlay(
            cam, cov.astype(np.float32), cov >= cfg.overlay_threshold, img.astype(np.float32), vid
        )

    # ------------------------------------------------------------------ state access
    @property
    def current(self) -> ObjectRecord:
        return self.objects[-1]

    @property
    def selection(self) -> np.ndarray:
        """Current object's selection: per-surfel bool (2DGS) or ``[D,H,W]`` bool (NeRF)."""
        return self._selection

    @property
    def views(self) -> list[SessionView]:
        """Centroid views of the current object, in spawn order."""
        return list(self.current.views)

    def view(self, view_id: str) -> SessionView:
        try:
            return self._views[view_id]
        except KeyError:
            raise KeyError(f"no view {view_id!r} in this session") from None

    def _resolve(self, view: SessionView | str) -> SessionView:
        v = self.view(view) if isinstance(view, str) else view
        if v.object_index != self.current.index:
            raise ValueError(f"view {v.id} belongs to a finished object")
        return v

    def label_set(self, include_current: bool = True) -> np.ndarray:
        """Committed labels, plus the current object's selection as the next label."""
        out = self.labels.copy()
        if include_current and self._selection.any():
            take = self._selection if self.config.overwrite_labels else self._selection & (out == 0)
            out[take] = self.current.label
        return out

    # ------------------------------------------------------------------ clicks and prompts
    def add_anchor(self, camera: Camera, source: str = "camera", index: int = -1) -> AnchorView:
        """Offer one more anchor — manual anchor selection (paper Sec. 1 and the
        limitations: when the Fibonacci views do not expose an off-centre or occluded
        target, the user picks a training camera or the current viewport).

        Args:
            camera: full-resolution camera (OpenCV convention); rendered at the session's
                ``render_scale`` on first use.
            source: ``"training"``, ``"viewport"`` or ``"camera"`` (free-form label kept
                in the saved session); index: e.g. the training-camera index.

        Returns the new :class:`AnchorView` (its ``index`` is the position to click).
        The anchor list is part of the saved session, so a replay sees it too.
        """
        if not isinstance(camera, Camera):
            raise TypeError(f"add_anchor: expected a Camera, got {type(camera).__name__}")
        a = AnchorView(
            len(self.anchors),
            self.working_camera(camera),
            camera,
            str(source),
            int(index),
            None,
            self,
        )
        self.anchors.append(a)
        self._autosave()
        return a

    def anchor(self, i: int) -> AnchorView:
        """Anchor ``i`` (:class:`DivasInputError` naming the range when there is none)."""
        if not 0 <= int(i) < len(self.anchors):
            raise DivasInputError(None, f"anchor {i} does not exist ({len(self.anchors)} anchors)")
        return self.anchors[int(i)]

    def _back_project(self, anchor: AnchorView, xy) -> tuple[float, np.ndarray]:
        b = anchor.buffers
        depth = b.D_med if self.kind == "2dgs" else b.D_mw
        return click_point(anchor.camera, xy, depth, b.alpha, self.config.view.min_alpha_click)

    def click(self, anchor_index: int, xy, positive: bool = True) -> SessionView | AnchorClick:
        """A click on an anchor (pixels of the anchor render).

        Positive: spawns, renders and returns the centroid view (Sec. 3.3). Negative:
        records an extra negative prompt for the centroid views of this anchor and
        returns the :class:`AnchorClick`.

        Raises:
            DivasInputError: outside the image, or no surface under the click.
        """
        anchor = self.anchor(anchor_index)
        xy = (float(xy[0]), float(xy[1]))
        obj = self.current
        clicks = obj.clicks.setdefault(anchor.index, [])
        ci = len(clicks)
        try:
            if not positive:
                _, point = self._back_project(anchor, xy)
                rec = AnchorClick(anchor.index, ci, xy, False, point)
                clicks.append(rec)
                return rec
            vid = f"o{obj.index}:a{anchor.index}:c{ci}"
            t0 = time.perf_counter()
            with self._render_lock, self.timings.measure("centroid"):
                if self.kind == "2dgs":
                    if self._planner is None:
                        from ..views import GsCentroidPlanner

                        self._planner = GsCentroidPlanner(
                            self.scene, self.renderer, self.config.view
                        )
                    cv = self._planner.centroid_view(anchor.camera, xy, anchor.buffers, name=vid)
                else:
                    from ..views import nerf_centroid_view

                    cv = nerf_centroid_view(
                        anchor.camera,
                        xy,
                        anchor.buffers,
                        zoom=self.config.nerf_zoom,
                        forward_facing=self.forward_facing,
                        config=self.config.view,
                        name=vid,
                    )
            t1 = time.perf_counter()
        except DivasInputError as e:
            raise DivasInputError(None, f"anchor {anchor.index}: {e.problem}") from None
        view = SessionView(vid, obj.index, anchor.index, ci, cv, _session=self)
        _ = view.buffers
        view.timings = {"centroid_s": t1 - t0, "render_s": time.perf_counter() - t1}
        clicks.append(AnchorClick(anchor.index, ci, xy, True, cv.target.copy(), vid))
        obj.views.append(view)
        self._views[vid] = view
        return view

    def default_prompts(self, view: SessionView | str) -> tuple[np.ndarray, np.ndarray]:
        """The click's 3D point projected into the view (positive) plus the anchor's
        visible negative clicks (negative)."""
        v = self.view(view) if isinstance(view, str) else view
        cam = v.camera
        uv, _ = cam.project(v.centroid.target[None])
        pts, labs = [uv[0]], [1]
        negs = [
            c
            for c in self.objects[v.object_index].clicks.get(v.anchor, [])
            if not c.positive and c.point is not None
        ]
        if negs:
            d_ref = v.buffers.D_ref
            puv, z = cam.project(np.stack([c.point for c in negs]))
            for (x, y), zz in zip(puv, z):
                if not (zz > 0 and 0 <= x < cam.width and 0 <= y < cam.height):
                    continue
                d = float(d_ref[int(y), int(x)])
                if d > 0 and zz <= (1.0 + self.config.negative_occlusion_tol) * d:
                    pts.append((x, y))
                    labs.append(0)
        return np.asarray(pts, np.float64), np.asarray(labs, np.int64)

    def _prompt_set(
        self, v: SessionView, points, labels, include_default: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        p, lab = _as_prompt_arrays(points, labels)
        cam = v.camera
        bad = ~((p[:, 0] >= 0) & (p[:, 0] < cam.width) & (p[:, 1] >= 0) & (p[:, 1] < cam.height))
        if bad.any():
            x, y = p[np.flatnonzero(bad)[0]]
            raise DivasInputError(
                None,
                f"view {v.id}: prompt point ({x:g}, {y:g}) is outside "
                f"the {cam.width}x{cam.height} image",
            )
        if include_default:
            dp, dl = self.default_prompts(v)
            p, lab = np.concatenate([dp, p]), np.concatenate([dl, lab])
        return p, lab

    def _mask_from(
        self, v: SessionView, res: SegResult, p: np.ndarray, lab: np.ndarray, seconds: float = 0.0
    ) -> MaskPreview:
        cfg = self.config
        sel = select_mask(res.masks, res.scores, lab, cfg.min_score, cfg.mask_channel)
        weighted, band, reason = None, None, sel.reason
        if sel.accepted:
            b = v.buffers
            if self.kind == "2dgs":
                weighted, band = apply_gs_bandpass(sel.mask, b.D_ref, p, lab, config=cfg.bandpass)
            else:
                weighted = apply_nerf_depth_weight(sel.mask, b.D_ref, config=cfg.nerf_weight)
            weighted = np.clip(weighted, 0.0, 1.0).astype(np.float32)
            if int(np.count_nonzero(weighted >= 0.5)) < cfg.min_mask_pixels:
                reason = "empty mask after depth weighting"
        return MaskPreview(
            v.id, p, lab, res.masks, res.scores, sel, weighted, band, reason, seconds
        )

    def _require_segmenter(self) -> _TimedSegmenter:
        if self._seg is None:
            raise DivasInputError(None, "this session has no segmenter (pass one to open/load)")
        return self._seg

    def prompt(
        self, view: SessionView | str, points=(), labels=(), *, include_default: bool = True
    ) -> MaskPreview:
        """Mask preview for a prompt set (default prompts + ``points``), synchronous."""
        v = self._resolve(view)
        if v.status in ("fused", "pending"):
            raise ValueError(f"view {v.id} is already accepted ({v.status}); undo it first")
        p, lab = self._prompt_set(v, points, labels, include_default)
        seg = self._require_segmenter()
        b = v.buffers
        t0 = time.perf_counter()
        res = seg.segment(b.rgb, b.D_ref, p, lab, view_id=v.id)
        prev = self._mask_from(v, res, p, lab, time.perf_counter() - t0)
        v.preview, v.points, v.labels = prev, p, lab
        return prev

    # ------------------------------------------------------------------ accept / sync
    def _end_of_group(self, v: SessionView) -> bool:
        return not any(
            o.anchor == v.anchor and o.status == "open" and o is not v for o in self.current.views
        )

    def next_view(self) -> SessionView | None:
        """The first open (not yet accepted) centroid view of the current object."""
        return next((v for v in self.current.views if v.status == "open"), None)

    def accept(
        self, view: SessionView | str, points=None, labels=None, *, include_default: bool = True
    ) -> AcceptResult:
        """Accept a view (Sec. 3.4–3.7): fuse its mask (NeRF: at the group sync).

        ``points``/``labels``: the prompt set (default: the last previewed set, else the
        default prompts). Rejected views (no positive prompt, score < 0.5, empty mask)
        are recorded with their reason and change nothing.
        """
        v = self._resolve(view)
        if v.status in ("fused", "pending"):
            raise ValueError(f"view {v.id} is already accepted ({v.status}); undo it first")
        if points is not None or labels is not None:
            p, lab = self._prompt_set(
                v,
                points if points is not None else (),
                labels if labels is not None else (),
                include_default,
            )
        elif v.points is not None:
            p, lab = v.points, v.labels
        else:
            p, lab = self._prompt_set(v, (), (), True)
        v.points, v.labels = p, lab
        self.current.accept_order.append(v.id)
        t0 = time.perf_counter()
        n_seg = len(self.timings.calls("segmenter"))
        if self.kind == "2dgs" or not self.config.nerf_async:
            prev = v.preview
            same = (
                prev is not None
                and np.array_equal(prev.points, p)
                and np.array_equal(prev.labels, lab)
            )
            if not same:
                prev = self.prompt(v, p, lab, include_default=False)
            result = self._fuse_group([(v, prev)], view=v)
        else:
            self._accept_async(v, p, lab)
            if self._end_of_group(v) or len(self._pending) >= self.config.sync_pending:
                result = self.sync(view=v)
            else:
                result = AcceptResult(
                    v, v.status, None, [], [], len(self._pending), False, self._selection
                )
        seg_calls = self.timings.calls("segmenter")[n_seg:]
        result.timings.setdefault("segmenter_s", float(sum(seg_calls)))
        result.timings["update_s"] = time.perf_counter() - t0
        self.updates.append(
            {
                "view": v.id,
                "status": v.status,
                "reason": v.reason,
                "synced": result.synced,
                **v.timings,
                **result.timings,
            }
        )
        self._autosave()
        return result

    def _accept_async(self, v: SessionView, p: np.ndarray, lab: np.ndarray) -> None:
        if self._worker is None:
            self._worker = SamWorker(
                self._require_segmenter(), asynchronous=True, sync_pending=self.config.sync_pending
            )
        b = v.buffers
        self._worker.submit(v.id, b.rgb, b.D_ref, p, lab)
        v.status = "pending"
        self._pending.append(v)

    def sync(self, view: SessionView | None = None) -> AcceptResult:
        """Collect every pending NeRF mask and fuse them together (no-op when none)."""
        if not self._pending:
            return AcceptResult(
                view,
                None if view is None else view.status,
                None if view is None else view.reason,
                [],
                [],
                0,
                False,
                self._selection,
            )
        group, self._pending = self._pending, []
        t0 = time.perf_counter()
        results: dict[Hashable, SegResult] = {}
        failures: dict[Hashable, BaseException] = {}
        try:
            results = self._worker.sync() if self._worker is not None else {}
        except SegmentationJobError as e:
            results, failures = dict(e.results), dict(e.failures)
        self.timings.add("segmenter_wait", time.perf_counter() - t0)
        items: list[tuple[SessionView, MaskPreview | str]] = []
        for v in group:
            res = results.get(v.id)
            if res is None and self._worker is not None:
                res = self._worker.result(v.id)
            if res is None:
                cause = failures.get(v.id)
                items.append(
                    (v, f"segmentation failed: {cause}" if cause else "segmentation result missing")
                )
                continue
            prev = self._mask_from(v, res, v.points, v.labels)
            v.preview = prev
            items.append((v, prev))
        out = self._fuse_group(items, view=view)
        out.timings["segmenter_wait_s"] = time.perf_counter() - t0 - out.timings.get("fuse_s", 0)
        return out

    def _fuse_group(self, items, view: SessionView | None) -> AcceptResult:
        from ..fusion import FusionCapacityError, FusionView

        fused, rejected, kernel_s = [], [], 0.0
        for v, prev in items:
            reason = prev if isinstance(prev, str) else prev.reason
            if reason is not None:
                v.status, v.reason = "rejected", reason
                v.score = float("nan") if isinstance(prev, str) else prev.score
                rejected.append((v.id, reason))
                continue
            b = v.buffers
            fv = FusionView(
                v.camera,
                prev.mask,
                b.D_min,
                b.D_ref,
                b.D_max,
                b.N_samp,
                float(v.centroid.d_cam),
                v.id,
            )
            t = time.perf_counter()
            try:
                fid = self.fusion.add_view(fv)
            except FusionCapacityError as e:
                v.status, v.reason = "open", None
                self.current.accept_order.remove(v.id)
                raise DivasInputError(None, str(e)) from None
            dt = time.perf_counter() - t
            self.timings.add("kernel", dt)
            kernel_s += dt
            v.status, v.reason, v.score = "fused", None, prev.score
            v.mask, v.fusion_id, v.fusion_view = prev.mask, fid, fv
            fused.append(v.id)
        timings: dict[str, float] = {"kernel_s": kernel_s}
        ov = nov = nxt = None
        if fused:
            timings["mapping_s"] = self._update_selection()
            t = time.perf_counter()
            if view is not None and view.status == "fused":
                ov = self.overlay(view)
            nxt = self.next_view()
            if nxt is not None:
                nov = self.overlay(nxt)
            timings["overlay_s"] = time.perf_counter() - t
        timings["fuse_s"] = sum(timings.values())
        return AcceptResult(
            view,
            None if view is None else view.status,
            None if view is None else view.reason,
            fused,
            rejected,
            len(self._pending),
            True,
            self._selection,
            ov,
            nxt,
            nov,
            timings,
        )

    # ------------------------------------------------------------------ selection
    def _live_views(self) -> list[SessionView]:
        return [v for v in self.current.views if v.status == "fused"]

    def _update_selection(self) -> float:
        t = time.perf_counter()
        live = self._live_views()
        if not live:
            self._selection = np.zeros_like(self._selection)
            return 0.0
        fused = self.fusion.result()
        if self.kind == "nerf":
            self._selection = self.grid.to_dense(fused.segmented.astype(bool), False)
        else:
            self._selection = self._map_surfels(fused, live)
        dt = time.perf_counter() - t
        self.timings.add("mapping", dt)
        return dt

    def _map_surfels(self, fused, live: list[SessionView]) -> np.ndarray:
        from ..mapping import SurfelMapper

        if self._mapper is None:
            self._mapper = SurfelMapper(self.scene, self.grid, self.config.mapping, self.device)
        res = self._mapper.map(
            fused,
            [v.fusion_view for v in live],
            [int(v.fusion_id) for v in live],
            self.config.mapping,
        )
        self.last_mapping = res
        return np.asarray(res.selected, dtype=bool)

    # ------------------------------------------------------------------ undo / reset / objects
    def undo(self) -> SessionView | None:
        """Undo the last accepted view of the current object (exact); returns it, or None."""
        obj = self.current
        while obj.accept_order:
            vid = obj.accept_order.pop()
            v = self._views[vid]
            if v.status == "fused":
                with self.timings.measure("undo"):
                    self.fusion.remove_view(int(v.fusion_id))
                v.status, v.fusion_id, v.fusion_view, v.mask = "open", None, None, None
                self._update_selection()
                self._autosave()
                return v
            if v.status == "pending":
                self._pending.remove(v)
                if self._worker is not None:
                    self._worker.forget(v.id)
                v.status = "open"
                self._autosave()
                return v
            # rejected accepts changed nothing: keep looking
        return None

    def reset(self, all_objects: bool = False) -> None:
        """Drop the current object's views and selection (``all_objects``: every label too)."""
        self._drain_worker()
        self.fusion.reset()
        for v in self.current.views:
            self._views.pop(v.id, None)
        if all_objects:
            for o in self.objects[:-1]:
                for v in o.views:
                    self._views.pop(v.id, None)
            self.objects = [ObjectRecord(0, 1, "object_1")]
            self.labels[...] = 0
        else:
            cur = self.current
            self.objects[-1] = ObjectRecord(cur.index, cur.label, f"object_{cur.label}")
        self._selection = np.zeros_like(self._selection)
        self._autosave()

    def _drain_worker(self) -> None:
        self._pending = []
        if self._worker is not None:
            with contextlib.suppress(SegmentationJobError):
                self._worker.sync()

    def finish_object(self, name: str | None = None) -> ObjectRecord:
        """Commit the current selection as the next label and start a new object."""
        if self._pending:
            self.sync()
        cur = self.current
        if name:
            cur.name = str(name)
        cur.selection = self._selection.copy()
        take = cur.selection if self.config.overwrite_labels else cur.selection & (self.labels == 0)
        self.labels[take] = cur.label
        cur.finished = True
        # open views of the finished object are dropped from the id table
        for v in cur.views:
            if v.status == "open":
                self._views.pop(v.id, None)
        cur.views = [v for v in cur.views if v.status != "open"]
        self.fusion.reset()
        self._selection = np.zeros_like(self._selection)
        k = len(self.objects)
        self.objects.append(ObjectRecord(k, k + 1, f"object_{k + 1}"))
        self._autosave()
        return cur

    # ------------------------------------------------------------------ export
    def export(self, path: str | PathLike, labels_path: str | PathLike | None = None):
        """Write the current selection in the input's format (PLY subset / masked npz grid)."""
        from ..export import export_selection

        if self._pending:
            self.sync()
        return export_selection(self.scene, self._selection, path, labels_path=labels_path)

    def object_selections(self) -> list[tuple[ObjectRecord, np.ndarray]]:
        """Finished objects and the current one when its selection is non-empty."""
        out = [(o, o.selection) for o in self.objects[:-1] if o.selection is not None]
        if self._selection.any():
            out.append((self.current, self._selection))
        return out

    def export_objects(self, out_dir: str | PathLike) -> dict[str, Any]:
        """One file per object (:func:`~divas_engine.export.export_selection`) plus the label
        set: ``labelled.ply`` with ``divas_label`` (surfels) or ``labels.npy`` (NeRF grid)."""
        from ..export import export_selection
        from .labels_io import write_labelled_ply

        if self._pending:
            self.sync()
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        files: dict[str, Any] = {"objects": []}
        ext = ".npz" if self.kind == "nerf" else _surfel_ext(self.scene)
        for o, sel in self.object_selections():
            if not sel.any():
                continue
            safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in o.name)
            p = out / f"{o.label:02d}_{safe}{ext}"
            export_selection(self.scene, sel, p)
            files["objects"].append(
                {"name": o.name, "label": o.label, "path": str(p), "count": int(sel.sum())}
            )
        labels = self.label_set()
        if self.kind == "2dgs":
            files["labelled"] = str(write_labelled_ply(self.scene, labels, out / "labelled.ply"))
        else:
            np.save(out / "labels.npy", labels)
            files["labelled"] = str(out / "labels.npy")
        return files

    def write_labelled(self, path: str | PathLike) -> Path:
        """The scene with the ``divas_label`` column (surfel scenes)."""
        from .labels_io import write_labelled_ply

        if self.kind != "2dgs":
            raise DivasInputError(path, "labelled PLY needs a surfel scene (NeRF: labels.npy)")
        return write_labelled_ply(self.scene, self.label_set(), path)

    # ------------------------------------------------------------------ report
    def counts(self) -> dict[str, Any]:
        views = [v for o in self.objects for v in o.views]
        st = [v.status for v in views]
        return {
            "primitives": int(len(self.scene)),
            "anchors": len(self.anchors),
            "centroid_views": len(views),
            "accepted": st.count("fused"),
            "rejected": st.count("rejected"),
            "pending": st.count("pending"),
            "open": st.count("open"),
            "objects": len(self.object_selections()),
            "selected": int(self._selection.sum()),
            "labelled": int((self.label_set() > 0).sum()),
            "active_voxels": int(len(self.grid)),
            "segmented_voxels": int(self.fusion.result().segmented.sum())
            if self._live_views()
            else 0,
        }

    def report(self) -> dict[str, Any]:
        """Timings, counts, views (with rejection reasons), memory, config, seed."""
        views = []
        for o in self.objects:
            for v in o.views:
                views.append(
                    {
                        "id": v.id,
                        "object": o.name,
                        "anchor": v.anchor,
                        "click": v.click,
                        "status": v.status,
                        "reason": v.reason,
                        "score": None if not np.isfinite(v.score) else float(v.score),
                        "strategy": v.centroid.strategy,
                        "d_cam": float(v.centroid.d_cam),
                        "prompts": None if v.points is None else int(len(v.points)),
                    }
                )
        summ = self.timings.summary()
        return {
            "kind": self.kind,
            "seed": self.config.seed,
            "device": str(self.device),
            "forward_facing": self.forward_facing,
            "segmenter": getattr(self.segmenter, "name", type(self.segmenter).__name__),
            "config": self.config.to_dict(),
            "grid": (self.grid.report.as_dict() if hasattr(self.grid.report, "as_dict") else None),
            "timings": summ,
            "updates": self.updates,
            "counts": self.counts(),
            "views": views,
            "objects": [
                {"name": o.name, "label": o.label, "count": int(s.sum())}
                for o, s in self.object_selections()
            ],
            "memory": memory_report(),
        }

    # ------------------------------------------------------------------ persistence
    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        arrays: dict[str, np.ndarray] = {}
        objs = []
        for o in self.objects:
            vdocs = []
            for v in o.views:
                key = None
                if v.status == "fused" and v.mask is not None:
                    key = f"mask_{len(arrays)}"
                    arrays[key] = v.mask.astype(np.float32)
                vdocs.append(v.to_dict(key))
            objs.append(
                {
                    "index": o.index,
                    "label": o.label,
                    "name": o.name,
                    "finished": o.finished,
                    "accept_order": list(o.accept_order),
                    "clicks": {str(a): [c.to_dict() for c in cs] for a, cs in o.clicks.items()},
                    "views": vdocs,
                }
            )
        arrays["labels"] = self.label_set(include_current=False)
        arrays["selection"] = self._selection
        doc = {
            "format": SESSION_FORMAT,
            "version": SESSION_VERSION,
            "scene": {
                "kind": self.kind,
                "count": int(len(self.scene)),
                "fingerprint": _scene_fingerprint(self.scene),
                "path": None
                if getattr(self.scene, "source", None) is None
                else str(self.scene.source.path),
            },
            "config": self.config.to_dict(),
            "forward_facing": self.forward_facing,
            "anchors": [
                {"camera": a.full_camera.to_dict(), "source": a.source, "index": a.source_index}
                for a in self.anchors
            ],
            "objects": objs,
        }
        return doc, arrays

    def save(self, path: str | PathLike) -> Path:
        """Write the session (JSON + ``.npz``), atomically."""
        doc, arrays = self._state()
        return save_state(path, doc, arrays)

    def _autosave(self) -> None:
        if self.config.autosave:
            self.save(self.config.autosave)

    @classmethod
    def load(
        cls,
        path: str | PathLike,
        scene: Scene,
        segmenter: Segmenter | None = None,
        device=None,
        *,
        cameras: Sequence[Camera] | None = None,
        gt_values: np.ndarray | None = None,
        autosave: str | None | bool = False,
    ) -> Session:
        """Rebuild a saved session on ``scene`` by replaying it (stored poses re-rendered,
        stored masks fused, mapping re-run); NeRF views still pending when it was saved are
        re-submitted to ``segmenter``. ``replay_matches`` tells whether the replayed labels
        equal the saved ones. ``autosave``: False keeps it off while loading and after;
        a path (or None) overrides the saved config's."""
        doc, arrays = load_state(path)
        config = SessionConfig.from_dict(doc["config"])
        from dataclasses import replace

        final_autosave = config.autosave if autosave is False else autosave
        config = replace(config, autosave=None)
        sd = doc["scene"]
        if sd["kind"] != scene_kind(scene) or sd["count"] != len(scene):
            raise DivasInputError(
                path,
                f"session was saved on a {sd['kind']} scene of "
                f"{sd['count']} primitives, not this one",
            )
        if sd.get("fingerprint") and sd["fingerprint"] != _scene_fingerprint(scene):
            raise DivasInputError(
                path, "session was saved on a different scene (fingerprint mismatch)"
            )
        anchors = [
            (Camera.from_dict(a["camera"]), a["source"], int(a["index"])) for a in doc["anchors"]
        ]
        s = cls(
            scene,
            cameras,
            config,
            segmenter,
            device,
            anchors,
            bool(doc["forward_facing"]),
            gt_values=gt_values,
        )
        s.plan = None
        s.objects = []
        for od in doc["objects"]:
            s._restore_object(od, arrays)
            if od["finished"]:
                s.finish_object(od["name"])
                s.objects.pop()  # finish_object opened the next one; the doc lists it
        if not s.objects or s.objects[-1].finished:
            k = len(s.objects)
            s.objects.append(ObjectRecord(k, k + 1, f"object_{k + 1}"))
        saved = arrays.get("labels")
        s.replay_matches = bool(
            saved is not None
            and np.array_equal(saved, s.labels)
            and np.array_equal(arrays.get("selection"), s._selection)
        )
        s.config = replace(
            s.config, autosave=None if final_autosave is None else str(final_autosave)
        )
        return s

    def _restore_object(self, od: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        obj = ObjectRecord(int(od["index"]), int(od["label"]), str(od["name"]))
        self.objects.append(obj)
        for a, cs in od["clicks"].items():
            obj.clicks[int(a)] = [
                AnchorClick(
                    int(c["anchor"]),
                    int(c["index"]),
                    (float(c["xy"][0]), float(c["xy"][1])),
                    bool(c["positive"]),
                    None if c["point"] is None else np.asarray(c["point"], np.float64),
                    c["view"],
                )
                for c in cs
            ]
        pending = []
        for vd in od["views"]:
            cam = Camera.from_dict(vd["camera"])
            cv = CentroidView(
                cam,
                float(vd["d_cam"]),
                np.asarray(vd["target"], np.float64),
                (float(vd["xy"][0]), float(vd["xy"][1])),
                float(vd["depth"]),
                None if vd["box"] is None else tuple(vd["box"]),
                vd["strategy"],
                float(vd["r_init"]),
                int(vd["neighbours"]),
            )
            v = SessionView(
                vd["id"], obj.index, int(vd["anchor"]), int(vd["click"]), cv, _session=self
            )
            v.status, v.reason = vd["status"], vd["reason"]
            v.score = float("nan") if vd["score"] is None else float(vd["score"])
            if vd["points"] is not None:
                v.points = np.asarray(vd["points"], np.float64).reshape(-1, 2)
                v.labels = np.asarray(vd["labels"], np.int64)
            obj.views.append(v)
            self._views[v.id] = v
            if v.status == "fused":
                from ..fusion import FusionView

                mask = arrays[vd["mask"]]
                b = v.buffers
                fv = FusionView(
                    cam, mask, b.D_min, b.D_ref, b.D_max, b.N_samp, float(cv.d_cam), v.id
                )
                with self.timings.measure("kernel"):
                    v.fusion_id = self.fusion.add_view(fv, int(vd["fusion_id"]))
                v.mask, v.fusion_view = mask, fv
            elif v.status == "pending":
                pending.append(v)
        obj.accept_order = list(od["accept_order"])
        if self._live_views():
            self._update_selection()
        for v in pending:
            self._accept_async(v, v.points, v.labels)
        if pending:
            self.sync()

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._worker is not None:
            self._worker.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _surfel_ext(scene: SurfelScene) -> str:
    src = scene.source
    if src is None or src.format in ("ply", "compressed_ply"):
        return ".ply"
    if src.format == "sog":  # a .sog bundle, or a folder for an unbundled input
        return ".sog" if scene.extras.get("sog_bundled") else ""
    return {"splat": ".splat", "spz": ".spz"}.get(src.format, ".ply")

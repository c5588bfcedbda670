"""What a session holds and shows: its parts (scene, backend, renderer, state) and every
read of them — queries, renders, overlays, the segmenter's view contexts, counts, the
report and the saved document. :class:`SessionReader` changes no state but the renders
it keeps in the records; the steps that change the state are
:class:`~divas_engine.session.Session`'s.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..blas_threads import BlasThreads
from ..camera import Camera
from ..errors import DivasInputError, InputErrorCode
from ..kinds import SceneKind, ViewStatus
from ..render import make_renderer
from ..render.buffers import RenderBuffers
from ..scene import Scene
from ..segment.base import Segmenter
from ..segment.context import SceneBinding, ViewContext
from ..segment.worker import SamWorker
from ..views import AnchorPlan, plan_scene_anchors
from . import negative_views
from .backends import SessionBackend, backend_class_for
from .config import SessionConfig
from .edits import EditLayer
from .history import SessionHistory
from .masks import TimedSegmenter, default_prompts
from .persistence import session_document
from .records import (
    AnchorView,
    CorrectionResult,
    ObjectRecord,
    Overlay,
    SessionView,
)
from .rendering import SessionRendering
from .report import session_counts, session_report
from .state import SessionState
from .store import save_state
from .timing import Timings

__all__ = ["SessionReader", "anchor_plan", "scene_kind"]


def scene_kind(scene: Scene) -> SceneKind:
    """The session kind of a scene (its backend's; both Gaussian kinds are ``GS2D``)."""
    return backend_class_for(scene).kind


def anchor_plan(
    scene: Scene, cameras: Sequence[Camera] | None, config: SessionConfig | None = None
) -> AnchorPlan:
    """The anchor plan of a scene (Sec. 3.2): what :meth:`Session.open` offers by default."""
    cfg = config or SessionConfig()
    return plan_scene_anchors(
        scene, list(cameras or []), kind=scene_kind(scene), config=cfg.view, all_views=cfg.all_views
    )


class SessionReader:
    """The parts of a session and the reads of them (module docstring).

    Attributes:
        scene, cameras, config, device, forward_facing: as given.
        kind: the backend's :class:`~divas_engine.kinds.SceneKind`.
        backend: the scene's :class:`~divas_engine.session.backends.SessionBackend`.
        renderer: renders anchors, centroid views and overlays; rendering: the
            session's :class:`~.rendering.SessionRendering` over it.
        state: the :class:`~.state.SessionState` (anchors, objects, labels, selections…).
        timings, updates: per-stage seconds and one record per accept and click.
        last_correction: what the last click did as a correction (:mod:`.corrections`).
        replay_matches: after ``Session.load``, whether the replay reproduced the saved
            labels; plan: the anchor plan of ``open``; autosave_error: the last
            autosave failure (None: the last autosave landed).
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

        backend_cls = backend_class_for(scene)
        self._blas = False
        self.scene = scene
        self.kind = backend_cls.kind
        self.cameras = list(cameras or [])
        self._config = config
        self.device = resolve_device(device)
        self.forward_facing = bool(forward_facing)
        self.timings = Timings()
        self.updates: list[dict[str, Any]] = []
        self.segmenter = segmenter
        if renderer is None:
            renderer = make_renderer(scene, device=self.device, config=config.render)
        self.renderer = renderer
        self.rendering = SessionRendering(self.renderer, self.timings, lambda: self.config)
        self._seg = None if segmenter is None else TimedSegmenter(segmenter, self.timings)
        self.plan: AnchorPlan | None = None
        if segmenter is not None:
            r = self.rendering
            segmenter.bind_scene(
                SceneBinding(
                    scene,
                    r.render_values,
                    up=lambda: None if self.plan is None else self.plan.up,
                    render_sparse=r.render_sparse if self.renderer.renders_sparse else None,
                )
            )
        self.backend: SessionBackend = backend_cls(
            scene,
            config,
            forward_facing=self.forward_facing,
            device=self.device,
            renderer=self.renderer,
        )
        self._gt_values = None
        #: the ground truth rendered per view id (evaluation; a view is segmented again
        #: when a click corrects it)
        self._truths: dict[str, tuple[Camera, np.ndarray]] = {}
        if gt_values is not None:
            self.set_ground_truth(gt_values)
        shape = self.backend.selection_shape
        self.state = SessionState.empty(
            [self._new_anchor(i, *a) for i, a in enumerate(anchors)], shape
        )
        self._worker: SamWorker | None = None
        self._history: SessionHistory | None = None
        self.autosave_error: str | None = None
        self.replay_matches: bool | None = None
        self.last_correction: CorrectionResult | None = None
        self._closed = False
        # one BLAS thread while the session is open: no core left spinning after each of
        # its tall, thin NumPy products (the same bits; :mod:`divas_engine.blas_threads`)
        BlasThreads.acquire()
        self._blas = True

    @property
    def config(self) -> SessionConfig:
        return self._config

    @config.setter
    def config(self, value: SessionConfig) -> None:
        self._config = value
        self.backend.config = value

    @property
    def grid(self):
        """Occupancy grid of the active voxels (the backend's)."""
        return self.backend.grid

    @property
    def fusion(self):
        """The incremental fusion state (the backend's)."""
        return self.backend.fusion

    @property
    def grid_config(self):
        """Surfel scenes: the occupancy :class:`~divas_engine.fusion.GridConfig`; else None."""
        return self.backend.grid_config

    @property
    def nerf_config(self):
        """Density grids: the :class:`~divas_engine.fusion.NerfFusionConfig`; else None."""
        return self.backend.nerf_config

    @property
    def preset(self) -> str:
        """Density grids: the NeRF preset in use (AttributeError on surfel scenes)."""
        return self.backend.preset

    @property
    def last_mapping(self):
        """Surfel scenes: the latest voxel-to-surfel mapping result; else None."""
        return self.backend.last_mapping

    @property
    def warmed_up(self) -> bool:
        """The fusion state is built (reading it would not wait for the warm-up)."""
        return self.backend.ready

    def wait_warm_up(self, timeout: float | None = None) -> bool:
        """Wait at most ``timeout`` s for the background warm-up of :meth:`open` (the
        fusion state, then the segmenter's per-scene state); whether it is done. Every
        step waits for what it uses, so nothing needs to call it."""
        return self.backend.wait_warm_up(timeout)

    def set_ground_truth(self, values: np.ndarray) -> None:
        """Evaluation only: ground truth handed to a segmenter that reads it (the oracle)
        at each view, composited in the view's own RGB blend (read back, not blended
        again: :meth:`~divas_engine.render.Renderer.attach_values`)."""
        v = np.asarray(values, dtype=np.float32)
        shape = self.backend.selection_shape
        if v.shape != shape:
            raise DivasInputError(
                None, f"ground-truth labels have shape {v.shape}, the scene needs {shape}"
            )
        self._gt_values = v
        self._truths.clear()
        if self.segmenter is not None:
            with self.rendering.lock:
                self.renderer.attach_values(v if self.segmenter.wants_ground_truth else None)

    @property
    def anchors(self) -> list[AnchorView]:
        return self.state.anchors

    @property
    def objects(self) -> list[ObjectRecord]:
        """The objects, the last one current."""
        return self.state.objects

    @property
    def labels(self) -> np.ndarray:
        """The committed integer labels."""
        return self.state.labels

    @property
    def edits(self) -> EditLayer:
        """The manual edit layers (:mod:`.edits`)."""
        return self.state.edits

    @property
    def current(self) -> ObjectRecord:
        return self.state.current

    @property
    def selection(self) -> np.ndarray:
        """Current object's selection: per-surfel bool (2DGS) or ``[D,H,W]`` bool (NeRF)."""
        return self.state.selection

    @property
    def semantic_selection(self) -> np.ndarray:
        """The fused-and-mapped selection of the current object, before manual edits."""
        return self.state.semantic

    @property
    def views(self) -> list[SessionView]:
        """Centroid views of the current object, in spawn order."""
        return list(self.current.views)

    def view(self, view_id: str) -> SessionView:
        return self.state.view(view_id)

    def _resolve(self, view: SessionView | str) -> SessionView:
        v = self.view(view) if isinstance(view, str) else view
        if v.object_index != self.current.index:
            raise DivasInputError(
                None,
                f"view {v.id} belongs to a finished object",
                code=InputErrorCode.VIEW_FINISHED,
                details={"view": v.id},
            )
        return v

    def anchor(self, i: int) -> AnchorView:
        """Anchor ``i`` (:class:`DivasInputError` naming the range when there is none)."""
        if not 0 <= int(i) < len(self.anchors):
            n = len(self.anchors)
            raise DivasInputError(
                None,
                f"anchor {i} does not exist ({n} anchors)",
                code=InputErrorCode.NO_ANCHOR,
                details={"anchor": int(i), "anchors": n},
            )
        return self.anchors[int(i)]

    def next_view(self) -> SessionView | None:
        """The first open (not yet accepted) centroid view of the current object."""
        return self.state.next_view()

    def click_holds(self, view: SessionView | str) -> bool:
        """Whether the click that spawned ``view`` holds its surface patch in the
        selection although the view was refused at accept (corrections on:
        :func:`~.corrections.constrain`) — what a refusal message tells the user."""
        v = self.view(view) if isinstance(view, str) else view
        if v.status != ViewStatus.REJECTED or not self.config.corrections.enabled:
            return False
        obj = next((o for o in self.objects if o.index == v.object_index), self.current)
        return any(c.spawned == v.id and c.positive and len(c.patch) for c in obj.corrections)

    def label_set(self, include_current: bool = True) -> np.ndarray:
        """Committed labels, plus the current object's selection as the next label."""
        return self.state.label_set(self.config.overwrite_labels, include_current)

    def object_selections(self) -> list[tuple[ObjectRecord, np.ndarray]]:
        """Finished objects and the current one when its selection is non-empty."""
        return self.state.object_selections()

    def counts(self, *, wait: bool = True) -> dict[str, Any]:
        """Views by status, primitives, objects, selected / labelled, voxels (``wait``
        False: None for the voxels while the fusion state is still being built)."""
        return session_counts(self, wait=wait)

    def report(self) -> dict[str, Any]:
        """Timings, counts, views (with rejection reasons), memory, config, seed."""
        return session_report(self)

    def render(self, target: AnchorView | SessionView) -> RenderBuffers:
        """The render of an anchor or a view: rendered now, and kept, when it is not yet."""
        return self.rendering.render(target)

    def working_camera(self, camera: Camera) -> Camera:
        """``camera`` at the session's render scale."""
        s = self.config.render_scale
        return camera if s == 1.0 else camera.scaled(s)

    def view_context(self, view: SessionView) -> ViewContext:
        """What the segmenter gets of ``view``: its render, camera and the 3D clicks of
        its object; its ground truth when the segmenter reads it (evaluation)."""
        b = self.render(view)
        truth = None
        seg = self.segmenter
        if self._gt_values is not None and seg is not None and seg.wants_ground_truth:
            truth = self._truths.get(view.id)
            if truth is None or truth[0] is not view.camera:
                truth = (view.camera, self.rendering.render_values(view.camera, self._gt_values))
                self._truths[view.id] = truth
            truth = truth[1]
        clicks = self.state.object_clicks(self.objects[view.object_index])
        return ViewContext(view.id, b.rgb, b.D_ref, view.camera, clicks, truth)

    def indicator(self, selection: np.ndarray | None = None) -> np.ndarray:
        """Float per-primitive indicator of a selection (current by default)."""
        sel = self.selection if selection is None else selection
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
        sel = self.selection if selection is None else selection
        if isinstance(target, SessionView):
            return self.rendering.overlay(target.camera, self.render(target).rgb, sel, target.id)
        cam = self.working_camera(target) if full_camera else target
        return self.rendering.overlay(cam, self.rendering.image_of(cam, self.anchors), sel)

    def _lazy_overlays(self, view: SessionView | None):
        """``(overlay of view, next open view, its overlay)`` for the current selection,
        each overlay a callable rendered on first read (an accept renders nothing the
        user does not look at). The selection is captured now."""
        sel = self.selection
        ov = nov = None
        if view is not None and view.status == ViewStatus.FUSED:
            ov = lambda: self.overlay(view, sel)  # noqa: E731
        nxt = self.next_view()
        if nxt is not None:
            nov = lambda: self.overlay(nxt, sel)  # noqa: E731
        return ov, nxt, nov

    def _anchor_full_camera(self, camera: Camera) -> Camera:
        """An anchor's full camera: ``camera`` resized so its render's long side is
        ``config.anchor_long_side`` (unchanged when that is 0)."""
        long_side = int(self.config.anchor_long_side)
        if long_side <= 0:
            return camera
        s = self.config.render_scale
        return camera.scaled(long_side / (s * max(camera.width, camera.height)))

    def _new_anchor(self, i: int, camera: Camera, source: str, index: int) -> AnchorView:
        full = self._anchor_full_camera(camera)
        return AnchorView(i, self.working_camera(full), full, str(source), int(index))

    def default_prompts(self, view: SessionView | str) -> tuple[np.ndarray, np.ndarray]:
        """The click's 3D point projected into the view (positive) plus the visible
        negative clicks (negative): of the view's object (:mod:`.corrections`), or with
        corrections off of its anchor. A negative click's view: the object's clicks
        visible there (:func:`.negative_views.view_prompts`)."""
        v = self.view(view) if isinstance(view, str) else view
        obj = self.objects[v.object_index]
        if negative_views.is_negative_view(self, v):
            return negative_views.view_prompts(self, v)  # its target is a negative click
        if self.config.corrections.enabled:
            oc = self.state.object_clicks(obj)
            negs = oc.points[~oc.positive]
        else:
            clicks = obj.clicks.get(v.anchor, [])
            negs = [c.point for c in clicks if not c.positive and c.point is not None]
        negs = np.asarray(negs, np.float64).reshape(-1, 3)
        if len(negs):
            self.render(v)  # the negative clicks' visibility reads its depth
        return default_prompts(v, negs, self.config.negative_occlusion_tol)

    def write_labelled(self, path: str | PathLike) -> Path:
        """The scene with the ``divas_label`` column (surfel scenes)."""
        return self.backend.write_labelled(self.label_set(), path)

    def save(self, path: str | PathLike) -> Path:
        """Write the session (JSON + ``.npz``), atomically."""
        doc, arrays = session_document(self)
        return save_state(path, doc, arrays)

    def autosave(self) -> None:
        """Save to ``config.autosave`` (when set). A failure (disk full, read-only
        folder …) is a :class:`RuntimeWarning` and :attr:`autosave_error`, never an
        exception: the work in memory goes on; the previous save stays intact."""
        if not self.config.autosave:
            return
        try:
            self.save(self.config.autosave)
        except (OSError, DivasInputError) as e:
            self.autosave_error = str(e)
            warnings.warn(f"autosave failed: {e}", RuntimeWarning, stacklevel=2)
        else:
            self.autosave_error = None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.segmenter is not None:
            self.segmenter.wait_prefetch(60.0)  # work a click started
        if self._worker is not None:
            self._worker.close()
        if self._blas:
            self._blas = False
            BlasThreads.release()

    def __enter__(self) -> SessionReader:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

"""What a session holds and shows, without the loop steps (those are :mod:`.session`).

:class:`SessionCore` owns the scene, its :class:`~divas_engine.session.backends.SessionBackend`
(occupancy grid and fusion state), the renderer, the anchors, the objects with their views,
the current selection and the committed labels; it renders views and overlays (Sec. 3.7),
answers queries, saves and reports. :class:`~divas_engine.session.Session` adds the
interaction loop on top.
"""

from __future__ import annotations

import contextlib
import threading
import time
import warnings
from collections.abc import Hashable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from ..blas_threads import BlasThreads
from ..camera import Camera
from ..errors import DivasInputError
from ..kinds import ViewStatus
from ..output_paths import check_output_path
from ..render import make_renderer
from ..render.buffers import RenderBuffers
from ..scene import Scene
from ..segment.base import Segmenter
from ..segment.worker import SamWorker
from ..views import AnchorPlan
from .backends import SessionBackend, backend_class_for
from .config import SessionConfig
from .edits import EditLayer, compose
from .masks import TimedSegmenter
from .persistence import session_state
from .records import AnchorView, ObjectRecord, Overlay, SessionView
from .report import session_counts, session_report
from .store import save_state
from .timing import Timings

__all__ = ["SessionCore"]


class SessionCore:
    """State, rendering, queries and outputs of a session (module docstring).

    Attributes:
        scene, cameras, config, device, forward_facing: as given.
        kind: the backend's :class:`~divas_engine.kinds.SceneKind`.
        backend: the scene's :class:`~divas_engine.session.backends.SessionBackend`.
        renderer: renders anchors, centroid views and overlays.
        anchors: the :class:`AnchorView` s offered; objects: the :class:`ObjectRecord` s
            (the last one is current); labels: the committed integer labels.
        timings, updates: per-stage seconds and one record per accept.
        replay_matches: after :meth:`~divas_engine.session.Session.load`, whether the
            replay reproduced the saved labels; plan: the anchor plan of ``open``.
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
        self._render_lock = threading.RLock()
        self.renderer = (
            renderer
            if renderer is not None
            else make_renderer(scene, device=self.device, config=config.render)
        )
        self._seg = None if segmenter is None else TimedSegmenter(segmenter, self.timings)
        self._bind_segmenter(segmenter)
        self.backend: SessionBackend = backend_cls(
            scene,
            config,
            forward_facing=self.forward_facing,
            device=self.device,
            renderer=self.renderer,
        )
        self._gt_values = None
        if gt_values is not None:
            self.set_ground_truth(gt_values)
        self.anchors: list[AnchorView] = []
        for cam, src, idx in anchors:
            full = self._anchor_full_camera(cam)
            self.anchors.append(
                AnchorView(len(self.anchors), self.working_camera(full), full, src, idx, None, self)
            )
        self._worker: SamWorker | None = None
        self._pending: list[SessionView] = []
        self._views: dict[str, SessionView] = {}
        self.objects: list[ObjectRecord] = [ObjectRecord(0, 1, "object_1")]
        shape = self.backend.selection_shape
        self.labels = np.zeros(shape, np.int32)
        self._selection = np.zeros(shape, bool)
        self._semantic = np.zeros(shape, bool)  # before manual edits (:mod:`.edits`)
        self.edits = EditLayer()
        self._history = None  # :attr:`Session.history`, made on first use
        #: the last autosave failure (None: the last autosave landed); a failed autosave
        #: warns and the session goes on (issue 14)
        self.autosave_error: str | None = None
        self.replay_matches: bool | None = None
        self.plan: AnchorPlan | None = None
        self._closed = False
        # one BLAS thread while the session is open: no core left spinning after each of
        # its tall, thin NumPy products (the same bits; :mod:`divas_engine.blas_threads`)
        BlasThreads.acquire()
        self._blas = True

    # ------------------------------------------------------------------ backend state
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
        return getattr(self.backend, "grid_config", None)

    @property
    def nerf_config(self):
        """Density grids: the :class:`~divas_engine.fusion.NerfFusionConfig`; else None."""
        return getattr(self.backend, "nerf_config", None)

    @property
    def preset(self) -> str:
        """Density grids: the NeRF preset in use (AttributeError on surfel scenes)."""
        return self.backend.preset

    @property
    def last_mapping(self):
        """Surfel scenes: the latest voxel-to-surfel mapping result; else None."""
        return getattr(self.backend, "last_mapping", None)

    def set_ground_truth(self, values: np.ndarray) -> None:
        """Evaluation only: ground truth rendered as the oracle's target at each view."""
        v = np.asarray(values, dtype=np.float32)
        shape = self.backend.selection_shape
        if v.shape != shape:
            raise DivasInputError(
                None, f"ground-truth labels have shape {v.shape}, the scene needs {shape}"
            )
        self._gt_values = v
        from ..segment.oracle import OracleSegmenter

        if isinstance(self.segmenter, OracleSegmenter) and self.segmenter.gt_render is None:
            self.segmenter.gt_render = self._gt_render
        seg = self.segmenter
        attach = getattr(self.renderer, "attach_values", None)
        if attach is not None and isinstance(seg, OracleSegmenter):
            # the oracle renders the truth at every view it segments: composited in the
            # view's own RGB blend, its value render is read back, not blended again
            # (issue 20; bit-identical — SurfelRenderer.attach_values)
            with self._render_lock:
                attach(v if seg.gt_render == self._gt_render else None)

    def _bind_segmenter(self, segmenter: Segmenter | None) -> None:
        """A scene-aware segmenter (issue 16) gets the scene, the renderer, the camera of
        a view id and the 3D clicks of the view's object, once."""
        from ..segment.scene_aware import SceneAwareSegmenter, SceneBinding

        if isinstance(segmenter, SceneAwareSegmenter):
            segmenter.bind_scene(
                SceneBinding(
                    self.scene,
                    self._render_values,
                    self._view_camera,
                    self._object_clicks,
                    lambda: None if self.plan is None else self.plan.up,
                    self._render_sparse if hasattr(self.renderer, "render_values_sparse") else None,
                )
            )

    def _view_camera(self, view_id: Hashable) -> Camera:
        return self._views[str(view_id)].camera

    def _object_clicks(self, view_id: Hashable):
        return self._clicks_of(self.objects[self._views[str(view_id)].object_index])

    @staticmethod
    def _clicks_of(obj, new_positive: np.ndarray | None = None):
        """The object's 3D clicks as :class:`~..segment.scene_aware.ObjectClicks`, with
        ``new_positive`` a positive click not recorded yet (the click being made)."""
        from ..segment.scene_aware import ObjectClicks

        clicks = [c for cs in obj.clicks.values() for c in cs if c.point is not None]
        pts = [np.asarray(c.point, np.float64) for c in clicks]
        pos = [bool(c.positive) for c in clicks]
        if new_positive is not None:
            pts.append(np.asarray(new_positive, np.float64))
            pos.append(True)
        if not pts:
            return ObjectClicks.empty()
        return ObjectClicks(np.stack(pts), np.array(pos))

    def _gt_render(self, view_id: Hashable) -> np.ndarray:
        cam = self._views[str(view_id)].camera
        return self._render_values(cam, self._gt_values)

    # ------------------------------------------------------------------ rendering
    def _render(self, camera: Camera) -> RenderBuffers:
        from ..render.surfel_renderer import SurfelRenderer

        with self._render_lock, self.timings.measure("render"):
            r = self.renderer
            if (
                isinstance(r, SurfelRenderer)  # not a wrapper (its render takes no opt-out)
                and r.attached_values is not None
                and any(a.camera is camera for a in self.anchors)
            ):  # an anchor is never segmented: no ground-truth channel in its blend
                return r.render(camera, attached=False)
            return self.renderer.render(camera)

    def _render_values(self, camera: Camera, values: np.ndarray) -> np.ndarray:
        with self._render_lock:
            return self.renderer.render_values(camera, values)

    def _render_sparse(
        self, camera: Camera, rows: np.ndarray, values: np.ndarray, threads: int | None = None
    ) -> np.ndarray:
        """A sparse value render; beside the session's other renders (no render lock)
        where the renderer allows it (CPU: graph3d's masks while the view renders,
        issue 20)."""
        r = self.renderer
        concurrent = bool(getattr(r, "sparse_renders_concurrent", False))
        with contextlib.nullcontext() if concurrent else self._render_lock:
            if threads is None:
                return r.render_values_sparse(camera, rows, values)
            return r.render_values_sparse(camera, rows, values, threads=threads)

    def working_camera(self, camera: Camera) -> Camera:
        """``camera`` at the session's render scale."""
        s = self.config.render_scale
        return camera if s == 1.0 else camera.scaled(s)

    def _anchor_full_camera(self, camera: Camera) -> Camera:
        """An anchor's full camera: ``camera`` resized so its render's long side is
        ``config.anchor_long_side`` (unchanged when that is 0)."""
        long_side = int(self.config.anchor_long_side)
        if long_side <= 0:
            return camera
        s = self.config.render_scale
        return camera.scaled(long_side / (s * max(camera.width, camera.height)))

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
            # an anchor's own camera: its render is already there (issue 20)
            done = next((a._buffers for a in self.anchors if a.camera is cam), None)
            rgb, vid = (done.rgb if done is not None else self._render(cam).rgb), None
        with self.timings.measure("overlay"):
            cov = self._render_values(cam, self.indicator(selection))
            a = (np.clip(cov, 0.0, 1.0) * np.float32(cfg.overlay_alpha))[..., None]
            img = rgb * (1.0 - a) + np.asarray(cfg.overlay_color, np.float32) * a
        return Overlay(
            cam, cov.astype(np.float32), cov >= cfg.overlay_threshold, img.astype(np.float32), vid
        )

    def _lazy_overlays(self, view: SessionView | None):
        """``(overlay of view, next open view, its overlay)`` for the current selection,
        each overlay a callable rendered on first read (issue 20: an accept renders
        nothing the user does not look at). The selection is captured now, so a later
        accept does not change what these show."""
        sel = self._selection
        ov = nov = None
        if view is not None and view.status == ViewStatus.FUSED:
            ov = lambda: self.overlay(view, sel)  # noqa: E731
        nxt = self.next_view()
        if nxt is not None:
            nov = lambda: self.overlay(nxt, sel)  # noqa: E731
        return ov, nxt, nov

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

    def _live_views(self) -> list[SessionView]:
        return [v for v in self.current.views if v.status == ViewStatus.FUSED]

    def next_view(self) -> SessionView | None:
        """The first open (not yet accepted) centroid view of the current object."""
        return next((v for v in self.current.views if v.status == ViewStatus.OPEN), None)

    def object_selections(self) -> list[tuple[ObjectRecord, np.ndarray]]:
        """Finished objects and the current one when its selection is non-empty."""
        out = [(o, o.selection) for o in self.objects[:-1] if o.selection is not None]
        if self._selection.any():
            out.append((self.current, self._selection))
        return out

    def _update_selection(self) -> float:
        t = time.perf_counter()
        live = self._live_views()
        if not live:
            self._set_semantic(np.zeros_like(self._selection))
            return 0.0
        self._set_semantic(self.backend.selection(self.fusion.result(), live))
        dt = time.perf_counter() - t
        self.timings.add("mapping", dt)
        return dt

    def _set_semantic(self, semantic: np.ndarray) -> None:
        """The fused selection ``S``; the selection is ``S`` with the manual edits."""
        self._semantic = semantic
        self._selection = compose(semantic, self.edits, self.current.index)

    # ------------------------------------------------------------------ anchors
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
        full = self._anchor_full_camera(camera)
        a = AnchorView(
            len(self.anchors),
            self.working_camera(full),
            full,
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

    # ------------------------------------------------------------------ outputs
    def _write_objects(self, out_dir: str | PathLike) -> dict[str, Any]:
        """:meth:`~divas_engine.session.Session.export_objects` once nothing is pending."""
        from ..export import export_selection

        out = Path(out_dir)
        check_output_path(out, what="objects folder", folder=True)
        out.mkdir(parents=True, exist_ok=True)
        files: dict[str, Any] = {"objects": []}
        ext = self.backend.object_suffix()
        for o, sel in self.object_selections():
            if not sel.any():
                continue
            safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in o.name)
            p = out / f"{o.label:02d}_{safe}{ext}"
            export_selection(self.scene, sel, p)
            files["objects"].append(
                {"name": o.name, "label": o.label, "path": str(p), "count": int(sel.sum())}
            )
        files["labelled"] = str(self.backend.write_label_set(self.label_set(), out))
        return files

    def write_labelled(self, path: str | PathLike) -> Path:
        """The scene with the ``divas_label`` column (surfel scenes)."""
        return self.backend.write_labelled(self.label_set(), path)

    # ------------------------------------------------------------------ report
    def counts(self, *, wait: bool = True) -> dict[str, Any]:
        """Views by status, primitives, objects, selected / labelled, voxels.

        ``wait=False``: while the fusion state is still being built in the background
        (:meth:`Session.open`'s warm-up), do not wait for it: the voxel counts are None."""
        return session_counts(self, wait=wait)

    @property
    def warmed_up(self) -> bool:
        """The fusion state is built (reading it would not wait for the warm-up)."""
        return self.backend.ready

    def wait_warm_up(self, timeout: float | None = None) -> bool:
        """Wait for the whole background warm-up of :meth:`Session.open` — the fusion
        state, then the segmenter's per-scene state (graph3d's primitives) — for at most
        ``timeout`` seconds; whether it is done. Nothing needs to call it: every step
        waits for what it uses."""
        return self.backend.wait_warm_up(timeout)

    def report(self) -> dict[str, Any]:
        """Timings, counts, views (with rejection reasons), memory, config, seed."""
        return session_report(self)

    # ------------------------------------------------------------------ persistence
    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        return session_state(self)

    def save(self, path: str | PathLike) -> Path:
        """Write the session (JSON + ``.npz``), atomically."""
        doc, arrays = self._state()
        return save_state(path, doc, arrays)

    def _autosave(self) -> None:
        """Save to ``config.autosave`` (when set). A failure (disk full, read-only
        folder …) is a :class:`RuntimeWarning` and :attr:`autosave_error`, never an
        exception: the user's work in memory goes on; the previous save stays intact."""
        if not self.config.autosave:
            return
        try:
            self.save(self.config.autosave)
        except (OSError, DivasInputError) as e:
            self.autosave_error = str(e)
            warnings.warn(f"autosave failed: {e}", RuntimeWarning, stacklevel=2)
        else:
            self.autosave_error = None

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        wait = getattr(self.segmenter, "wait_prefetch", None)  # work a click started
        if wait is not None:
            wait(60.0)
        if self._worker is not None:
            self._worker.close()
        if self._blas:
            self._blas = False
            BlasThreads.release()

    def __enter__(self) -> SessionCore:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

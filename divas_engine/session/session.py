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
depth-weighted masks), autosaved after open, every click and every accept when
``config.autosave`` is set (one atomic unit, :mod:`.store`), and :meth:`Session.load`
replays it — re-rendering the stored camera poses and fusing
the stored masks — to identical labels, without running SAM again.

Multiple objects: :meth:`Session.finish_object` commits the selection as the next
integer label (0 = unlabelled; earlier labels are kept unless
``overwrite_labels``) and starts an empty object.

Structure: this module holds the loop steps; what differs per scene representation
(occupancy, click depth, centroid view, depth weighting, scheduling, selection, export)
is the session's :class:`~divas_engine.session.backends.SessionBackend`, picked from the
scene by the backend registry. State, rendering and outputs: :mod:`.core`; records:
:mod:`.records`; prompts and mask previews: :mod:`.masks`; save / replay:
:mod:`.persistence`; counts and the report: :mod:`.report`.

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
import time
from collections.abc import Callable, Hashable, Sequence
from os import PathLike
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError
from ..kinds import SceneKind, ViewStatus
from ..scene import Scene
from ..segment.base import Segmenter, SegResult
from ..segment.worker import SamWorker, SegmentationJobError
from ..views import Anchor, AnchorPlan, plan_scene_anchors
from ..views.centroid_common import click_point
from .backends import backend_class_for
from .config import SessionConfig
from .core import SessionCore
from .edits import SelectionEditing
from .history import SessionHistory
from .masks import TimedSegmenter, default_prompts, mask_preview, prompt_set
from .persistence import load_session
from .records import AcceptResult, AnchorClick, AnchorView, MaskPreview, ObjectRecord, SessionView

__all__ = ["Session", "anchor_plan", "scene_kind"]

_ACCEPTED = (ViewStatus.FUSED, ViewStatus.PENDING)


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


class Session(SelectionEditing, SessionCore):
    """One interactive segmentation session over a scene (module docstring): the loop
    steps, over the state, rendering and outputs of :class:`~.core.SessionCore`.

    Create with :meth:`open` (fresh) or :meth:`load` (saved session, replayed).
    Manual edits of the selection: :class:`~.edits.SelectionEditing`; undo / redo of any
    step: :attr:`history`.
    """

    @property
    def history(self) -> SessionHistory:
        """The undo / redo history of this session (:mod:`.history`); made on first use,
        with the current state as its first step. Steps are recorded by the caller
        (:meth:`SessionHistory.record`), once per user-level step."""
        if self._history is None:
            self._history = SessionHistory(self)
        return self._history

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
            segmenter: the mask source (default: the weight-free :class:`Graph3DSegmenter`).
            device: Warp device (None/"auto": CUDA when present).
            anchors: the anchors to offer instead of the planned ones — each an
                :class:`~divas_engine.views.Anchor`, a :class:`Camera`, or a
                ``(camera, source, index)`` tuple (full-resolution cameras).
            gt_values: evaluation only — ground-truth per surfel ``[N]`` (NeRF ``[D,H,W]``);
                wired into an :class:`OracleSegmenter` that has no ``gt_render``.
            render_anchors: render the first anchor now — what the user looks at first;
                the others render on first use (``AnchorView.buffers``), so opening a
                session does no work the first anchor does not need (issue 20). False:
                none now.
        """
        cfg = config or SessionConfig()
        if segmenter is None:
            from ..segment import Graph3DSegmenter

            segmenter = Graph3DSegmenter()
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
        if render_anchors and s.anchors:
            _ = s.anchors[0].buffers
        # after the fusion state, in the same background thread: the segmenter's per-scene
        # state (graph3d's primitives: seconds of the first click at 3M, issue 20)
        s.backend.warm_up(then=getattr(segmenter, "warm_up", None))
        s._autosave()  # the anchors are saved at once (issue 14)
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

    # ------------------------------------------------------------------ clicks and prompts
    def _back_project(self, anchor: AnchorView, xy) -> tuple[float, np.ndarray]:
        b = anchor.buffers
        depth = self.backend.click_depth(b)
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
                self._autosave()
                return rec
            vid = f"o{obj.index}:a{anchor.index}:c{ci}"
            on_camera = self._prefetch(anchor, xy, obj)
            t0 = time.perf_counter()
            with self._render_lock, self.timings.measure("centroid"):
                cv = self.backend.centroid_view(anchor.camera, xy, anchor.buffers, vid, on_camera)
            t1 = time.perf_counter()
        except DivasInputError as e:
            raise DivasInputError(None, f"anchor {anchor.index}: {e.problem}") from None
        buffers, handed_s = cv.take_buffers()  # the planner's first probe, when it is the view
        view = SessionView(vid, obj.index, anchor.index, ci, cv, _buffers=buffers, _session=self)
        _ = view.buffers  # rendered here otherwise
        t2 = time.perf_counter()
        view.timings = {"centroid_s": t1 - t0 - handed_s, "render_s": handed_s + t2 - t1}
        clicks.append(AnchorClick(anchor.index, ci, xy, True, cv.target.copy(), vid))
        obj.views.append(view)
        self._views[vid] = view
        self._autosave()
        return view

    def _prefetch(
        self, anchor: AnchorView, xy: tuple[float, float], obj: ObjectRecord
    ) -> Callable[[Camera], object] | None:
        """Hand the object's 3D clicks with this positive click's point (the centroid
        view's target: the same back-projection) to a segmenter that can start work for
        the view's prompt before the view is rendered (``prefetch``: graph3d's cut, issue
        20). SAM and the oracle have no such hook. A point that differs from the view's
        target only costs the unused work: the segmenter keys it by its inputs.

        Returns the callback the centroid view calls with the view's camera before
        rendering it (``prefetch_view``: graph3d's masks of the default prompt, rendered
        while the view renders), or None."""
        seg = self.segmenter
        fn = getattr(seg, "prefetch", None)
        if fn is None or not getattr(seg, "prefetch_cuts", True):
            return None  # (graph3d's switch off: nothing would start; no back-projection)
        _, point = self._back_project(anchor, xy)  # raises as the centroid view would
        clicks = self._clicks_of(obj, point)
        fn(clicks)
        view_fn = getattr(seg, "prefetch_view", None)  # (it checks its own switches)
        return None if view_fn is None else lambda camera: view_fn(camera, clicks)

    def default_prompts(self, view: SessionView | str) -> tuple[np.ndarray, np.ndarray]:
        """The click's 3D point projected into the view (positive) plus the anchor's
        visible negative clicks (negative)."""
        v = self.view(view) if isinstance(view, str) else view
        clicks = self.objects[v.object_index].clicks.get(v.anchor, [])
        return default_prompts(v, clicks, self.config.negative_occlusion_tol)

    def _prompt_set(
        self, v: SessionView, points, labels, include_default: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        p, lab = prompt_set(v, points, labels)
        if include_default:
            dp, dl = self.default_prompts(v)
            p, lab = np.concatenate([dp, p]), np.concatenate([dl, lab])
        return p, lab

    def _mask_from(
        self, v: SessionView, res: SegResult, p: np.ndarray, lab: np.ndarray, seconds: float = 0.0
    ) -> MaskPreview:
        return mask_preview(v, res, p, lab, self.config, self.backend, seconds)

    def _require_segmenter(self) -> TimedSegmenter:
        if self._seg is None:
            raise DivasInputError(None, "this session has no segmenter (pass one to open/load)")
        return self._seg

    def prompt(
        self, view: SessionView | str, points=(), labels=(), *, include_default: bool = True
    ) -> MaskPreview:
        """Mask preview for a prompt set (default prompts + ``points``), synchronous."""
        v = self._resolve(view)
        if v.status in _ACCEPTED:
            raise ValueError(f"view {v.id} is already accepted ({v.status}); undo it first")
        p, lab = self._prompt_set(v, points, labels, include_default)
        seg = self._require_segmenter()
        b = v.buffers
        t0 = time.perf_counter()
        res = seg.segment(b.rgb, b.D_ref, p, lab, view_id=v.id)
        prev = self._mask_from(v, res, p, lab, time.perf_counter() - t0)
        v.preview, v.points, v.labels, v.advice = prev, p, lab, prev.advice
        return prev

    # ------------------------------------------------------------------ accept / sync
    def _end_of_group(self, v: SessionView) -> bool:
        return not any(
            o.anchor == v.anchor and o.status == ViewStatus.OPEN and o is not v
            for o in self.current.views
        )

    def accept(
        self, view: SessionView | str, points=None, labels=None, *, include_default: bool = True
    ) -> AcceptResult:
        """Accept a view (Sec. 3.4–3.7): fuse its mask (NeRF: at the group sync).

        ``points``/``labels``: the prompt set (default: the last previewed set, else the
        default prompts). Rejected views (no positive prompt, score < 0.5, empty mask)
        are recorded with their reason and change nothing.
        """
        v = self._resolve(view)
        if v.status in _ACCEPTED:
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
        if not self.backend.asynchronous:
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
                "advice": v.advice,
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
        v.status = ViewStatus.PENDING
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
        for k, (v, prev) in enumerate(items):
            reason = prev if isinstance(prev, str) else prev.reason
            if reason is not None:
                v.status, v.reason = ViewStatus.REJECTED, reason
                v.score = float("nan") if isinstance(prev, str) else prev.score
                v.advice = None if isinstance(prev, str) else prev.advice
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
                # the views fused before stay fused and selected; this one and the rest
                # of the group go back to open (their previews kept, so a retry is cheap)
                for w, _ in items[k:]:
                    w.status, w.reason = ViewStatus.OPEN, None
                    if w.id in self.current.accept_order:
                        self.current.accept_order.remove(w.id)
                if fused:
                    self._update_selection()
                raise DivasInputError(None, str(e)) from None
            dt = time.perf_counter() - t
            self.timings.add("kernel", dt)
            kernel_s += dt
            v.status, v.reason, v.score, v.advice = ViewStatus.FUSED, None, prev.score, None
            v.mask, v.fusion_id, v.fusion_view = prev.mask, fid, fv
            fused.append(v.id)
        timings: dict[str, float] = {"kernel_s": kernel_s}
        ov = nov = nxt = None
        if fused:
            timings["mapping_s"] = self._update_selection()
            release = getattr(self.renderer, "release", None)
            for vid in fused if release is not None else ():  # segmented: binning done
                release(self._views[vid].camera)
            # overlays of this selection, rendered when first read (AcceptResult.overlay)
            ov, nxt, nov = self._lazy_overlays(view)
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

    # ------------------------------------------------------------------ undo / reset / objects
    def undo(self) -> SessionView | None:
        """Undo the last accepted view of the current object (exact); returns it, or None."""
        obj = self.current
        while obj.accept_order:
            vid = obj.accept_order.pop()
            v = self._views[vid]
            if v.status == ViewStatus.FUSED:
                with self.timings.measure("undo"):
                    self.fusion.remove_view(int(v.fusion_id))
                v.status, v.fusion_id, v.fusion_view, v.mask = ViewStatus.OPEN, None, None, None
                self._update_selection()
                self._autosave()
                return v
            if v.status == ViewStatus.PENDING:
                self._pending.remove(v)
                if self._worker is not None:
                    self._worker.forget(v.id)
                v.status = ViewStatus.OPEN
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
            self.labels = np.zeros_like(self.labels)
            for k in list(self.edits.objects):
                self.edits = self.edits.with_object(k, None)
        else:
            cur = self.current
            self.objects[-1] = ObjectRecord(cur.index, cur.label, f"object_{cur.label}")
            self.edits = self.edits.with_object(cur.index, None)
        self._set_semantic(np.zeros_like(self._selection))
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
        self.labels = np.where(take, cur.label, self.labels).astype(self.labels.dtype)
        cur.finished = True
        # open views of the finished object are dropped from the id table
        for v in cur.views:
            if v.status == ViewStatus.OPEN:
                self._views.pop(v.id, None)
        cur.views = [v for v in cur.views if v.status != ViewStatus.OPEN]
        self.fusion.reset()
        k = len(self.objects)
        self.objects.append(ObjectRecord(k, k + 1, f"object_{k + 1}"))
        self._set_semantic(np.zeros_like(self._selection))
        self._autosave()
        return cur

    # ------------------------------------------------------------------ export
    def export(self, path: str | PathLike, labels_path: str | PathLike | None = None):
        """Write the current selection in the input's format (PLY subset / masked npz grid)."""
        from ..export import export_selection

        if self._pending:
            self.sync()
        return export_selection(self.scene, self._selection, path, labels_path=labels_path)

    def export_objects(self, out_dir: str | PathLike) -> dict[str, Any]:
        """One file per object (:func:`~divas_engine.export.export_selection`) plus the label
        set: ``labelled.ply`` with ``divas_label`` (surfels) or ``labels.npy`` (NeRF grid)."""
        if self._pending:
            self.sync()
        return self._write_objects(out_dir)

    # ------------------------------------------------------------------ persistence
    #: Rebuild a saved session by replaying it (:func:`.persistence.load_session`).
    load = classmethod(load_session)

"""The interactive DivAS session: the engine API of the loop of paper Sec. 3 (no ``bpy``).

Loop (Sec. 3.1): anchors → a click spawns a centroid view (Sec. 3.3) → point prompts give a
depth-weighted SAM mask (Sec. 3.4) → accepting fuses it (Sec. 3.5) and, for 2DGS, maps voxels
to surfels (Sec. 3.6) → the selection is overlaid on the current and next view (Sec. 3.7).
Scheduling (Sec. 3.4): 2DGS segments synchronously at :meth:`Session.accept`; NeRF hands the
view to a background :class:`~divas_engine.segment.SamWorker` and fuses pending masks together
at the end of an anchor group or at ``sync_pending`` (3) masks. Pixel coordinates are in the
images the session renders (cameras scaled by ``SessionConfig.render_scale``).
:class:`Session` is the only writer of its :class:`~.state.SessionState`; reads are
:class:`~.reader.SessionReader`'s.

Not in the paper: a view whose mask holds fewer than ``min_mask_pixels`` pixels ≥ 0.5 is
rejected; every click is a 3D constraint on its object (:mod:`.corrections`: a prompt of every
view where its point is visible and the mask disagrees, and its surface patch forced in or
out); a centroid view's default prompt is the click's 3D point projected into it; multiple
objects: :meth:`Session.finish_object` commits the selection as the next integer label.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from os import PathLike
from typing import Any

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError, InputErrorCode
from ..kinds import ViewStatus
from ..scene import Scene
from ..segment.base import Rejection, Segmenter, SegResult
from ..segment.factory import SegmenterSettings, build_segmenter
from ..segment.worker import SamWorker
from ..views import Anchor
from . import clicks, fusing, negative_views, widening
from . import corrections as corr
from . import edits as edit_steps
from .config import SessionConfig
from .edits import EditLayer
from .history import SessionHistory
from .masks import TimedSegmenter, mask_preview, prompt_set
from .outputs import export_objects
from .persistence import load_session
from .reader import SessionReader, anchor_plan, scene_kind
from .records import (
    AcceptResult,
    AnchorView,
    MaskPreview,
    ObjectRecord,
    SessionView,
)
from .state import StateSnapshot

__all__ = ["Session", "anchor_plan", "scene_kind"]

_ACCEPTED = (ViewStatus.FUSED, ViewStatus.PENDING)


def _check_open(v: SessionView) -> None:
    if v.status in _ACCEPTED:
        raise DivasInputError(
            None,
            f"view {v.id} is already accepted ({v.status}); undo it first",
            code=InputErrorCode.VIEW_ACCEPTED,
            details={"view": v.id},
        )


class Session(SessionReader):
    """One interactive segmentation session over a scene (module docstring): the steps
    that change its state, over the parts and reads of :class:`~.reader.SessionReader`.

    Create with :meth:`open` (fresh) or :meth:`load` (saved session, replayed).
    """

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
            segmenter: the mask source (default: :data:`~divas_engine.segment.DEFAULT_SEGMENTER`).
            device: Warp device (None/"auto": CUDA when present).
            anchors: the anchors to offer instead of the planned ones — each an
                :class:`~divas_engine.views.Anchor`, a :class:`Camera`, or a
                ``(camera, source, index)`` tuple (full-resolution cameras).
            gt_values: evaluation only — ground truth per surfel ``[N]`` (NeRF
                ``[D,H,W]``) for a segmenter that reads it (the oracle).
            render_anchors: render the first anchor now (the others when first used).
        """
        cfg = config or SessionConfig()
        if segmenter is None:
            segmenter = build_segmenter(SegmenterSettings())
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
            s.render(s.anchors[0])
        # after the fusion state, in the same background thread: the segmenter's per-scene
        # state (graph3d's primitives: seconds of the first click at 3M)
        s.backend.warm_up(then=segmenter.warm_up)
        s.autosave()  # the anchors are saved at once
        return s

    #: Rebuild a saved session by replaying it (:func:`.persistence.load_session`).
    load = classmethod(load_session)

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

    def add_anchor(self, camera: Camera, source: str = "camera", index: int = -1) -> AnchorView:
        """Offer one more anchor — manual anchor selection (paper Sec. 1 and its
        limitations: when the planned views miss an off-centre or occluded target, the
        user picks a training camera or the current viewport).

        Args:
            camera: full-resolution camera (OpenCV convention); rendered at the session's
                ``render_scale`` when first used.
            source: ``"training"``, ``"viewport"`` or ``"camera"`` (kept in the saved
                session); index: e.g. the training-camera index.

        Returns the new :class:`AnchorView` (its ``index`` is the position to click).
        """
        if not isinstance(camera, Camera):
            raise TypeError(f"add_anchor: expected a Camera, got {type(camera).__name__}")
        a = self._new_anchor(len(self.anchors), camera, source, index)
        self.state.anchors.append(a)
        self.autosave()
        return a

    # the clicks (Sec. 3.3), each one a 3D constraint (:mod:`.corrections`): :mod:`.clicks`
    click = clicks.click
    click_view = clicks.click_view
    click_camera = clicks.click_camera
    click_point = clicks.click_point

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
        gate = self._seg is None or getattr(self._seg.seg, "score_gates_views", True)
        if negative_views.is_negative_view(self, v):
            res = negative_views.within_selection(self, v, res)  # no mask beyond the selection
        return mask_preview(
            v, self.render(v), res, p, lab, self.config, self.backend, seconds, gate
        )

    def _require_segmenter(self) -> TimedSegmenter:
        if self._seg is None:
            raise DivasInputError(None, "this session has no segmenter (pass one to open/load)")
        return self._seg

    def prompt(
        self, view: SessionView | str, points=(), labels=(), *, include_default: bool = True
    ) -> MaskPreview:
        """Mask preview for a prompt set (default prompts + ``points``), synchronous;
        with the default prompts, segmented again with the object's clicks its mask
        disagrees with (:func:`.corrections.missing_prompts`)."""
        v = self._resolve(view)
        _check_open(v)
        p, lab = self._prompt_set(v, points, labels, include_default)
        return self._prompt(v, p, lab, include_default)

    def _prompt(self, v: SessionView, p, lab, clicks: bool) -> MaskPreview:
        """The preview of ``p``/``lab``; ``clicks``: then with the object's clicks its
        mask disagrees with (:func:`.corrections.missing_prompts`)."""
        prev = self._preview(v, p, lab)
        if clicks and self.config.corrections.enabled:
            oc = self.state.object_clicks(self.objects[v.object_index])
            tol = self.config.negative_occlusion_tol
            mp, ml = corr.missing_prompts(v, oc, p, tol, self.backend.weight_reads_prompts)
            if len(mp):
                prev = self._preview(v, np.concatenate([p, mp]), np.concatenate([lab, ml]))
        prev.asked = (p, lab)
        return prev

    def _preview(self, v: SessionView, p: np.ndarray, lab: np.ndarray) -> MaskPreview:
        """Segment ``v`` with the prompt set ``p``/``lab``; kept as its preview."""
        seg = self._require_segmenter()
        ctx = self.view_context(v)
        t0 = time.perf_counter()
        res = seg.segment_view(ctx, p, lab)
        prev = self._mask_from(v, res, p, lab, time.perf_counter() - t0)
        v.preview, v.points, v.labels, v.advice = prev, p, lab, prev.advice
        return prev

    def accept(
        self, view: SessionView | str, points=None, labels=None, *, include_default: bool = True
    ) -> AcceptResult:
        """Accept a view (Sec. 3.4–3.7): fuse its mask (NeRF: at the group sync).

        ``points``/``labels``: the prompt set (default: the last previewed set, else the
        default prompts). Rejected views (no positive prompt, score < 0.5, empty mask)
        are recorded with their reason and change nothing.
        """
        v = self._resolve(view)
        _check_open(v)
        with_default = True
        if points is not None or labels is not None:
            p, lab = self._prompt_set(
                v,
                points if points is not None else (),
                labels if labels is not None else (),
                include_default,
            )
            with_default = include_default
        elif v.points is not None:
            p, lab, with_default = v.points, v.labels, False  # a preview's set, complete
        else:
            p, lab = self._prompt_set(v, (), (), True)
        v.points, v.labels = p, lab
        self.current.accept_order.append(v.id)
        t0 = time.perf_counter()
        n_seg = len(self.timings.calls("segmenter"))
        if not self.backend.asynchronous:
            prev = v.preview
            asked = None if prev is None else (prev.asked or (prev.points, prev.labels))
            same = prev is not None and any(
                np.array_equal(a, p) and np.array_equal(b, lab)
                for a, b in (asked, (prev.points, prev.labels))
            )
            if not same:
                prev = self._prompt(v, p, lab, with_default)
            result = widening.widen(self, self._fuse_group([(v, prev)], view=v))
        else:
            self._accept_async(v, p, lab)
            end_of_group = not any(
                o.anchor == v.anchor and o.status == ViewStatus.OPEN and o is not v
                for o in self.current.views
            )
            if end_of_group or len(self.state.pending) >= self.config.sync_pending:
                result = self.sync(view=v)
            else:
                result = AcceptResult(
                    v, v.status, None, [], [], len(self.state.pending), False, self.selection
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
        self.autosave()
        return result

    def _submit(self, v: SessionView, p: np.ndarray, lab: np.ndarray) -> None:
        """Hand a view to the background segmentation worker (NeRF)."""
        if self._worker is None:
            self._worker = SamWorker(
                self._require_segmenter(), asynchronous=True, sync_pending=self.config.sync_pending
            )
        self._worker.submit(self.view_context(v), p, lab)

    def _accept_async(self, v: SessionView, p: np.ndarray, lab: np.ndarray) -> None:
        self._submit(v, p, lab)
        v.status = ViewStatus.PENDING
        self.state.pending.append(v)

    def sync(self, view: SessionView | None = None) -> AcceptResult:
        """Collect every pending NeRF mask and fuse them together (no-op when none)."""
        st = self.state
        if not st.pending:
            status = None if view is None else view.status
            reason = None if view is None else view.reason
            return AcceptResult(view, status, reason, [], [], 0, False, st.selection)
        group, st.pending = st.pending, []
        t0 = time.perf_counter()
        segmented = fusing.collect(self._worker, group)
        self.timings.add("segmenter_wait", time.perf_counter() - t0)
        items: list[tuple[SessionView, MaskPreview | Rejection]] = []
        for v, res in segmented:
            if isinstance(res, Rejection):
                items.append((v, res))
                continue
            prev = self._mask_from(v, res, v.points, v.labels)
            v.preview = prev
            items.append((v, prev))
        out = widening.widen(self, self._fuse_group(items, view=view))
        out.timings["segmenter_wait_s"] = time.perf_counter() - t0 - out.timings.get("fuse_s", 0)
        return out

    def _fuse_group(self, items, view: SessionView | None) -> AcceptResult:
        """Fuse (or reject) each ``(view, preview or failure)``, then update the selection."""
        buffers = {v.id: self.render(v) for v, prev in items if isinstance(prev, MaskPreview)}
        try:
            fused, rejected, kernel_s = fusing.fuse_views(
                items, buffers, self.fusion, self.timings, self.current.accept_order
            )
        except fusing.FusedSome as e:
            if e.fused:
                self._update_selection()
            views = e.cause.max_views
            raise DivasInputError(
                None, str(e.cause), code=InputErrorCode.FUSION_FULL, details={"views": views}
            ) from None
        timings: dict[str, float] = {"kernel_s": kernel_s}
        ov = nov = nxt = None
        if fused:
            timings["mapping_s"] = self._update_selection()
            for vid in fused:  # segmented: what the renderer kept for it is done with
                self.renderer.release(self.view(vid).camera)
            ov, nxt, nov = self._lazy_overlays(view)  # rendered when first read
        elif rejected:  # a refused view's click holds (corrections.constrain)
            self.state.selection = self.state.composed()
        timings["fuse_s"] = sum(timings.values())
        return AcceptResult(
            view,
            None if view is None else view.status,
            None if view is None else view.reason,
            fused,
            rejected,
            len(self.state.pending),
            True,
            self.selection,
            ov,
            nxt,
            nov,
            timings,
        )

    def _update_selection(self) -> float:
        """The semantic selection of the fused live views (the backend's mapping)."""
        t = time.perf_counter()
        live = self.state.live_views()
        if not live:
            self.state.set_semantic(np.zeros_like(self.selection))
            return 0.0
        self.state.set_semantic(self.backend.selection(self.fusion.result(), live))
        dt = time.perf_counter() - t
        self.timings.add("mapping", dt)
        return dt

    def undo(self) -> SessionView | None:
        """Undo the last accepted view of the current object (exact), with the wider
        views its accept added (:mod:`.widening`); returns it, or None."""
        obj, changed = self.current, False
        while obj.accept_order:
            v = self.view(obj.accept_order.pop())
            wide = widening.is_wider(v.id)
            changed = changed or wide
            if v.status == ViewStatus.FUSED:
                with self.timings.measure("undo"):
                    self.fusion.remove_view(int(v.fusion_id))
                v.status, v.fusion_id, v.fusion_view, v.mask = ViewStatus.OPEN, None, None, None
                self._update_selection()
            elif v.status == ViewStatus.PENDING:
                self.state.pending.remove(v)
                if self._worker is not None:
                    self._worker.forget(v.id)
                v.status = ViewStatus.OPEN
            elif v.status == ViewStatus.REJECTED and not wide:
                # a refused accept selected its click's patch (corrections.constrain)
                v.status, v.reason, v.rejection = ViewStatus.OPEN, None, None
                self.state.selection = self.state.composed()
            elif not wide:
                continue  # an accept that changed nothing: keep looking
            if wide:  # part of the accept before it: go on to the click's own view
                widening.forget(self, v)
                continue
            self.autosave()
            return v
        if changed:
            self.autosave()
        return None

    def reset(self, all_objects: bool = False) -> None:
        """Drop the current object's views and selection (``all_objects``: every label too)."""
        st = self.state
        st.pending = []
        fusing.drain(self._worker)
        self.fusion.reset()
        dropped = st.objects if all_objects else [st.current]
        for o in dropped:
            for v in o.views:
                st.views.pop(v.id, None)
        if all_objects:
            st.objects = [ObjectRecord(0, 1, "object_1")]
            st.labels = np.zeros_like(st.labels)
            for k in list(st.edits.objects):
                st.edits = st.edits.with_object(k, None)
        else:
            cur = st.current
            st.objects[-1] = ObjectRecord(cur.index, cur.label, f"object_{cur.label}")
            st.edits = st.edits.with_object(cur.index, None)
        st.set_semantic(np.zeros_like(st.selection))
        self.autosave()

    def _sync_pending(self) -> None:
        if self.state.pending:
            self.sync()

    def finish_object(self, name: str | None = None) -> ObjectRecord:
        """Commit the current selection as the next label and start a new object."""
        self._sync_pending()
        st = self.state
        cur = st.current
        if name:
            cur.name = str(name)
        cur.selection = st.selection.copy()
        take = cur.selection if self.config.overwrite_labels else cur.selection & (st.labels == 0)
        st.labels = np.where(take, cur.label, st.labels).astype(st.labels.dtype)
        cur.finished = True
        for v in cur.views:  # open views of the finished object leave the id table
            if v.status == ViewStatus.OPEN:
                st.views.pop(v.id, None)
        cur.views = [v for v in cur.views if v.status != ViewStatus.OPEN]
        self.fusion.reset()
        st.new_object()
        st.set_semantic(np.zeros_like(st.selection))
        self.autosave()
        return cur

    @property
    def history(self) -> SessionHistory:
        """The undo / redo history (:mod:`.history`); made on first use, with the current
        state as its first step. The caller records each user-level step."""
        if self._history is None:
            self._history = SessionHistory(self)
        return self._history

    def restore(self, snapshot: StateSnapshot, *, autosave: bool = True) -> None:
        """Put the session in the state of ``snapshot`` (:meth:`SessionState.snapshot`):
        the fusion is reconciled slot by slot (exact, no render), pending views are
        forgotten or submitted again; the snapshot's selection is kept (no mapping)."""
        st = self.state
        before_fused, before_pending = fusing.slot_views(st.fused_slots()), list(st.pending)
        st.restore(snapshot)
        fusing.reconcile(self.fusion, before_fused, fusing.slot_views(st.fused_slots()))
        keep = set(map(id, st.pending))
        for v in before_pending:
            if id(v) not in keep and self._worker is not None:
                self._worker.forget(v.id)
        had = set(map(id, before_pending))
        for v in st.pending:
            if id(v) not in had:
                self._submit(v, v.points, v.labels)
        if autosave:
            self.autosave()

    def replay(self, objects: Sequence[ObjectRecord], edits: EditLayer) -> None:
        """Rebuild the state of saved ``objects`` (:mod:`.persistence`): in order, each
        one's fused views fused again in their slots (rendered again), its pending views
        segmented again, finished ones finished (their labels committed)."""
        st = self.state
        st.objects, st.views, st.edits = [], {}, edits
        for saved in objects:
            obj = ObjectRecord(saved.index, saved.label, saved.name, clicks=saved.clicks,
                               corrections=saved.corrections)  # fmt: skip
            st.objects.append(obj)
            pending = []
            for v in saved.views:
                obj.views.append(v)
                st.views[v.id] = v
                if v.status == ViewStatus.FUSED:
                    fv = fusing.fusion_view(v, v.mask, self.render(v))
                    with self.timings.measure("kernel"):
                        v.fusion_id = self.fusion.add_view(fv, int(v.fusion_id))
                    v.fusion_view = fv
                elif v.status == ViewStatus.PENDING:
                    pending.append(v)
            obj.accept_order = list(saved.accept_order)
            self._update_selection()  # the fused views (if any) with the manual edits
            for v in pending:
                self._accept_async(v, v.points, v.labels)
            if pending:
                self.sync()
            if saved.finished:
                self.finish_object(saved.name)
                st.objects.pop()  # finish_object opened the next one; the save lists it
        if not st.objects or st.objects[-1].finished:
            st.new_object()

    def apply_selection(self, new, within=None, *, autosave: bool = True) -> np.ndarray:
        """Make the current selection ``new`` by hand (a manual edit composed with the
        semantic selection, :mod:`.edits`); ``within``: only these primitives change.
        Deleted ones stay unselected. ``autosave``: False while a brush stroke goes on
        (the host saves at its end). Returns the new selection."""
        shape = self.backend.selection_shape
        new = edit_steps.check_mask(new, shape, "apply_selection")
        if within is not None:
            within = edit_steps.check_mask(within, shape, "apply_selection within")
        out = edit_steps.apply_selection(self.state, new, within)
        if autosave:
            self.autosave()
        return out

    def delete_primitives(self, mask) -> int:
        """Delete primitives: out of every selection and label from now on, and out of
        every export (the scene file is never changed). Returns how many were new."""
        m = edit_steps.check_mask(mask, self.backend.selection_shape, "delete_primitives")
        count = edit_steps.delete_primitives(self.state, m)
        self.autosave()
        return count

    def hide_primitives(self, mask) -> None:
        """Hide primitives until :meth:`reveal_primitives`; hidden ones are deselected by
        hand (a manual removal that stays, :mod:`.edits`)."""
        m = edit_steps.check_mask(mask, self.backend.selection_shape, "hide_primitives")
        edit_steps.hide_primitives(self.state, m)
        self.autosave()

    def reveal_primitives(self) -> np.ndarray:
        """Show every hidden primitive again (still deselected); the mask of them."""
        old = edit_steps.reveal_primitives(self.state)
        self.autosave()
        return np.zeros(self.backend.selection_shape, bool) if old is None else old

    def export(self, path: str | PathLike, labels_path: str | PathLike | None = None):
        """Write the current selection in the input's format (PLY subset / masked npz grid)."""
        from ..export import export_selection

        self._sync_pending()
        return export_selection(self.scene, self.selection, path, labels_path=labels_path)

    def export_objects(self, out_dir: str | PathLike) -> dict[str, Any]:
        """One file per object (:func:`~divas_engine.export.export_selection`) plus the label
        set: ``labelled.ply`` with ``divas_label`` (surfels) or ``labels.npy`` (NeRF grid)."""
        self._sync_pending()
        return export_objects(self.scene, self.backend, self.state, self.label_set(), out_dir)

"""The fusion bookkeeping of a session's views (paper Sec. 3.5): fusing a group of
accepted views into their slots, fusing a corrected view again in its slot, collecting
the background worker's masks, and reconciling the fusion with a restored state.

The fusion is fixed-point, so removing and adding views in any order gives the
accumulators of the target set bit for bit (:mod:`divas_engine.fusion.state`): a
restore reconciles slot by slot instead of fusing everything again.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..kinds import RejectReason, ViewStatus
from ..render.buffers import RenderBuffers
from ..segment.base import Rejection, SegResult
from ..segment.worker import SamWorker, SegmentationJobError
from .records import MaskPreview, SessionView
from .timing import Timings

if TYPE_CHECKING:
    from ..fusion import FusionCapacityError

__all__ = [
    "FusedSome",
    "collect",
    "drain",
    "fuse_views",
    "fusion_view",
    "reconcile",
    "refuse_view",
    "slot_views",
]


class FusedSome(Exception):
    """The fusion ran out of room in a group: ``fused`` views of the group were fused
    (they stay), the others are back to open; ``cause`` is the fusion's error."""

    def __init__(self, fused: list[str], cause: FusionCapacityError):
        super().__init__(str(cause))
        self.fused, self.cause = fused, cause


def fusion_view(v: SessionView, mask, b: RenderBuffers):
    """The :class:`~divas_engine.fusion.FusionView` of ``v`` (rendered as ``b``) with the
    depth-weighted ``mask``."""
    from ..fusion import FusionView

    return FusionView(
        v.camera, mask, b.D_min, b.D_ref, b.D_max, b.N_samp, float(v.centroid.d_cam), v.id
    )


def fuse_views(
    items: Sequence[tuple[SessionView, MaskPreview | Rejection]],
    buffers: dict[str, RenderBuffers],
    fusion,
    timings: Timings,
    accept_order: list[str],
) -> tuple[list[str], list[tuple[str, str]], float]:
    """Fuse each ``(view, preview)`` whose preview is accepted into a free slot; record
    the others as rejected (a :class:`Rejection` item: the segmentation failed). Returns
    the fused ids, the ``(id, reason)`` of the rejected ones and the kernel seconds.

    Raises:
        FusedSome: no slot left; this view and the rest of the group go back to open
            (their previews kept, so a retry is cheap; out of ``accept_order``).
    """
    from ..fusion import FusionCapacityError

    fused, rejected, kernel_s = [], [], 0.0
    for k, (v, prev) in enumerate(items):
        failed = isinstance(prev, Rejection)
        rejection = prev if failed else prev.rejection
        if rejection is not None:
            v.status, v.reason, v.rejection = ViewStatus.REJECTED, rejection.message, rejection
            v.score = float("nan") if failed else prev.score
            v.advice = None if failed else prev.advice
            rejected.append((v.id, rejection.message))
            continue
        fv = fusion_view(v, prev.mask, buffers[v.id])
        t = time.perf_counter()
        try:
            fid = fusion.add_view(fv)
        except FusionCapacityError as e:
            for w, _ in items[k:]:
                w.status, w.reason, w.rejection = ViewStatus.OPEN, None, None
                if w.id in accept_order:
                    accept_order.remove(w.id)
            raise FusedSome(fused, e) from None
        dt = time.perf_counter() - t
        timings.add("kernel", dt)
        kernel_s += dt
        v.status, v.reason, v.rejection = ViewStatus.FUSED, None, None
        v.score, v.advice = prev.score, prev.advice  # an unsure fused view keeps it
        v.mask, v.fusion_id, v.fusion_view = prev.mask, fid, fv
        fused.append(v.id)
    return fused, rejected, kernel_s


def refuse_view(v: SessionView, prev: MaskPreview, b: RenderBuffers, fusion, timings: Timings):
    """Fuse the fused view ``v`` again, in its own slot, with the corrected ``prev``
    (rendered as ``b``): its old fusion view removed, the new one added (exact: the
    fusion is fixed-point). A rejected ``prev`` takes the view out of the fusion
    (``REJECTED``, with its reason). Returns the kernel seconds."""
    slot = int(v.fusion_id)
    t = time.perf_counter()
    fusion.remove_view(slot)
    rejection = prev.rejection
    if rejection is None:
        fv = fusion_view(v, prev.mask, b)
        fusion.add_view(fv, slot)
        v.mask, v.fusion_view, v.score, v.advice = prev.mask, fv, prev.score, prev.advice
    else:
        v.status, v.reason, v.rejection = ViewStatus.REJECTED, rejection.message, rejection
        v.mask, v.fusion_id, v.fusion_view, v.score = None, None, None, prev.score
    dt = time.perf_counter() - t
    timings.add("kernel", dt)
    return dt


def collect(
    worker: SamWorker | None, group: Sequence[SessionView]
) -> list[tuple[SessionView, SegResult | Rejection]]:
    """The worker's result for each view of ``group``, or why there is none."""
    results: dict = {}
    failures: dict = {}
    try:
        results = worker.sync() if worker is not None else {}
    except SegmentationJobError as e:
        results, failures = dict(e.results), dict(e.failures)
    out: list[tuple[SessionView, SegResult | Rejection]] = []
    for v in group:
        res = results.get(v.id)
        if res is None and worker is not None:
            res = worker.result(v.id)
        if res is None:
            cause = failures.get(v.id)
            if cause:
                out.append((v, Rejection(RejectReason.SEGMENTATION_FAILED, cause=str(cause))))
            else:
                out.append((v, Rejection(RejectReason.SEGMENTATION_MISSING)))
        else:
            out.append((v, res))
    return out


def drain(worker: SamWorker | None) -> None:
    """Wait for the worker's jobs and drop their results (a reset)."""
    if worker is not None:
        with contextlib.suppress(SegmentationJobError):
            worker.sync()


def slot_views(views: dict[int, SessionView]) -> dict[int, object]:
    """The fusion view of each slot (what :func:`reconcile` compares)."""
    return {slot: v.fusion_view for slot, v in views.items()}


def reconcile(fusion, before: dict[int, object], target: dict[int, object]) -> None:
    """Make the fusion hold the ``target`` fusion views by slot (:func:`slot_views`),
    from ``before``: the ones fused now but not in the target are removed, the target's
    missing ones fused again in their own slots (a view fused again after a correction
    is a new fusion view in the same slot)."""
    for slot, fv in before.items():
        if target.get(slot) is not fv and slot in fusion.view_ids:
            fusion.remove_view(slot)
    for slot, fv in target.items():
        if before.get(slot) is not fv and slot not in fusion.view_ids:
            fusion.add_view(fv, slot)
    if sorted(fusion.view_ids) != sorted(target):  # never expected; rebuild to be exact
        fusion.reset()
        for slot, fv in target.items():
            fusion.add_view(fv, slot)

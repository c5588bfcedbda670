"""A view of a negative click that no view of its object sees (beyond the paper).

A negative click prompts every view of its object where its 3D point is visible
(:mod:`.corrections`). When none is — the spill lies behind the object in every fused
view, so no mask ever held it and no mask can drop it: the fusion put it there from hidden
evidence, or the 3DGS completion filled it — the click could only force its own surface
patch out, and the rest of the spill stayed. Yet the user saw the spill: the anchor they
clicked shows it. So the session fuses one more view of the object, the centroid view of
the click (alg:centroid-gs, as a positive click spawns: the click's neighbourhood framed
from the anchor's side, close enough for a mask of thin parts — a view at the anchor's
distance blurs a wheel's spokes into the wall between them). Its prompts are the
object's clicks visible in it, each with its own label (this click negative); it needs
one positive among them (the object is in sight, and an image segmenter has a positive
prompt), so when it shows none the view moves back along the same ray by the widening
factor (:class:`~.config.WideningConfig`), up to the anchor's own distance; with none
even there, no view is made. A negative click's view holds no mask beyond the
selection: each time it is segmented, its masks are limited to what the selection
covers in it (:func:`within_selection`). Fused like any view, it holds the spill outside its mask
where it sees it, which weighs against the hidden evidence that made it. An ordinary
session view (``o<object>:a<anchor>:c<click>``, the id a positive click's view would
have, named in the click's record): saved, re-segmented by later corrections, widened
when its mask runs off the image, restored by history, undone by
:meth:`~.session.Session.undo`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DivasInputError, InputErrorCode
from ..kinds import ViewStatus
from ..segment.base import SegResult
from ..views.centroid_common import build_pose
from .corrections import visible_pixels
from .records import AcceptResult, AnchorClick, SessionView
from .widening import forget

if TYPE_CHECKING:
    from .session import Session

__all__ = [
    "is_negative_view",
    "within_selection",
    "seen_by_a_view",
    "negative_view",
    "view_prompts",
    "fuse_negative_view",
]

#: the statuses of views whose masks are or will be fused
_LIVE = (ViewStatus.FUSED, ViewStatus.PENDING, ViewStatus.OPEN)


def is_negative_view(session: Session, view: SessionView) -> bool:
    """Whether ``view`` is a negative click's view (or a wider view of one): the click
    it belongs to is negative."""
    clicks = session.objects[view.object_index].clicks.get(view.anchor, ())
    return 0 <= view.click < len(clicks) and not clicks[view.click].positive


def within_selection(session: Session, view: SessionView, res: SegResult) -> SegResult:
    """``res`` with its masks limited to what the selection covers in ``view`` (its
    render ≥ 0.5): a negative click takes away, so its view holds no more — where
    its mask holds more than the selection, that is the segmenter's spill (a SAM-like
    mask bleeding between a wheel's spokes), not the user's."""
    cam = view.camera
    sel = np.asarray(session.selection, np.float32)
    cov = session.renderer.render_values(cam, sel).reshape(cam.height, cam.width) >= 0.5
    masks = np.asarray(res.masks, np.float32) * cov[None].astype(np.float32)
    return replace(res, masks=masks)


def seen_by_a_view(session: Session, point: np.ndarray) -> bool:
    """Whether a fused, pending or open view of the current object, rendered, shows
    ``point`` on its surface (:func:`~.corrections.visible_pixels`)."""
    tol = session.config.negative_occlusion_tol
    p = np.asarray(point, np.float64).reshape(1, 3)
    return any(
        v.status in _LIVE
        and v.buffers is not None
        and bool(visible_pixels(v.camera, v.buffers.D_ref, p, tol)[1][0])
        for v in session.current.views
    )


def negative_view(
    session: Session, rec: AnchorClick
) -> tuple[SessionView, np.ndarray, np.ndarray] | None:
    """The view of negative anchor click ``rec`` (module docstring), rendered, with its
    prompts ``([K,2] pixels, [K] labels)``; None when it needs none (the object has no
    fused view, or a view of it sees the point) or can have none (no positive click
    of the object is visible from there). Not added to the session."""
    obj = session.current
    if rec.positive or rec.point is None or not session.config.corrections.negative_views:
        return None
    if not any(v.status == ViewStatus.FUSED for v in obj.views):
        return None  # nothing selected by views yet: nothing for a view to correct
    if seen_by_a_view(session, rec.point):
        return None
    vid = f"o{obj.index}:a{rec.anchor}:c{rec.index}"
    if vid in session.state.views:
        return None
    anchor = session.anchor(rec.anchor)
    try:
        with session.rendering.lock, session.timings.measure("centroid"):
            b = session.render(anchor)
            cv = session.backend.centroid_view(anchor.camera, rec.xy, b, vid, None)
    except DivasInputError:
        return None  # no surface under the click at the planner's depth
    buffers, _ = cv.take_buffers()
    view = SessionView(vid, obj.index, rec.anchor, rec.index, cv, buffers=buffers)
    points, labels = view_prompts(session, view)
    # no positive click in sight: farther back along the same ray (as a wider view),
    # up to the anchor's own distance
    reach = float(np.linalg.norm(cv.target - anchor.camera.center))
    direction = (cv.target - anchor.camera.center) / max(reach, 1e-300)
    r, factor = cv.d_cam, float(session.config.widening.factor)
    near = session.config.view.near_fraction
    while not labels.any() and r < reach * (1.0 - 1e-9):
        r = min(r * factor, reach)
        cam = build_pose(anchor.camera, cv.target, direction, r, vid, near)
        wide = replace(cv, camera=cam, d_cam=r, strategy=f"{cv.strategy}+wider", _buffers=None)
        view = SessionView(vid, obj.index, rec.anchor, rec.index, wide)
        points, labels = view_prompts(session, view)
    if not labels.any():
        return None
    return view, points, labels


def view_prompts(session: Session, view: SessionView) -> tuple[np.ndarray, np.ndarray]:
    """The default prompts of a negative click's view: its object's clicks visible
    there, ``([K,2] pixels, [K] labels)`` (the view rendered here when it is not)."""
    session.render(view)
    clicks = session.state.object_clicks(session.objects[view.object_index])
    tol = session.config.negative_occlusion_tol
    uv, ok = visible_pixels(view.camera, view.buffers.D_ref, clicks.points, tol)
    return uv[ok].astype(np.float64), clicks.positive[ok].astype(np.int64)


def fuse_negative_view(session: Session, rec: AnchorClick) -> AcceptResult | None:
    """Add and accept the view of negative anchor click ``rec`` when it needs one
    (:func:`negative_view`); its accept's result, or None. A full fusion leaves the
    click as it was (the view is dropped)."""
    made = negative_view(session, rec)
    if made is None:
        return None
    view, points, labels = made
    session.state.add_view(view)
    rec.view_id = view.id
    try:
        return session.accept(view, points, labels, include_default=False)
    except DivasInputError as e:
        if e.code != InputErrorCode.FUSION_FULL:
            raise
        forget(session, view)  # no slot left: the click stays a patch
        order = session.current.accept_order
        if order and order[-1] == view.id:
            order.pop()
        rec.view_id = None
        return None

"""Wider views of an object the centroid view cuts off (beyond the paper).

The paper frames a centroid view on the click's neighbourhood (alg:centroid-gs: R_phys, the
P90 lateral extent of the opaque surfels near the click, then the occlusion probes), which
suits an object about the size of that neighbourhood. A click on a large object — a
ribcage that fills the anchor, a sofa, a car — gets a close-up of a patch of it, and the
fusion can only select what that close-up shows: the user clicked the object and got a
patch.

So after a view is fused the session reads its mask's border: when the mask (≥ 0.5) covers
more than τ_b (:attr:`~.config.WideningConfig.border_fraction`) of the image's border
pixels — or, when the segmenter renders its masks from a 3D selection (graph3d), when
more than τ_o (``outside_fraction``) of that selection's opacity lies out of the image
and no other view of the object shows it (a thin part leaving the view covers little
border: a close-up of a guitar's headstock with the rest of the guitar below it) — the
object runs out of the view, and the session fuses one more view of the same
click — the same look-at point x_w (the click's 3D point) and direction, ``factor`` times
as far, never past the anchor's own distance to x_w (at that distance the view is the
anchor turned to centre the click). Its prompts are the view's defaults (x_w projected,
the object's negative clicks visible there, the corrections' missing prompts), as for any
centroid view; when its mask is cut off too, it widens again, at most ``max_views`` per
click. A wider view is an ordinary session view (``<click's view id>:w<k>``): saved,
re-segmented by corrections and restored by history like the others; undoing an accept
undoes the wider views it added with it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import DivasInputError, InputErrorCode
from ..kinds import ViewStatus
from ..views.centroid_common import CentroidView, build_pose
from .corrections import visible_pixels
from .records import AcceptResult, SessionView

if TYPE_CHECKING:
    from .session import Session

__all__ = [
    "border_fraction",
    "cut_off",
    "unseen_outside",
    "widened_from",
    "is_wider",
    "wider_view",
    "widen",
    "forget",
]

#: the id tag of a wider view: ``<view id>:w<k>``
WIDE_TAG = ":w"
#: the centroid strategy recorded for a wider view
WIDENED = "widened"


def border_fraction(mask: np.ndarray) -> float:
    """The fraction of an image's border pixels (each counted once) where ``mask`` ≥ 0.5."""
    m = np.asarray(mask) >= 0.5
    if m.ndim != 2 or min(m.shape) < 3:
        return float(m.mean()) if m.size else 0.0
    edge = np.concatenate([m[0], m[-1], m[1:-1, 0], m[1:-1, -1]])
    return float(edge.mean())


def cut_off(session: Session, view: SessionView) -> bool:
    """Whether the object runs out of fused ``view``: its mask covers more than τ_b of
    the image's border, or more than τ_o of the segmenter's 3D selection behind the mask
    is out of the view's image and shown by no other view of the object
    (:func:`unseen_outside`; :class:`~.config.WideningConfig`)."""
    cfg = session.config.widening
    if border_fraction(view.mask) > cfg.border_fraction:
        return True
    share = unseen_outside(session, view)
    return share is not None and share > cfg.outside_fraction


def unseen_outside(session: Session, view: SessionView) -> float | None:
    """The opacity share of the segmenter's 3D selection behind ``view``'s mask
    (:meth:`~..segment.base.Segmenter.rendered_selection`) that projects outside
    ``view``'s image and that no other view of the object shows: visible (within
    ``negative_occlusion_tol`` of its D_ref) inside a fused view's mask, or visible in
    an open view (one the user has yet to accept). What no view shows, the fusion cannot
    select; what is hidden behind the object in this view, a wider view would not show
    either, so only the part out of the image counts. None for an image segmenter."""
    sel = session.segmenter.rendered_selection(view.id, session.config.mask_channel)
    if sel is None:
        return None
    pts, mass = sel
    total = float(mass.sum())
    if total <= 0.0:
        return 0.0
    uv, z = view.camera.project(pts)
    unseen = ~view.camera.in_image(uv, z)
    tol = session.config.negative_occlusion_tol
    for other in session.objects[view.object_index].views:
        if other is view or other.buffers is None or not unseen.any():
            continue
        if other.status == ViewStatus.FUSED and other.mask is not None:
            mask = np.asarray(other.mask) >= 0.5
        elif other.status == ViewStatus.OPEN:
            mask = None  # to be accepted: what it sees, it will fuse
        else:
            continue
        left = np.flatnonzero(unseen)
        px, vis = visible_pixels(other.camera, other.buffers.D_ref, pts[left], tol)
        if mask is not None:
            hit = np.flatnonzero(vis)
            vis[hit] = mask[px[hit, 1].astype(np.int64), px[hit, 0].astype(np.int64)]
        unseen[left[vis]] = False
    return float(mass[unseen].sum()) / total


def widened_from(view_id: str) -> tuple[str, int]:
    """``(id of the click's own view, k)`` of a view id: k wider views deep (0: not one)."""
    head, sep, tail = view_id.rpartition(WIDE_TAG)
    if sep and tail.isdigit() and head:
        return head, int(tail)
    return view_id, 0


def is_wider(view_id: str) -> bool:
    """Whether ``view_id`` names a wider view (one the session added, not a click's own)."""
    return widened_from(view_id)[1] > 0


def wider_view(session: Session, view: SessionView) -> SessionView | None:
    """The next wider view of a fused ``view`` whose mask runs off its image (module
    docstring), not yet added to the session; None when it needs none or can have none."""
    cfg = session.config.widening
    if not cfg.enabled or view.status != ViewStatus.FUSED or view.mask is None:
        return None
    root, k = widened_from(view.id)
    if k >= int(cfg.max_views) or not cut_off(session, view):
        return None
    anchor = session.anchor(view.anchor).camera
    cv = view.centroid
    reach = float(np.linalg.norm(cv.target - anchor.center))
    r = min(cv.d_cam * cfg.factor, reach)
    vid = f"{root}{WIDE_TAG}{k + 1}"
    if not r > cv.d_cam * (1.0 + 1e-6) or vid in session.state.views:
        return None  # already as far as the anchor, or already widened
    direction = (cv.target - anchor.center) / reach
    cam = build_pose(anchor, cv.target, direction, r, vid, session.config.view.near_fraction)
    wide = CentroidView(
        cam, r, cv.target.copy(), cv.click, cv.depth, None, WIDENED, cv.r_init, cv.neighbours
    )
    return SessionView(vid, view.object_index, view.anchor, view.click, wide)


def widen(session: Session, result: AcceptResult) -> AcceptResult:
    """Fuse the wider views the views ``result`` fused need (each accepted like any view,
    so it widens in turn); ``result`` with their ids, rejections and the new selection."""
    added = False
    for vid in list(result.fused):
        wide = wider_view(session, session.view(vid))
        if wide is None:
            continue
        session.state.add_view(wide)
        try:
            sub = session.accept(wide)
        except DivasInputError as e:
            if e.code != InputErrorCode.FUSION_FULL:
                raise
            forget(session, wide)  # no slot left: the click's own view stays fused
            break
        added = True
        result.fused += [x for x in sub.fused if x not in result.fused]
        result.rejected += [x for x in sub.rejected if x not in result.rejected]
        result.pending = sub.pending
        result.synced = result.synced or sub.synced
    if added:
        result.selection = session.selection
        ov, nxt, nov = session._lazy_overlays(result.view)
        result.overlay_source, result.next_view, result.next_overlay_source = ov, nxt, nov
    return result


def forget(session: Session, view: SessionView) -> None:
    """Drop a wider view that holds nothing (unfused, or undone) from the session."""
    obj = session.objects[view.object_index]
    if view in obj.views:
        obj.views.remove(view)
    session.state.views.pop(view.id, None)

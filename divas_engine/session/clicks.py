"""The click steps of a session: a click on an anchor (the paper's, Sec. 3.3: a
positive one spawns a centroid view), on a centroid view, through any camera, or a world
point — each one also a 3D constraint of its object (:mod:`.corrections`, beyond the
paper), made by :func:`correct`.

These are :class:`~divas_engine.session.Session` methods (bound in its class, as
``Session.load`` is): they change the session's state like its other steps, and only
from there.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..camera import Camera
from ..errors import DivasInputError, InputErrorCode
from ..kinds import ClickOrigin, ViewStatus
from ..render.buffers import RenderBuffers
from ..views.centroid_common import click_point as back_project
from . import corrections as corr
from . import edits as edit_steps
from . import fusing, negative_views
from .records import (
    AnchorClick,
    AnchorView,
    ClickSource,
    Correction,
    CorrectionResult,
    ObjectRecord,
    SessionView,
)

if TYPE_CHECKING:
    from .session import Session

__all__ = ["click", "click_view", "click_camera", "click_point", "correct"]


def _back_project(self: Session, anchor: AnchorView, xy) -> tuple[float, np.ndarray]:
    b = self.render(anchor)
    depth = self.backend.click_depth(b)
    front = self.backend.click_depth_at(anchor.camera, xy, b)
    min_alpha = self.config.view.min_alpha_click
    return back_project(anchor.camera, xy, depth, b.alpha, min_alpha, front)


def click(self: Session, anchor_index: int, xy, positive: bool = True) -> SessionView | AnchorClick:
    """A click on an anchor (pixels of the anchor render), also a 3D constraint
    (:mod:`.corrections`; its outcome in :attr:`last_correction`).

    Positive: spawns, renders and returns the centroid view (Sec. 3.3). Negative:
    records an extra negative prompt of the object's views and returns the
    :class:`AnchorClick`.

    Raises:
        DivasInputError: outside the image, or no surface under the click.
    """
    anchor = self.anchor(anchor_index)
    xy = (float(xy[0]), float(xy[1]))
    obj = self.current
    clicks = obj.clicks.setdefault(anchor.index, [])
    ci = len(clicks)
    source = ClickSource(ClickOrigin.ANCHOR, xy, anchor.index, ci)
    constrained = self.config.corrections.enabled
    try:
        if not positive:
            depth, point = _back_project(self, anchor, xy)
            rec = AnchorClick(anchor.index, ci, xy, False, point)
            clicks.append(rec)
            if constrained:
                before = self.state.selection  # replaced, never written, by the steps
                res = correct(self, point, anchor.camera, depth, source, False)
                _negative_view(self, rec, res, before)
            self.autosave()
            return rec
        vid = f"o{obj.index}:a{anchor.index}:c{ci}"
        on_camera = _prefetch(self, anchor, xy, obj)
        t0 = time.perf_counter()
        with self.rendering.lock, self.timings.measure("centroid"):
            b = self.render(anchor)
            cv = self.backend.centroid_view(anchor.camera, xy, b, vid, on_camera)
        t1 = time.perf_counter()
    except DivasInputError as e:
        raise DivasInputError(
            None, f"anchor {anchor.index}: {e.problem}", code=e.code, details=e.details
        ) from None
    buffers, handed_s = cv.take_buffers()  # the planner's first probe, when it is the view
    view = SessionView(vid, obj.index, anchor.index, ci, cv, buffers=buffers)
    self.render(view)  # rendered here when the planner's probe is not the view
    t2 = time.perf_counter()
    view.timings = {"centroid_s": t1 - t0 - handed_s, "render_s": handed_s + t2 - t1}
    clicks.append(AnchorClick(anchor.index, ci, xy, True, cv.target.copy(), vid))
    self.state.add_view(view)
    if constrained:
        correct(self, cv.target, anchor.camera, cv.depth, source, True, spawned=view)
    self.autosave()
    return view


def _negative_view(
    self: Session, rec: AnchorClick, res: CorrectionResult, before: np.ndarray
) -> None:
    """Fuse the view of a negative anchor click no view of its object sees
    (:mod:`.negative_views`); the click's correction result ``res`` then counts it among
    the views the click changed, with the selection delta from ``before`` the click."""
    acc = negative_views.fuse_negative_view(self, rec)
    if acc is None:
        return
    after = self.state.selection
    res.resegmented.append(acc.view.id)
    res.view = acc.view
    res.added = np.flatnonzero(after & ~before)
    res.removed = np.flatnonzero(before & ~after)
    res.selection = after
    for k in ("segmenter_s", "update_s"):
        res.timings[k] = res.timings.get(k, 0.0) + float(acc.timings.get(k, 0.0))


def _prefetch(
    self: Session, anchor: AnchorView, xy: tuple[float, float], obj: ObjectRecord
) -> Callable[[Camera], object] | None:
    """Hand the object's 3D clicks with this click's point (the view's target) to a
    segmenter that starts work before the view renders (:meth:`Segmenter.prefetch`);
    the callback the centroid view calls with its camera (``prefetch_view``), or None."""
    seg = self.segmenter
    if not seg.prefetches:
        return None  # nothing would start: no back-projection
    _, point = _back_project(self, anchor, xy)  # raises as the centroid view would
    clicks = self.state.object_clicks(obj, point)
    seg.prefetch(clicks)
    return lambda camera: seg.prefetch_view(camera, clicks)


def click_view(
    self: Session, view: SessionView | str, xy, positive: bool = True
) -> CorrectionResult:
    """A click on a centroid view (pixels of its render), accepted or not: a correction
    (:mod:`.corrections`); on an open view it is also a prompt point of that view.

    Raises:
        DivasInputError: outside the image, no surface under the click, a view of a
            finished object, or corrections off.
    """
    v = self._resolve(view)
    depth, point = _surface_point(self, v.camera, self.render(v), xy, f"view {v.id}")
    src = ClickSource(ClickOrigin.VIEW, (float(xy[0]), float(xy[1])), view=v.id)
    res = correct(self, point, v.camera, depth, src, positive, own=v)
    self.autosave()
    return res


def click_camera(
    self: Session, camera: Camera, xy, positive: bool = True, *, full_camera: bool = True
) -> CorrectionResult:
    """A click through any camera, e.g. a free 3D view (pixels of ``camera``; rendered at
    the session's scale when ``full_camera``): a correction that spawns nothing.

    Raises:
        DivasInputError: outside the image, no surface under the click, or corrections off.
    """
    cam = self.working_camera(camera) if full_camera else camera
    if cam is not camera:
        xy = camera.pixels_to(cam, (float(xy[0]), float(xy[1])))
    b = self.rendering.render_camera(cam, segmented=False)
    depth, point = _surface_point(self, cam, b, xy, "the camera")
    src = ClickSource(ClickOrigin.CAMERA, (float(xy[0]), float(xy[1])), camera=cam)
    res = correct(self, point, cam, depth, src, positive)
    self.autosave()
    return res


def click_point(
    self: Session, point, positive: bool = True, radius: float | None = None
) -> CorrectionResult:
    """A world point as a click. ``radius``: the patch radius in world units (default:
    ``patch_px`` pixels at its depth in the first view or anchor that shows it).

    Raises:
        DivasInputError: not a finite point, no rendered view shows it (and no
            ``radius``), or corrections off.
    """
    p = np.asarray(point, np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise DivasInputError(None, f"a world point needs 3 finite numbers, got {point!r}")
    cam, depth = None, None
    tol = self.config.negative_occlusion_tol
    for r in [*self.current.views, *self.anchors]:
        if r.buffers is not None and corr.visible_pixels(r.camera, r.buffers.D_ref, p, tol)[1][0]:
            cam, depth = r.camera, float(r.camera.project(p[None])[1][0])
            break
    if radius is None and cam is None:
        raise DivasInputError(
            None,
            "no rendered view sees the point: pass its patch radius",
            code=InputErrorCode.NO_SURFACE,
            details={"point": p.tolist()},
        )
    res = correct(self, p, cam, depth, ClickSource(ClickOrigin.POINT), positive, radius)
    self.autosave()
    return res


def _surface_point(
    self: Session, camera: Camera, b: RenderBuffers, xy, what: str
) -> tuple[float, np.ndarray]:
    """The depth and 3D point under pixel ``xy`` of a render (``what`` names it in an
    error)."""
    try:
        min_alpha = self.config.view.min_alpha_click
        front = self.backend.click_depth_at(camera, xy, b)
        return back_project(camera, xy, self.backend.click_depth(b), b.alpha, min_alpha, front)
    except DivasInputError as e:
        problem = f"{what}: {e.problem}"
        raise DivasInputError(None, problem, code=e.code, details=e.details) from None


def correct(
    self: Session,
    point,
    camera: Camera | None,
    depth: float | None,
    source: ClickSource,
    positive: bool,
    radius: float | None = None,
    *,
    own: SessionView | None = None,
    spawned: SessionView | None = None,
) -> CorrectionResult:
    """The click at ``point`` (seen by ``camera`` at ``depth``, which give the patch
    radius unless ``radius``) as a constraint of the current object
    (:mod:`.corrections`): its patch, the views it prompts segmented and fused again,
    the selection composed. ``own``: the view clicked on; ``spawned``: the view a
    positive anchor click spawned (not prompted: the click is its default prompt)."""
    cfg = self.config.corrections
    if not cfg.enabled:
        raise DivasInputError(None, "corrections are off in this session's config")
    t0 = time.perf_counter()
    st, obj = self.state, self.current
    before = st.selection
    if radius is None:
        radius = corr.patch_radius(camera, depth, cfg.patch_px)
    sigmas = cfg.positive_sigmas if positive else cfg.negative_sigmas
    point = np.array(point, np.float64)
    patch = self.backend.click_patch(point, float(radius), sigmas)
    share = cfg.positive_pixel_share if positive else cfg.negative_pixel_share
    if share > 0 and camera is not None and source.xy:
        drawn = self.backend.pixel_weights(camera, source.xy)
        if drawn is not None:
            rows, w, centres = drawn
            near = np.linalg.norm(centres - point, axis=1)
            patch = corr.pixel_patch(patch, rows, w, near, share, positive)
    views = [v for v in obj.views if v is not spawned]
    tol, reads = self.config.negative_occlusion_tol, self.backend.weight_reads_prompts
    plan = corr.prompt_plan(views, point, positive, tol, reads, own=own)
    c = Correction(
        len(obj.corrections),
        bool(positive),
        point,
        float(radius),
        patch,
        source,
        tuple(v.id for v, _ in plan),
        None if spawned is None else spawned.id,
    )
    obj.corrections.append(c)
    edit_steps.yield_to_click(st, corr.flat_mask(patch, before.shape), positive)
    refused, rejected, timings = _resegment(self, plan, positive)
    if refused or rejected:
        timings["mapping_s"] = self._update_selection()
    else:
        st.selection = st.composed()
    after = st.selection
    timings["update_s"] = time.perf_counter() - t0
    added, removed = np.flatnonzero(after & ~before), np.flatnonzero(before & ~after)
    ids = [v.id for v, _ in plan]
    res = CorrectionResult(c, ids, refused, rejected, added, removed, after, spawned, timings)
    self.last_correction = res
    self.updates.append({"correction": c.index, "views": res.views_changed, **timings})
    return res


def _resegment(
    self: Session, plan, positive: bool
) -> tuple[list[str], list[tuple[str, str]], dict[str, float]]:
    """Segment each ``(view, pixel)`` of a correction's plan again with the click added
    to its prompts: fused views fused again in their slots (:func:`.fusing.refuse_view`),
    pending ones submitted again, previewed ones previewed. Returns the ids fused again,
    the ``(id, reason)`` of fused views the new mask rejects, and the seconds by stage."""
    refused, rejected = [], []
    seg_s = kernel_s = 0.0
    for v, xy in plan:
        base = (v.points, v.labels) if v.points is not None else self.default_prompts(v)
        p, lab = corr.with_prompt(*base, xy, positive)
        if v.status == ViewStatus.PENDING:
            v.points, v.labels = p, lab
            self._submit(v, p, lab)
            continue
        prev = self._preview(v, p, lab)
        seg_s += prev.seconds
        if v.status == ViewStatus.FUSED:
            kernel_s += fusing.refuse_view(v, prev, self.render(v), self.fusion, self.timings)
            if v.status == ViewStatus.FUSED:
                refused.append(v.id)
            else:
                rejected.append((v.id, v.reason))
    return refused, rejected, {"segmenter_s": seg_s, "kernel_s": kernel_s}

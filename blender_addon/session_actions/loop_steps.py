"""The steps of the interactive loop on a live session: add an anchor, click (on an
anchor, or anywhere in a 3D view), add a prompt point, correct an accepted view,
accept, sync, undo, reset, finish the object.

Every click is also a correction of the selection (a 3D constraint,
:mod:`divas_engine.session.corrections`): the points' selection is written in the same
step, so the viewport shows it at once, and the step's record says how many views it
changed (the panel shows it).

Each makes one engine call on the session and then updates what Blender shows: the
cameras' images (:mod:`.view_cameras`) and the points' selection (:mod:`.points`). Pixel
coordinates are rendered-image pixels (the camera × render scale) unless a function
says otherwise.
"""

from __future__ import annotations

import time

import numpy as np

from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.kinds import ViewStatus
from divas_engine.session.negative_views import is_negative_view
from divas_engine.session.widening import is_wider
from divas_engine.viewport import OrthographicViewError, camera_from_region, region_click_pixel

from ..session_registry import LiveSession
from .points import write_selection
from .start import training_camera_objects
from .view_cameras import (
    camera_target,
    ensure_background,
    make_anchor_camera,
    prune_view_cameras,
    scene_camera_of,
    show_anchor,
    show_view,
    world_to_scene_camera,
)

__all__ = [
    "full_to_session_xy",
    "add_anchor",
    "viewport_camera",
    "viewport_click",
    "click",
    "correct_view",
    "correction_summary",
    "add_prompt",
    "refresh_preview",
    "accept",
    "sync",
    "undo",
    "reset",
    "finish_object",
]


def full_to_session_xy(live: LiveSession, anchor: int, xy) -> tuple[float, float]:
    """A full-camera pixel of anchor ``anchor`` in its rendered image (as ``divas segment``
    converts the prompts file)."""
    a = live.session.anchor(anchor)
    x, y = a.full_camera.pixels_to(a.camera, (float(xy[0]), float(xy[1])))
    return float(x), float(y)


def add_anchor(context, obj, live: LiveSession, cam_obj) -> int:
    """Manual anchor selection: ``cam_obj`` (a training camera, or any camera the user
    placed, e.g. aligned to the viewport with Ctrl+Alt+Numpad 0) becomes the session's
    next anchor, with its own anchor camera; returns its index."""
    if cam_obj is None or cam_obj.type != "CAMERA":
        raise DivasInputError(
            None, "Select a camera object first (make it active), then Add Camera as Anchor"
        )
    if cam_obj.name in live.anchor_cameras or cam_obj.name in live.view_cameras.values():
        raise DivasInputError(
            None,
            f"{cam_obj.name!r} is already one of this session's anchor or view cameras: "
            "click the object on it directly",
        )
    training = [o.name for o in training_camera_objects()]
    source_name, index = (
        ("training", training.index(cam_obj.name)) if cam_obj.name in training else ("camera", -1)
    )
    t0 = time.perf_counter()
    cam = scene_camera_of(obj, cam_obj, context.scene)
    a = live.session.add_anchor(cam, source_name, index)
    make_anchor_camera(context, obj, live, a.index)
    show_anchor(context, live, a.index)
    live.record(
        {"what": f"anchor {a.index} from {cam_obj.name}", "update_s": time.perf_counter() - t0}
    )
    return a.index


def viewport_camera(obj, view_matrix, window_matrix, region_size) -> Camera:
    """The exact camera of a 3D-view region (:func:`divas_engine.viewport.camera_from_region`)
    in ``obj``'s scene frame."""
    try:
        cam = camera_from_region(view_matrix, window_matrix, region_size, name="viewport")
    except OrthographicViewError:
        raise DivasInputError(
            None,
            "This view is orthographic, so there is no camera to segment through: "
            "switch it to perspective (Numpad 5) and click again",
        ) from None
    return world_to_scene_camera(obj, cam)


def _same_view(a, cam: Camera) -> bool:
    """``cam`` (a region camera) shows what anchor ``a`` shows (its full camera is ``cam``
    resized): same pose, same normalised intrinsics."""
    f = a.full_camera
    norm = lambda c: np.array([c.fx / c.width, c.fy / c.height, c.cx / c.width, c.cy / c.height])  # noqa: E731
    return (
        a.source == "viewport"
        and abs(f.width * cam.height - f.height * cam.width) <= max(f.width, cam.width)
        and np.allclose(norm(f), norm(cam), rtol=0, atol=1e-4)
        and np.allclose(f.c2w, cam.c2w, rtol=0, atol=1e-6)
    )


def viewport_click(
    context,
    obj,
    live: LiveSession,
    view_matrix,
    window_matrix,
    region_size: tuple[int, int],
    mouse: tuple[int, int],
    positive: bool = True,
):
    """A click in a free 3D view: the view becomes an anchor (its camera reconstructed
    exactly from the region, reused while the view does not move) and the click proceeds
    as a click on that anchor. Returns ``(anchor index, click result)``."""
    cam = viewport_camera(obj, view_matrix, window_matrix, region_size)
    s = live.session
    index = next((a.index for a in reversed(s.anchors) if _same_view(a, cam)), None)
    if index is None:
        index = s.add_anchor(cam, "viewport", -1).index
        make_anchor_camera(context, obj, live, index)
    a = s.anchors[index]  # its camera: the region's, resized (anchor resolution, scale)
    xy = cam.pixels_to(a.camera, region_click_pixel(mouse, region_size))
    return index, click(context, obj, live, index, (float(xy[0]), float(xy[1])), positive)


def correction_summary(res) -> str:
    """What a correction (:class:`~divas_engine.session.CorrectionResult`) changed, in
    words: the views segmented again and the splats selected / deselected."""
    n = res.views_changed
    parts = [f"{n} view{'s' if n != 1 else ''} changed"]
    if len(res.removed):
        parts.append(f"{len(res.removed):,} splats out")
    if len(res.added):
        parts.append(f"{len(res.added):,} splats in")
    return ", ".join(parts)


def _after_correction(context, obj, live: LiveSession, res) -> dict:
    """Show a correction at once: the points' selection, the selection over the views it
    changed; its record fields (views changed, seconds by stage)."""
    s = live.session
    if res.refused or res.rejected or len(res.added) or len(res.removed):
        write_selection(obj, live)
    sel = s.selection
    for vid in res.resegmented:
        v = s.view(vid)
        # the view a negative click no view saw fused gets its camera here
        made = vid in live.view_cameras or is_negative_view(s, v)
        if made and v.status == ViewStatus.FUSED:
            show_view(context, obj, live, v, lambda v=v: s.overlay(v, sel), activate=False)
    return {"views_changed": res.views_changed, **res.timings}


def click(
    context, obj, live: LiveSession, anchor: int, xy, positive: bool = True, *, preview: bool = True
):
    """A click on anchor ``anchor``: positive spawns (and shows) the centroid view with
    its default-prompt preview; negative takes the spot out of the selection at once
    (and out of every view that held it). Both correct the views that disagree."""
    s = live.session
    t0 = time.perf_counter()
    last = s.last_correction
    res = s.click(int(anchor), (float(xy[0]), float(xy[1])), positive=positive)
    corr = s.last_correction if s.last_correction is not last else None
    _show_rendered_anchor(live, int(anchor))
    fields = {} if corr is None else _after_correction(context, obj, live, corr)
    if not positive:
        what = f"negative click on anchor {anchor}"
        if corr is not None:
            what += f": {correction_summary(corr)}"
        live.record({"what": what, **fields, "update_s": time.perf_counter() - t0})
        return res
    timings = {**dict(res.timings), **fields}
    if preview:
        timings["preview_s"] = s.prompt(res).seconds
    show_view(context, obj, live, res)
    live.record({"what": f"view {res.id}", **timings, "update_s": time.perf_counter() - t0})
    return res


def correct_view(context, obj, live: LiveSession, view_id: str, xy, positive: bool = True):
    """A click on centroid view ``view_id`` (accepted or not) as a correction: the spot
    goes out of (negative) or into (positive) the selection at once, and every view
    that disagrees with it is segmented and fused again. Returns the engine's
    :class:`~divas_engine.session.CorrectionResult`."""
    s = live.session
    t0 = time.perf_counter()
    v = s.view(view_id)
    res = s.click_view(v, (float(xy[0]), float(xy[1])), positive=positive)
    fields = _after_correction(context, obj, live, res)
    if v.status == ViewStatus.FUSED:
        sel = s.selection
        show_view(context, obj, live, v, lambda: s.overlay(v, sel))
    else:
        show_view(context, obj, live, v)
    sign = "click" if positive else "negative click"
    what = f"{sign} on view {v.id}: {correction_summary(res)}"
    live.record({"what": what, **fields, "update_s": time.perf_counter() - t0})
    return res


def _show_rendered_anchor(live: LiveSession, i: int) -> None:
    """A click rendered anchor ``i`` (if it was not yet): its camera shows that render."""
    import bpy

    if 0 <= i < len(live.anchor_cameras):
        ensure_background(live, bpy.data.objects.get(live.anchor_cameras[i]))


def add_prompt(context, obj, live: LiveSession, view_id: str, xy, positive: bool = True):
    """One more prompt point on an open centroid view; refreshes its mask preview."""
    extras = live.extra_prompts.setdefault(view_id, [])
    extras.append((float(xy[0]), float(xy[1]), int(bool(positive))))
    try:
        return refresh_preview(context, obj, live, view_id)
    except BaseException:
        extras.pop()
        raise


def refresh_preview(context, obj, live: LiveSession, view_id: str):
    """Segment the view's default prompt plus its added points; show the mask preview."""
    s = live.session
    v = s.view(view_id)
    pts, labs = _extras(live, view_id)
    prev = s.prompt(v, pts, labs)
    show_view(context, obj, live, v)
    live.record({"what": f"preview {v.id}", "segmenter_s": prev.seconds, "update_s": prev.seconds})
    return prev


def _extras(live: LiveSession, view_id: str) -> tuple[np.ndarray, np.ndarray]:
    e = live.extra_prompts.get(view_id, [])
    return (
        np.array([(x, y) for x, y, _ in e], np.float64).reshape(-1, 2),
        np.array([lab for _, _, lab in e], np.int64),
    )


def accept(context, obj, live: LiveSession, view_id: str | None = None, points=None, labels=None):
    """Accept a centroid view (default: the scene camera's, else the next open one):
    fuse + map, recolour the points, show the selection on the next view (or back on the
    anchor). ``points``/``labels`` replace the view's added prompt points."""
    s = live.session
    if not view_id:
        cam = context.scene.camera
        t = camera_target(live, cam)
        view_id = t.view_id if t.is_view else None
    if not view_id:
        nxt = s.next_view()
        if nxt is None:
            raise DivasInputError(
                None,
                "There is no open view to accept: click the object on an anchor "
                "(or anywhere in a 3D view) first",
            )
        view_id = nxt.id
    v = s.view(view_id)
    if points is not None:
        p = np.asarray(points, np.float64).reshape(-1, 2)
        lab = np.asarray(labels if labels is not None else np.ones(len(p)), np.int64)
        res = s.accept(v, p, lab)  # as given (the view's default prompt is added)
        live.extra_prompts[v.id] = [(float(x), float(y), int(b)) for (x, y), b in zip(p, lab)]
    else:
        pts, labs = _extras(live, v.id)
        res = s.accept(v, pts, labs) if len(pts) else s.accept(v)
    live.record({"what": f"accept {v.id} ({v.status})", **res.timings})
    if res.synced:
        write_selection(obj, live)
        for vid in res.fused:  # views fused at this sync (NeRF: the whole group), and
            # the wider views of an object the close-up cut off (cameras made here)
            if vid != v.id and (vid in live.view_cameras or is_wider(vid)):
                show_view(context, obj, live, s.view(vid), activate=False)
    if v.status == ViewStatus.REJECTED:
        show_view(context, obj, live, v)  # stay: more prompts, then Enter again
        return res
    # the overlays are rendered when the view is first drawn (read), not here
    if res.overlay_source is not None:
        show_view(context, obj, live, v, lambda: res.overlay, activate=False)
    if res.next_view is not None and res.next_overlay_source is not None:
        show_view(context, obj, live, res.next_view, lambda: res.next_overlay)
    else:
        show_anchor(context, live, v.anchor)
    return res


def sync(context, obj, live: LiveSession):
    """Fuse every pending NeRF mask now (no-op for 2DGS or when none is pending)."""
    res = live.session.sync()
    if res.synced:
        write_selection(obj, live)
        for vid in res.fused:
            if vid in live.view_cameras or is_wider(vid):
                show_view(context, obj, live, live.session.view(vid), activate=False)
        live.record({"what": "sync", **res.timings})
    return res


def undo(context, obj, live: LiveSession):
    """Undo the last accepted view (exact); it is shown again, open, with its preview."""
    t0 = time.perf_counter()
    v = live.session.undo()
    if v is None:
        return None
    prune_view_cameras(live)  # the wider views the accept added are gone with it
    write_selection(obj, live)
    show_view(context, obj, live, v)
    live.record({"what": f"undo {v.id}", "update_s": time.perf_counter() - t0})
    return v


def reset(context, obj, live: LiveSession, *, all_objects: bool = False) -> None:
    """Drop the current object's views and selection (``all_objects``: every label too)."""
    t0 = time.perf_counter()
    live.session.reset(all_objects=all_objects)
    prune_view_cameras(live)
    write_selection(obj, live)
    if live.anchor_cameras:
        show_anchor(context, live, 0)
    live.record({"what": "reset", "update_s": time.perf_counter() - t0})


def finish_object(context, obj, live: LiveSession, name: str | None = None):
    """Commit the selection as the next label (``divas_label``) and start a new object."""
    t0 = time.perf_counter()
    rec = live.session.finish_object(name or None)
    prune_view_cameras(live)
    write_selection(obj, live)
    live.record({"what": f"finish {rec.name}", "update_s": time.perf_counter() - t0})
    return rec

"""The session's cameras in Blender: one per anchor and per centroid view.

Each is a camera in the "DivAS Views" collection, made by
:func:`..camera_objects.create_camera_object` from the *rendered* camera (so its pixels
are the session's pixels), parented to the segmented object (so it follows the object's
transform and tells whose camera it is), tagged with ``divas_owner`` / ``divas_anchor``
/ ``divas_view``. Its background image is the view's plain engine render, packed into
the .blend; the mask preview, the prompt points and the selection are drawn over the
viewport by :mod:`..draw` from the live session, so undo and redo need no image work.

The tables of camera names a :class:`~..session_registry.LiveSession` keeps are rebuilt
from the cameras themselves (:func:`sync_camera_tables`) after Blender's undo, which
brings cameras back or removes them with the rest of the file's data.
"""

from __future__ import annotations

from dataclasses import replace

import bpy
import numpy as np

from divas_engine.blender_convention import camera_from_blender
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.session import Session, SessionView

from .. import memory, overlays
from ..camera_objects import (
    RESOLUTION_PROP,
    apply_render_settings,
    blender_params,
    create_camera_object,
)
from ..modal_logic import ANCHOR_PROP, OWNER_PROP, VIEW_PROP, Target, target_from_props
from ..session_registry import LiveSession

__all__ = [
    "VIEWS_COLLECTION",
    "activate_camera",
    "camera_target",
    "scene_camera_of",
    "object_frame",
    "world_to_scene_camera",
    "make_anchor_camera",
    "make_anchor_cameras",
    "has_background",
    "ensure_background",
    "cameras_needing_background",
    "fill_backgrounds",
    "show_anchor",
    "show_view",
    "remove_cameras_of",
    "prune_view_cameras",
    "prune_anchor_cameras",
    "cameras_of",
    "sync_camera_tables",
    "adopt_cameras",
]

VIEWS_COLLECTION = "DivAS Views"


def _views_collection(context):
    coll = bpy.data.collections.get(VIEWS_COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(VIEWS_COLLECTION)
    if coll.name not in context.scene.collection.children:
        context.scene.collection.children.link(coll)
    return coll


def _remove_camera(name: str) -> None:
    cam = bpy.data.objects.get(name)
    if cam is None:
        return
    data = cam.data
    img = bpy.data.images.get(overlays.image_name(cam))
    bpy.data.objects.remove(cam)
    if data is not None and data.users == 0:
        bpy.data.cameras.remove(data)
    if img is not None:
        bpy.data.images.remove(img)


def cameras_of(obj) -> list:
    """The session cameras of ``obj``: its camera children tagged as anchors or views
    (and untagged-parent cameras naming it in ``divas_owner``)."""
    return [
        o
        for o in bpy.data.objects
        if o.type == "CAMERA"
        and (o.parent == obj or o.get(OWNER_PROP) == obj.name)
        and ANCHOR_PROP in o
    ]


def remove_cameras_of(obj) -> None:
    """Remove every camera a session made for ``obj``."""
    for o in cameras_of(obj):
        _remove_camera(o.name)


def _display_size(session: Session) -> float:
    centres = np.array([a.camera.center for a in session.anchors])
    spread = float(np.linalg.norm(centres.max(0) - centres.min(0))) if len(centres) > 1 else 1.0
    return max(0.03 * spread, 1e-3)


def _new_camera(context, obj, camera, name: str, session: Session):
    cam = create_camera_object(
        camera, _views_collection(context), name=name, display_size=_display_size(session)
    )
    cam[OWNER_PROP] = obj.name
    cam.parent = obj  # world = object @ camera: follows the object's transform
    if camera.near > 0:
        # the engine camera's own near clip (centroid views), so the camera view hides
        # what the engine's render did; Blender clips in the normalised camera frame,
        # i.e. in world units: scene units × the object's uniform scale
        s = abs(float(np.linalg.det(np.array(obj.matrix_world, np.float64)[:3, :3]))) ** (1 / 3)
        cam.data.clip_start = max(cam.data.clip_start, camera.near * s)
    return cam


def activate_camera(context, cam) -> None:
    """Make ``cam`` the scene camera with its own render size, and look through it in the
    context's 3D view (when there is one); a lazy anchor renders now."""
    from .. import session_registry

    for live in session_registry.all_sessions():
        if ensure_background(live, cam):
            break
    apply_render_settings(context.scene, cam)
    space = getattr(context, "space_data", None)
    if space is not None and getattr(space, "type", None) == "VIEW_3D":
        space.region_3d.view_perspective = "CAMERA"
        if context.area is not None:
            context.area.tag_redraw()


def camera_target(live: LiveSession | None, cam) -> Target:
    """What ``cam`` shows in ``live``'s session (:class:`~..modal_logic.Target`)."""
    if live is None or cam is None:
        return Target()
    if (
        cam.get(OWNER_PROP) != live.object_name
        and cam.name not in live.anchor_cameras
        and cam.name not in live.view_cameras.values()
    ):
        return Target()

    def status(vid: str) -> str | None:
        try:
            v = live.session.view(vid)
        except KeyError:
            return None
        return v.status if v.object_index == live.session.current.index else None

    return target_from_props({k: cam[k] for k in (ANCHOR_PROP, VIEW_PROP) if k in cam}, status)


def object_frame(obj) -> np.ndarray:
    """``obj.matrix_world`` (the session's scene frame in the world), checked to be a
    rotation with a uniform scale (what a pinhole camera survives)."""
    ow = np.array(obj.matrix_world, np.float64)
    g = ow[:3, :3].T @ ow[:3, :3]  # s²·I for a rotation with uniform scale s
    if not np.allclose(g, np.eye(3) * np.trace(g) / 3.0, rtol=0, atol=1e-5 * np.trace(g)):
        raise DivasInputError(
            None,
            f"{obj.name!r} is stretched (a non-uniform scale or shear), so a camera cannot "
            "be placed in its frame: apply its scale (Ctrl+A › Scale) and click again",
        )
    return ow


def world_to_scene_camera(obj, camera: Camera) -> Camera:
    """A world-frame engine camera in ``obj``'s scene frame (uniform scale allowed)."""
    c2w = np.linalg.inv(object_frame(obj)) @ camera.c2w
    c2w[:3, :3] /= np.linalg.norm(c2w[:3, :3], axis=0, keepdims=True)
    return camera.with_pose(c2w)


def scene_camera_of(obj, cam_obj, scene) -> Camera:
    """The engine camera of Blender camera ``cam_obj`` in ``obj``'s scene frame (the
    session's): ``obj.matrix_world⁻¹ @ cam.matrix_world`` — the anchor cameras are
    parented to ``obj``, training cameras usually are not."""
    ow = object_frame(obj)
    p = blender_params(scene, cam_obj)
    return camera_from_blender(replace(p, matrix_world=np.linalg.inv(ow) @ p.matrix_world))


# ----------------------------------------------------------------------------- anchors
def show_anchor(context, live: LiveSession, i: int, *, activate: bool = True) -> None:
    """Make anchor ``i``'s camera the scene camera (when ``activate``); what it shows
    over its render is drawn live (:mod:`..draw`)."""
    cam = bpy.data.objects.get(live.anchor_cameras[i]) if i < len(live.anchor_cameras) else None
    if cam is not None and activate:
        activate_camera(context, cam)


def make_anchor_camera(context, obj, live: LiveSession, i: int, **_ignored):
    """The camera of anchor ``i`` (appended to ``live.anchor_cameras``), with its render
    as background when the anchor is rendered already; otherwise the render comes when
    the user first looks through it (:func:`ensure_background`)."""
    a = live.session.anchors[i]
    cam = _new_camera(context, obj, a.camera, f"{obj.name} Anchor {i:02d}", live.session)
    cam[ANCHOR_PROP] = i
    live.anchor_cameras.append(cam.name)
    if a.rendered:
        overlays.set_background(cam, a.rgb)
    return cam


def make_anchor_cameras(context, obj, live: LiveSession) -> None:
    """A camera per anchor of the session (lazy backgrounds: :func:`make_anchor_camera`)."""
    for i in range(len(live.session.anchors)):
        make_anchor_camera(context, obj, live, i)


def has_background(cam) -> bool:
    """``cam`` shows an image behind its view."""
    bgs = cam.data.background_images
    return len(bgs) > 0 and bgs[0].image is not None


def ensure_background(live: LiveSession, cam) -> bool:
    """Render anchor camera ``cam``'s view now if it has no background image yet (the
    lazy anchors: an anchor renders when the user looks through it or selects it).
    Returns whether an image was made."""
    if cam is None or cam.type != "CAMERA" or VIEW_PROP in cam or ANCHOR_PROP not in cam:
        return False
    if cam.name not in live.anchor_cameras or has_background(cam):
        return False
    i = live.anchor_cameras.index(cam.name)
    if i >= len(live.session.anchors):
        return False
    overlays.set_background(cam, live.session.render(live.session.anchors[i]).rgb)
    memory.release_freed()  # the render's freed transients back to the system
    return True


def cameras_needing_background(context) -> list[tuple[LiveSession, object]]:
    """``(live session, anchor camera)`` for the scene camera and the active object when
    they are anchor cameras of a live session still without their render."""
    from .. import session_registry

    out = []
    for cam in {getattr(context.scene, "camera", None), getattr(context, "active_object", None)}:
        if cam is None or cam.type != "CAMERA" or ANCHOR_PROP not in cam or VIEW_PROP in cam:
            continue
        if has_background(cam):
            continue
        for live in session_registry.all_sessions():
            if cam.name in live.anchor_cameras:
                out.append((live, cam))
                break
    return out


def fill_backgrounds(context) -> int:
    """Render the missing anchor backgrounds the user looks at (scene camera, active
    object); returns how many were made."""
    return sum(ensure_background(live, cam) for live, cam in cameras_needing_background(context))


# ----------------------------------------------------------------------------- views
def _view_camera(context, obj, live: LiveSession, v: SessionView):
    name = live.view_cameras.get(v.id)
    cam = bpy.data.objects.get(name) if name else None
    if cam is None:
        cam = _new_camera(context, obj, v.camera, f"{obj.name} View {v.id}", live.session)
        cam[VIEW_PROP], cam[ANCHOR_PROP] = v.id, int(v.anchor)
        live.view_cameras[v.id] = cam.name
        overlays.set_background(cam, live.session.render(v).rgb)
    return cam


def show_view(
    context, obj, live: LiveSession, v: SessionView, overlay=None, *, activate: bool = True
):
    """The camera of centroid view ``v`` (made on first use, with its render); the
    engine's selection ``overlay`` on it (an :class:`~divas_engine.session.Overlay`, or
    a callable returning one: rendered only when the view is first drawn) is
    kept to be drawn while that selection is current; the scene camera when
    ``activate``."""
    cam = _view_camera(context, obj, live, v)
    if overlay is not None:
        live.set_coverage(v.id, overlay)
    if activate:
        activate_camera(context, cam)
    return cam


def prune_view_cameras(live: LiveSession) -> None:
    """Remove the cameras of views that are no longer part of the current object."""
    current = {v.id for v in live.session.views}
    for vid in [vid for vid in live.view_cameras if vid not in current]:
        _remove_camera(live.view_cameras.pop(vid))
        live.extra_prompts.pop(vid, None)
        live.coverage.pop(vid, None)


def prune_anchor_cameras(live: LiveSession) -> None:
    """Remove the cameras of anchors the session no longer has (an undone viewport click)."""
    n = len(live.session.anchors)
    for name in live.anchor_cameras[n:]:
        _remove_camera(name)
    del live.anchor_cameras[n:]


def sync_camera_tables(obj, live: LiveSession) -> None:
    """Rebuild ``live.anchor_cameras`` / ``view_cameras`` from ``obj``'s cameras."""
    anchors: dict[int, str] = {}
    views: dict[str, str] = {}
    for cam in cameras_of(obj):
        if cam.get(VIEW_PROP):
            views[str(cam[VIEW_PROP])] = cam.name
        else:
            anchors[int(cam[ANCHOR_PROP])] = cam.name
    live.anchor_cameras = [anchors[i] for i in sorted(anchors)]
    live.view_cameras = views


def adopt_cameras(context, obj, live: LiveSession) -> None:
    """Match ``obj``'s existing session cameras (a reopened .blend) to the resumed
    session: keep the ones that show an anchor / view of the same size, make the
    missing ones, remove the rest."""
    s = live.session
    by_anchor, by_view = {}, {}
    for cam in cameras_of(obj):
        (by_view if cam.get(VIEW_PROP) else by_anchor)[
            str(cam[VIEW_PROP]) if cam.get(VIEW_PROP) else int(cam[ANCHOR_PROP])
        ] = cam

    def fits(cam, camera) -> bool:
        return tuple(cam.get(RESOLUTION_PROP, ())) == (camera.width, camera.height)

    live.anchor_cameras, live.view_cameras = [], {}
    for i, a in enumerate(s.anchors):
        cam = by_anchor.pop(i, None)
        if cam is not None and fits(cam, a.camera):
            live.anchor_cameras.append(cam.name)
            if not has_background(cam) and a.rendered:
                overlays.set_background(cam, a.rgb)  # else rendered when looked through
        else:
            if cam is not None:
                _remove_camera(cam.name)
            make_anchor_camera(context, obj, live, i)
    for v in s.views:
        cam = by_view.pop(v.id, None)
        if cam is not None and fits(cam, v.camera):
            live.view_cameras[v.id] = cam.name
        else:
            if cam is not None:
                _remove_camera(cam.name)
            _view_camera(context, obj, live, v)
    for cam in [*by_anchor.values(), *by_view.values()]:
        _remove_camera(cam.name)

"""The session's cameras in Blender: one per anchor and per centroid view.

Each is a camera in the "DivAS Views" collection, made by
:func:`..camera_objects.create_camera_object` from the *rendered* camera (so its pixels
are the session's pixels), parented to the segmented object (so it follows the object's
transform), tagged with ``divas_owner`` / ``divas_anchor`` / ``divas_view``. Its
background image is the view's render with the mask preview and prompt points
(:mod:`..overlays`), or the selection overlay once accepted.
"""

from __future__ import annotations

from dataclasses import replace

import bpy
import numpy as np

from divas_engine.blender_convention import camera_from_blender
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.kinds import ViewStatus
from divas_engine.session import Session, SessionView

from .. import overlays
from ..camera_objects import apply_render_settings, blender_params, create_camera_object
from ..modal_logic import ANCHOR_PROP, OWNER_PROP, VIEW_PROP, Target, target_from_props
from ..session_registry import LiveSession

__all__ = [
    "VIEWS_COLLECTION",
    "activate_camera",
    "camera_target",
    "scene_camera_of",
    "make_anchor_camera",
    "make_anchor_cameras",
    "show_anchor",
    "show_view",
    "remove_cameras_of",
    "prune_view_cameras",
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


def remove_cameras_of(obj_name: str) -> None:
    """Remove every camera a session made for the object named ``obj_name``."""
    for o in [o for o in bpy.data.objects if o.type == "CAMERA" and o.get(OWNER_PROP) == obj_name]:
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
    context's 3D view (when there is one)."""
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


def scene_camera_of(obj, cam_obj, scene) -> Camera:
    """The engine camera of Blender camera ``cam_obj`` in ``obj``'s scene frame (the
    session's): ``obj.matrix_world⁻¹ @ cam.matrix_world`` — the anchor cameras are
    parented to ``obj``, training cameras usually are not."""
    ow = np.array(obj.matrix_world, np.float64)
    g = ow[:3, :3].T @ ow[:3, :3]  # s²·I for a rotation with uniform scale s
    if not np.allclose(g, np.eye(3) * np.trace(g) / 3.0, rtol=0, atol=1e-5 * np.trace(g)):
        raise DivasInputError(
            None,
            f"{obj.name!r} has a non-uniform scale or shear: apply "
            "its scale (Ctrl+A) before adding a camera as an anchor",
        )
    p = blender_params(scene, cam_obj)
    return camera_from_blender(replace(p, matrix_world=np.linalg.inv(ow) @ p.matrix_world))


# ----------------------------------------------------------------------------- anchors
def _anchor_image(live: LiveSession, i: int, *, with_selection: bool) -> np.ndarray:
    s = live.session
    a = s.anchors[i]
    rgb = a.rgb
    if with_selection and s.selection.any():
        rgb = s.overlay(a.camera, full_camera=False).image
    clicks = s.current.clicks.get(i, [])
    pts = np.array([c.xy for c in clicks], np.float64).reshape(-1, 2)
    return overlays.preview_image(rgb, None, pts, [int(c.positive) for c in clicks])


def show_anchor(context, live: LiveSession, i: int, *, activate: bool = True) -> None:
    """Refresh anchor ``i``'s image (render, selection overlay, clicks); make it the scene
    camera when ``activate``."""
    cam = bpy.data.objects.get(live.anchor_cameras[i])
    if cam is None:
        return
    overlays.set_background(cam, _anchor_image(live, i, with_selection=True))
    if activate:
        activate_camera(context, cam)


def make_anchor_camera(context, obj, live: LiveSession, i: int, *, with_selection: bool):
    """The camera of anchor ``i`` (appended to ``live.anchor_cameras``)."""
    a = live.session.anchors[i]
    cam = _new_camera(context, obj, a.camera, f"{obj.name} Anchor {i:02d}", live.session)
    cam[ANCHOR_PROP] = i
    live.anchor_cameras.append(cam.name)
    overlays.set_background(cam, _anchor_image(live, i, with_selection=with_selection))
    return cam


def make_anchor_cameras(context, obj, live: LiveSession) -> None:
    """A camera per anchor of the session, with its plain render."""
    for i in range(len(live.session.anchors)):
        make_anchor_camera(context, obj, live, i, with_selection=False)


# ----------------------------------------------------------------------------- views
def _view_image(live: LiveSession, v: SessionView) -> np.ndarray:
    prev = v.preview
    if v.status == ViewStatus.FUSED:
        return live.session.overlay(v).image
    if prev is None:
        pts, labs = live.session.default_prompts(v)
        return overlays.preview_image(v.rgb, None, pts, labs)
    return overlays.preview_image(v.rgb, prev.mask, prev.points, prev.labels)


def _view_camera(context, obj, live: LiveSession, v: SessionView):
    name = live.view_cameras.get(v.id)
    cam = bpy.data.objects.get(name) if name else None
    if cam is None:
        cam = _new_camera(context, obj, v.camera, f"{obj.name} View {v.id}", live.session)
        cam[VIEW_PROP], cam[ANCHOR_PROP] = v.id, int(v.anchor)
        live.view_cameras[v.id] = cam.name
    return cam


def show_view(
    context, obj, live: LiveSession, v: SessionView, image=None, *, activate: bool = True
):
    """The camera of centroid view ``v`` (made on first use) showing ``image`` (default:
    its preview, or its selection overlay once fused); the scene camera when
    ``activate``."""
    cam = _view_camera(context, obj, live, v)
    overlays.set_background(cam, _view_image(live, v) if image is None else image)
    if activate:
        activate_camera(context, cam)
    return cam


def prune_view_cameras(live: LiveSession) -> None:
    """Remove the cameras of views that are no longer part of the current object."""
    current = {v.id for v in live.session.views}
    for vid in [vid for vid in live.view_cameras if vid not in current]:
        _remove_camera(live.view_cameras.pop(vid))
        live.extra_prompts.pop(vid, None)

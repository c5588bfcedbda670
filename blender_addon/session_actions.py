"""The DivAS session steps on Blender data: the work behind the session operators and
the click-to-segment modal (which share every function here).

Each step makes one engine call on the object's live
:class:`~divas_engine.session.Session` (:mod:`.session_registry`) and then updates
what Blender shows:

* **cameras** — every anchor and centroid view is a camera in the "DivAS Views"
  collection, made by :func:`.camera_objects.create_camera_object` from the *rendered*
  camera (so its pixels are the session's pixels), parented to the segmented object (so
  it follows the object's transform), tagged with ``divas_owner`` / ``divas_anchor`` /
  ``divas_view``;
* **background images** — the view's render, with the mask preview and prompt points
  (:mod:`.overlays`), or the selection overlay once accepted;
* **points** — ``divas_selected`` (bool, the current object's selection) and
  ``divas_label`` (int, every object's label) written through :mod:`.bridge` after every
  change of the selection, so the display material recolours the splats live.

Pixel coordinates are in rendered-image pixels (the camera × render scale) unless a
function says otherwise.
"""

from __future__ import annotations

import re
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path

import bpy
import numpy as np

from divas_engine.blender_convention import camera_from_blender
from divas_engine.camera import Camera
from divas_engine.errors import DivasInputError
from divas_engine.evaluation.ground_truth import load_ground_truth
from divas_engine.io.cameras import load_cameras
from divas_engine.kinds import ViewStatus
from divas_engine.point_attributes import INDEX, SELECTED, point_values
from divas_engine.segment import SegmenterSettings, SegmenterSetupError, build_segmenter
from divas_engine.session import Session, SessionConfig, SessionView, anchor_plan, load_prompts
from divas_engine.session.prompts import resolve_anchors

from . import bridge, overlays, session_registry, source
from .camera_objects import (
    apply_render_settings,
    blender_params,
    create_camera_object,
    engine_camera,
)
from .importers import TRAINING_CAMERAS
from .modal_logic import ANCHOR_PROP, OWNER_PROP, VIEW_PROP, Target, target_from_props
from .reporting import USER_ERRORS
from .session_registry import LiveSession

__all__ = [
    "StartSettings",
    "VIEWS_COLLECTION",
    "LABEL_ATTRIBUTE",
    "SESSION_ERRORS",
    "autosave_path",
    "start",
    "resume",
    "click",
    "add_prompt",
    "accept",
    "sync",
    "undo",
    "reset",
    "finish_object",
    "write_selection",
    "activate_camera",
    "camera_target",
    "report_exception",
    "full_to_session_xy",
]

VIEWS_COLLECTION = "DivAS Views"
#: per-point int32: the label of every finished object plus the current selection.
LABEL_ATTRIBUTE = "divas_label"
#: failures reported as one line (anything else is reported with its type, the traceback
#: going to the console).
SESSION_ERRORS = (*USER_ERRORS, ImportError, RuntimeError)
#: where the add-on's user sets what a segmenter needs (``SegmenterSetupError.requires``).
_WHERE = {
    "ground_truth": "Ground Truth .npy",
    "sam_encoder": "set in the DivAS add-on preferences",
    "sam_decoder": "set in the DivAS add-on preferences",
    "sam_checkpoint": "set in the DivAS add-on preferences",
}


@dataclass(frozen=True)
class StartSettings:
    """How to start (or resume) a session.

    Attributes:
        config: the engine session config (:func:`.properties.session_config`).
        device: ``auto`` / ``cpu`` / ``cuda``.
        segmenter: ``classic`` / ``sam_onnx`` / ``sam_torch`` / ``oracle`` (evaluation):
            a :class:`~divas_engine.segment.SegmenterKind` name.
        sam_*: model files of the SAM segmenters.
        cameras_path: training cameras; None → ``cameras.json`` beside the scene file,
            else the cameras in the "DivAS Cameras" collection, else none.
        prompts_path: take the anchors of this prompts file instead of the planned ones.
        gt_labels: ground truth ``.npy`` (the oracle's target).
    """

    config: SessionConfig
    device: str = "cpu"
    segmenter: str = "classic"
    sam_encoder: Path | None = None
    sam_decoder: Path | None = None
    sam_checkpoint: Path | None = None
    sam_model_type: str = "vit_h"
    cameras_path: Path | None = None
    prompts_path: Path | None = None
    gt_labels: Path | None = None


def report_exception(operator, exc: BaseException) -> set[str]:
    """One readable ``ERROR`` line on ``operator``; unexpected errors keep their traceback
    in the console only."""
    if isinstance(exc, SESSION_ERRORS):
        msg = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    else:
        traceback.print_exception(exc, file=sys.stderr)
        msg = f"DivAS internal error ({type(exc).__name__}: {exc}); details in the console"
    operator.report({"ERROR"}, msg or type(exc).__name__)
    return {"CANCELLED"}


def autosave_path(obj) -> Path:
    """``<blend>_divas_session.json`` beside the saved .blend, else in a temp folder."""
    if bpy.data.filepath:
        blend = Path(bpy.path.abspath(bpy.data.filepath))
        return blend.with_name(f"{blend.stem}_divas_session.json")
    safe = re.sub(r"[^A-Za-z0-9_-]+", "_", obj.name)
    return Path(tempfile.gettempdir()) / "divas" / f"{safe}_divas_session.json"


# ----------------------------------------------------------------------------- points
def write_selection(obj, live: LiveSession) -> None:
    """``divas_selected`` and ``divas_label`` of ``obj``'s points from the session."""
    s = live.session
    geom = obj.data
    index = bridge.read_attribute(geom, INDEX)
    try:
        selected = point_values(s.scene, index, s.selection).astype(bool)
        labels = point_values(s.scene, index, s.label_set()).astype(np.int32)
    except ValueError:
        raise DivasInputError(
            None, "the object's points are not rows of the session's scene"
        ) from None
    bridge.write_attribute(geom, SELECTED, selected)
    bridge.write_attribute(geom, LABEL_ATTRIBUTE, labels)
    geom.update_tag()


# ----------------------------------------------------------------------------- cameras
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


def _remove_cameras_of(obj_name: str) -> None:
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
    """What ``cam`` shows in ``live``'s session (:class:`~.modal_logic.Target`)."""
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


def _anchor_image(live: LiveSession, i: int, *, with_selection: bool) -> np.ndarray:
    s = live.session
    a = s.anchors[i]
    rgb = a.rgb
    if with_selection and s.selection.any():
        rgb = s.overlay(a.camera, full_camera=False).image
    clicks = s.current.clicks.get(i, [])
    pts = np.array([c.xy for c in clicks], np.float64).reshape(-1, 2)
    return overlays.preview_image(rgb, None, pts, [int(c.positive) for c in clicks])


def _show_anchor(context, live: LiveSession, i: int, *, activate: bool = True) -> None:
    cam = bpy.data.objects.get(live.anchor_cameras[i])
    if cam is None:
        return
    overlays.set_background(cam, _anchor_image(live, i, with_selection=True))
    if activate:
        activate_camera(context, cam)


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


def _show_view(
    context, obj, live: LiveSession, v: SessionView, image=None, *, activate: bool = True
):
    cam = _view_camera(context, obj, live, v)
    overlays.set_background(cam, _view_image(live, v) if image is None else image)
    if activate:
        activate_camera(context, cam)
    return cam


def _prune_view_cameras(live: LiveSession) -> None:
    """Remove the cameras of views that are no longer part of the current object."""
    current = {v.id for v in live.session.views}
    for vid in [vid for vid in live.view_cameras if vid not in current]:
        _remove_camera(live.view_cameras.pop(vid))
        live.extra_prompts.pop(vid, None)


# ----------------------------------------------------------------------------- start
def _training_cameras(context, ref: source.SourceRef, path: Path | None):
    if path is None and (ref.path.parent / "cameras.json").is_file():
        path = ref.path.parent / "cameras.json"
    if path is not None:
        return load_cameras(path)
    return [engine_camera(context.scene, o) for o in _training_camera_objects()]


def _training_camera_objects() -> list:
    """The camera objects of the training-camera collection, in its order."""
    coll = bpy.data.collections.get(TRAINING_CAMERAS)
    return [] if coll is None else [o for o in coll.objects if o.type == "CAMERA"]


def _segmenter(settings: StartSettings):
    """The engine's segmenter (built first: a missing model file fails before the load)."""
    seg_settings = SegmenterSettings(
        settings.segmenter,
        seed=settings.config.seed,
        sam_encoder=settings.sam_encoder,
        sam_decoder=settings.sam_decoder,
        sam_checkpoint=settings.sam_checkpoint,
        sam_model_type=settings.sam_model_type,
        device=settings.device,
    )
    try:
        return build_segmenter(seg_settings, has_ground_truth=settings.gt_labels is not None)
    except SegmenterSetupError as e:
        where = dict.fromkeys(_WHERE[r] for r in e.requires)
        raise DivasInputError(None, f"{e.problem} ({'; '.join(where)})") from None


def _engine_inputs(context, obj, settings: StartSettings):
    from divas_kernels import resolve_device

    ref = source.source_of(obj)
    if ref is None:
        raise DivasInputError(
            None,
            f"{getattr(obj, 'name', None)!r} is not a DivAS-imported "
            "point cloud (import splats or a density grid first)",
        )
    seg = _segmenter(settings)
    scene = source.load_source_scene(ref)
    cameras = _training_cameras(context, ref, settings.cameras_path)
    gt = load_ground_truth(settings.gt_labels, scene) if settings.gt_labels is not None else None
    try:
        device = resolve_device(settings.device)
    except RuntimeError as e:
        raise DivasInputError(None, str(e)) from None
    return scene, cameras, gt, seg, device


def _make_anchor_camera(context, obj, live: LiveSession, i: int, *, with_selection: bool):
    a = live.session.anchors[i]
    cam = _new_camera(context, obj, a.camera, f"{obj.name} Anchor {i:02d}", live.session)
    cam[ANCHOR_PROP] = i
    live.anchor_cameras.append(cam.name)
    overlays.set_background(cam, _anchor_image(live, i, with_selection=with_selection))
    return cam


def _make_anchor_cameras(context, obj, live: LiveSession) -> None:
    for i in range(len(live.session.anchors)):
        _make_anchor_camera(context, obj, live, i, with_selection=False)


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


def add_anchor(context, obj, live: LiveSession, cam_obj) -> int:
    """Manual anchor selection: ``cam_obj`` (a training camera, or any camera the user
    placed, e.g. aligned to the viewport with Ctrl+Alt+Numpad 0) becomes the session's
    next anchor, with its own anchor camera; returns its index."""
    if cam_obj is None or cam_obj.type != "CAMERA":
        raise DivasInputError(None, "select a camera object to add as an anchor")
    if cam_obj.name in live.anchor_cameras or cam_obj.name in live.view_cameras.values():
        raise DivasInputError(
            None, f"{cam_obj.name!r} is already one of this session's anchor or view cameras"
        )
    training = [o.name for o in _training_camera_objects()]
    source_name, index = (
        ("training", training.index(cam_obj.name)) if cam_obj.name in training else ("camera", -1)
    )
    t0 = time.perf_counter()
    cam = scene_camera_of(obj, cam_obj, context.scene)
    a = live.session.add_anchor(cam, source_name, index)
    _make_anchor_camera(context, obj, live, a.index, with_selection=True)
    _show_anchor(context, live, a.index)
    live.record(
        {"what": f"anchor {a.index} from {cam_obj.name}", "update_s": time.perf_counter() - t0}
    )
    return a.index


def start(context, obj, settings: StartSettings) -> LiveSession:
    """Load the object's scene, build the session (occupancy grid, anchor renders) and the
    anchor cameras; the first anchor becomes the scene camera."""
    wm = context.window_manager
    t0 = time.perf_counter()
    wm.progress_begin(0, 100)
    try:
        scene, cameras, gt, seg, device = _engine_inputs(context, obj, settings)
        wm.progress_update(10)
        config = settings.config
        anchors = None
        if settings.prompts_path is not None:
            prompts = load_prompts(settings.prompts_path)
            resolved = resolve_anchors(
                prompts,
                cameras,
                lambda: [a.camera for a in anchor_plan(scene, cameras, config).candidates],
            )
            anchors = [(r.camera, r.source, r.index) for r in resolved]
        session = Session.open(
            scene, cameras, config, seg, device, anchors=anchors, gt_values=gt, render_anchors=False
        )
        wm.progress_update(40)
        try:
            n = len(session.anchors)
            for k, a in enumerate(session.anchors):
                _ = a.buffers
                wm.progress_update(40 + int(50 * (k + 1) / max(n, 1)))
            live = LiveSession(
                session,
                obj.name,
                autosave=None if config.autosave is None else Path(config.autosave),
                segmenter=settings.segmenter,
            )
            session_registry.drop(obj)  # a restart: the old session and its cameras go
            _remove_cameras_of(obj.name)
            _make_anchor_cameras(context, obj, live)
        except BaseException:
            _remove_cameras_of(obj.name)
            session.close()
            raise
        if obj.data.attributes.get(SELECTED) is not None:
            write_selection(obj, live)  # a restart clears the old selection
        session_registry.put(obj, live)
        live.open_s = time.perf_counter() - t0
        live.record({"what": "start", "update_s": live.open_s})
        if live.anchor_cameras:
            activate_camera(context, bpy.data.objects[live.anchor_cameras[0]])
        return live
    finally:
        wm.progress_end()


def resume(context, obj, path: Path, settings: StartSettings) -> LiveSession:
    """Reload a saved session (replayed by the engine) onto ``obj``: anchor and view
    cameras, the selection; it keeps autosaving to ``path``."""
    wm = context.window_manager
    t0 = time.perf_counter()
    wm.progress_begin(0, 100)
    try:
        path = Path(path)
        if not path.is_file():
            raise DivasInputError(path, "no saved DivAS session here")
        scene, cameras, gt, seg, device = _engine_inputs(context, obj, settings)
        wm.progress_update(20)
        session = Session.load(
            path, scene, seg, device, cameras=cameras, gt_values=gt, autosave=str(path)
        )
        wm.progress_update(70)
        try:
            live = LiveSession(session, obj.name, autosave=path, segmenter=settings.segmenter)
            session_registry.drop(obj)
            _remove_cameras_of(obj.name)
            _make_anchor_cameras(context, obj, live)
            for v in session.views:
                _show_view(context, obj, live, v, activate=False)
            write_selection(obj, live)
        except BaseException:
            _remove_cameras_of(obj.name)
            session.close()
            raise
        session_registry.put(obj, live)
        live.open_s = time.perf_counter() - t0
        live.record({"what": "resume", "update_s": live.open_s})
        if live.anchor_cameras:
            _show_anchor(context, live, 0)  # with the selection (the others: when shown)
        return live
    finally:
        wm.progress_end()


# ----------------------------------------------------------------------------- clicks
def full_to_session_xy(live: LiveSession, anchor: int, xy) -> tuple[float, float]:
    """A full-camera pixel of anchor ``anchor`` in its rendered image (as ``divas segment``
    converts the prompts file)."""
    a = live.session.anchor(anchor)
    x, y = a.full_camera.pixels_to(a.camera, (float(xy[0]), float(xy[1])))
    return float(x), float(y)


def click(
    context, obj, live: LiveSession, anchor: int, xy, positive: bool = True, *, preview: bool = True
):
    """A click on anchor ``anchor``: positive spawns (and shows) the centroid view with
    its default-prompt preview; negative becomes a negative prompt of the anchor's views."""
    s = live.session
    t0 = time.perf_counter()
    res = s.click(int(anchor), (float(xy[0]), float(xy[1])), positive=positive)
    if not positive:
        _show_anchor(context, live, int(anchor), activate=False)
        live.record(
            {"what": f"negative click on anchor {anchor}", "update_s": time.perf_counter() - t0}
        )
        return res
    timings = dict(res.timings)
    if preview:
        timings["preview_s"] = s.prompt(res).seconds
    _show_view(context, obj, live, res)
    live.record({"what": f"view {res.id}", **timings, "update_s": time.perf_counter() - t0})
    return res


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
    s = live.session
    v = s.view(view_id)
    pts, labs = _extras(live, view_id)
    prev = s.prompt(v, pts, labs)
    _show_view(context, obj, live, v)
    live.record({"what": f"preview {v.id}", "segmenter_s": prev.seconds, "update_s": prev.seconds})
    return prev


def _extras(live: LiveSession, view_id: str) -> tuple[np.ndarray, np.ndarray]:
    e = live.extra_prompts.get(view_id, [])
    return (
        np.array([(x, y) for x, y, _ in e], np.float64).reshape(-1, 2),
        np.array([lab for _, _, lab in e], np.int64),
    )


# ----------------------------------------------------------------------------- accept …
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
                None, "no open view to accept: click the object on an anchor first"
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
        for vid in res.fused:  # views fused at this sync (NeRF: the whole group)
            if vid != v.id and vid in live.view_cameras:
                _show_view(context, obj, live, s.view(vid), activate=False)
    if v.status == ViewStatus.REJECTED:
        _show_view(context, obj, live, v)  # stay: more prompts, then Enter again
        return res
    if res.overlay is not None:
        _show_view(context, obj, live, v, res.overlay.image, activate=False)
    if res.next_view is not None and res.next_overlay is not None:
        _show_view(context, obj, live, res.next_view, res.next_overlay.image)
    else:
        _show_anchor(context, live, v.anchor)
    return res


def sync(context, obj, live: LiveSession):
    """Fuse every pending NeRF mask now (no-op for 2DGS or when none is pending)."""
    res = live.session.sync()
    if res.synced:
        write_selection(obj, live)
        for vid in res.fused:
            if vid in live.view_cameras:
                _show_view(context, obj, live, live.session.view(vid), activate=False)
        live.record({"what": "sync", **res.timings})
    return res


def undo(context, obj, live: LiveSession):
    """Undo the last accepted view (exact); it is shown again, open, with its preview."""
    t0 = time.perf_counter()
    v = live.session.undo()
    if v is None:
        return None
    write_selection(obj, live)
    _show_view(context, obj, live, v)
    live.record({"what": f"undo {v.id}", "update_s": time.perf_counter() - t0})
    return v


def reset(context, obj, live: LiveSession, *, all_objects: bool = False) -> None:
    """Drop the current object's views and selection (``all_objects``: every label too)."""
    t0 = time.perf_counter()
    live.session.reset(all_objects=all_objects)
    _prune_view_cameras(live)
    write_selection(obj, live)
    for i in range(len(live.anchor_cameras)):
        _show_anchor(context, live, i, activate=i == 0)
    live.record({"what": "reset", "update_s": time.perf_counter() - t0})


def finish_object(context, obj, live: LiveSession, name: str | None = None):
    """Commit the selection as the next label (``divas_label``) and start a new object."""
    t0 = time.perf_counter()
    rec = live.session.finish_object(name or None)
    _prune_view_cameras(live)
    write_selection(obj, live)
    for i in range(len(live.anchor_cameras)):  # the selection is empty now: plain renders
        _show_anchor(context, live, i, activate=False)
    live.record({"what": f"finish {rec.name}", "update_s": time.perf_counter() - t0})
    return rec

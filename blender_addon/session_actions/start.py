"""Starting a session on an imported object, or resuming its saved one.

Both gather the engine's inputs (the object's scene file, training cameras, ground
truth, the segmenter of :func:`divas_engine.segment.build_segmenter`, the device), build
the engine session, make the anchor cameras (:mod:`.view_cameras`) and register the
:class:`~..session_registry.LiveSession`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import bpy

from divas_engine.errors import DivasInputError
from divas_engine.evaluation.ground_truth import load_ground_truth
from divas_engine.io.cameras import load_cameras
from divas_engine.render import make_renderer
from divas_engine.segment import (
    DEFAULT_SEGMENTER,
    SegmenterSettings,
    SegmenterSetupError,
    build_segmenter,
)
from divas_engine.session import Session, SessionConfig, anchor_plan, load_prompts
from divas_engine.session.point_prompts import resolve_prompts

from .. import memory, session_registry, source
from ..camera_objects import engine_camera
from ..importers import TRAINING_CAMERAS
from ..session_registry import STEP_PROP, LiveSession
from .files import ensure_key, recovery_path
from .points import write_selection
from .view_cameras import (
    activate_camera,
    adopt_cameras,
    make_anchor_cameras,
    remove_cameras_of,
    show_anchor,
)

__all__ = [
    "StartSettings",
    "autosave_path",
    "training_camera_objects",
    "start",
    "resume",
]

#: where the add-on's user sets what a segmenter needs (``SegmenterSetupError.requires``).
_WHERE = {
    "ground_truth": "set Ground Truth (.npy) in Start DivAS's options",
    "sam_encoder": "set the SAM model files in the DivAS add-on preferences",
    "sam_decoder": "set the SAM model files in the DivAS add-on preferences",
    "sam_checkpoint": "set the SAM model files in the DivAS add-on preferences",
}


@dataclass(frozen=True)
class StartSettings:
    """How to start (or resume) a session.

    Attributes:
        config: the engine session config (:func:`..properties.session_config`).
        device: ``auto`` / ``cpu`` / ``cuda``.
        segmenter: a :class:`~divas_engine.segment.SegmenterKind` value (``graph3d``,
            ``classic``, ``sam-onnx``, ``sam-torch``, ``oracle`` for evaluation).
        sam_*: model files of the SAM segmenters.
        cameras_path: training cameras; None → ``cameras.json`` beside the scene file,
            else the cameras in the "DivAS Cameras" collection, else none.
        prompts_path: take the anchors of this prompts file instead of the planned ones.
        gt_labels: ground truth ``.npy`` (the oracle's target).
    """

    config: SessionConfig
    device: str = "cpu"
    segmenter: str = DEFAULT_SEGMENTER.value
    sam_encoder: Path | None = None
    sam_decoder: Path | None = None
    sam_checkpoint: Path | None = None
    sam_model_type: str = "vit_h"
    cameras_path: Path | None = None
    prompts_path: Path | None = None
    gt_labels: Path | None = None


def autosave_path(obj) -> Path:
    """Where the session of ``obj`` autosaves between saves of the .blend: a recovery
    file keyed by the object's session key (:mod:`.files`; the .blend's own sidecar is
    written when the .blend is saved)."""
    return recovery_path(ensure_key(obj))


def training_camera_objects() -> list:
    """The camera objects of the training-camera collection, in its order."""
    coll = bpy.data.collections.get(TRAINING_CAMERAS)
    return [] if coll is None else [o for o in coll.objects if o.type == "CAMERA"]


def _training_cameras(context, ref: source.SourceRef, path: Path | None):
    if path is None and (ref.path.parent / "cameras.json").is_file():
        path = ref.path.parent / "cameras.json"
    if path is not None:
        return load_cameras(path)
    return [engine_camera(context.scene, o) for o in training_camera_objects()]


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
        raise DivasInputError(
            None, f"{e.problem}: {'; '.join(where)}, then Start DivAS again"
        ) from None


def _engine_inputs(context, obj, settings: StartSettings):
    from divas_kernels import resolve_device

    ref = source.source_of(obj)
    if ref is None:
        raise DivasInputError(
            None,
            f"{getattr(obj, 'name', None)!r} is not a point cloud imported with DivAS: "
            "import the splats (or a density grid) with File › Import first",
        )
    seg = _segmenter(settings)
    scene = source.load_source_scene(ref)
    cameras = _training_cameras(context, ref, settings.cameras_path)
    gt = load_ground_truth(settings.gt_labels, scene) if settings.gt_labels is not None else None
    try:
        device = resolve_device(settings.device)
    except RuntimeError as e:
        raise DivasInputError(
            None, f"{e}: choose the CPU device in the DivAS preferences and start again"
        ) from None
    return scene, cameras, gt, seg, device


def _primitive_count(scene) -> int:
    """Surfels of a surfel scene, cells of a density grid."""
    density = getattr(scene, "density", None)
    return int(density.size) if density is not None else len(scene)


def _reuse_scratch(session: Session, limited: bool) -> None:
    """With the heap's fixed mmap threshold (a large scene, :mod:`..memory`) every large
    transient array is fresh pages: the mask renders of a scene-aware segmenter then
    keep their working arrays between calls (``SurfelRenderer.scratch_sparse``: far
    fewer page faults a mask render, at ≈ 140 MB held on a 3M-splat scene)."""
    if limited:
        session.renderer.scratch_sparse = True


def _prefetch_cuts(session: Session) -> None:
    """The click operator previews the view's mask before it returns: a segmenter that
    can start its work for that prompt while the view renders (graph3d's cut,
    ``Graph3DSegmenter.prefetch_cuts``) is told to."""
    session.segmenter.prefetch_cuts = True


def _follow_undo_steps(context, session: Session) -> None:
    """Keep at least as many session steps as Blender keeps undo steps."""
    steps = int(getattr(context.preferences.edit, "undo_steps", 32))
    session.history.limit = max(session.history.limit, steps + 2)


def start(context, obj, settings: StartSettings) -> LiveSession:
    """Load the object's scene (the import's copy when it is still cached), build the
    session and the anchor cameras; the first anchor, rendered now, becomes the scene
    camera. The other anchors render when first looked through."""
    wm = context.window_manager
    t0 = time.perf_counter()
    wm.progress_begin(0, 100)
    try:
        scene, cameras, gt, seg, device = _engine_inputs(context, obj, settings)
        # a large scene's big transients give their pages back when freed
        limited = memory.limit_heap_for(_primitive_count(scene))
        wm.progress_update(10)
        config = settings.config
        anchors, renderer = None, None
        if settings.prompts_path is not None:
            prompts = load_prompts(settings.prompts_path)
            if prompts.points:  # anchors that see the 3D points are picked on renders
                renderer = make_renderer(scene, device=device, config=config.render)
            resolved = resolve_prompts(
                prompts,
                scene,
                cameras,
                config,
                lambda cam: renderer.render(cam),
                lambda: [a.camera for a in anchor_plan(scene, cameras, config).candidates],
            )
            anchors = [(r.camera, r.source, r.index) for r in resolved]
        # the first anchor renders now (the user looks through it first); the others
        # when the user looks through them (:func:`.view_cameras.ensure_background`)
        session = Session.open(
            scene, cameras, config, seg, device, anchors=anchors, gt_values=gt, renderer=renderer
        )
        _reuse_scratch(session, limited)
        _prefetch_cuts(session)
        wm.progress_update(80)
        try:
            live = LiveSession(
                session,
                obj.name,
                autosave=None if config.autosave is None else Path(config.autosave),
                segmenter=settings.segmenter,
                key=ensure_key(obj),
            )
            session_registry.drop(obj)  # a restart: the old session and its cameras go
            remove_cameras_of(obj)
            make_anchor_cameras(context, obj, live)
        except BaseException:
            remove_cameras_of(obj)
            session.close()
            raise
        write_selection(obj, live)  # defined from the start (a restart clears the old one)
        session_registry.put(obj, live)
        _follow_undo_steps(context, session)
        obj[STEP_PROP] = session.history.current.id
        live.open_s = time.perf_counter() - t0
        live.record({"what": "start", "update_s": live.open_s})
        if live.anchor_cameras:
            activate_camera(context, bpy.data.objects[live.anchor_cameras[0]])
        memory.release_freed()  # the load's and first render's freed transients
        return live
    finally:
        wm.progress_end()


def resume(context, obj, path: Path, settings: StartSettings) -> LiveSession:
    """Reload a saved session (replayed by the engine) onto ``obj``: the object's anchor
    and view cameras kept when they match (a reopened .blend), made when missing; the
    selection. It autosaves where ``settings`` says (the recovery file by default)."""
    wm = context.window_manager
    t0 = time.perf_counter()
    wm.progress_begin(0, 100)
    try:
        path = Path(path)
        if not path.is_file():
            raise DivasInputError(
                path, "no saved DivAS session is here: Start DivAS to begin a new one"
            )
        scene, cameras, gt, seg, device = _engine_inputs(context, obj, settings)
        limited = memory.limit_heap_for(_primitive_count(scene))
        wm.progress_update(20)
        autosave = settings.config.autosave
        session = Session.load(
            path, scene, seg, device, cameras=cameras, gt_values=gt, autosave=autosave
        )
        _reuse_scratch(session, limited)
        _prefetch_cuts(session)
        wm.progress_update(70)
        try:
            live = LiveSession(
                session,
                obj.name,
                autosave=None if autosave is None else Path(autosave),
                segmenter=settings.segmenter,
                key=ensure_key(obj),
            )
            session_registry.drop(obj)
            adopt_cameras(context, obj, live)
            write_selection(obj, live)
        except BaseException:
            session.close()
            raise
        session_registry.put(obj, live)
        _follow_undo_steps(context, session)
        obj[STEP_PROP] = session.history.current.id
        live.open_s = time.perf_counter() - t0
        live.record({"what": "resume", "update_s": live.open_s})
        if live.anchor_cameras:
            show_anchor(context, live, 0)
        return live
    finally:
        wm.progress_end()

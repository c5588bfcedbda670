"""Import scene files and camera files into Blender (the work behind the import operators).

Each function takes the context and a frozen settings dataclass, calls the engine (which
raises :class:`~divas_engine.errors.DivasInputError` naming the file on bad input) and builds
Blender data through :mod:`.bridge`.

Axes, like Blender's own importers: points keep the file's coordinates and the *object*
carries the axis conversion, so export writes the file's own frame and the session's scene
frame is the object's local frame. The conversion is the Forward/Up pair (default:
COLMAP-trained 3DGS, forward +Z, up −Y), or with *Up From Scene* the rotation that makes the
engine's estimate (:func:`divas_engine.views.estimate_scene_up`) world +Z. Training cameras
come in the same frame: parented to the splat object, or with the same Forward/Up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from divas_engine import load_scene
from divas_engine.blender_convention import axis_conversion, conversion_matrix, up_conversion
from divas_engine.errors import DivasInputError
from divas_engine.io.cameras import load_cameras
from divas_engine.point_attributes import PointTable, grid_point_table, surfel_point_table
from divas_engine.scene import DensityGrid, Scene, SurfelScene

from . import blend_space, bridge, camera_objects, display, memory, source

__all__ = [
    "SplatImportSettings",
    "GridImportSettings",
    "CameraImportSettings",
    "import_splats",
    "import_density_grid",
    "import_cameras",
    "scene_conversion",
    "FRAME_PROP",
]

#: object custom property: the 4×4 axis conversion the import applied (row-major).
FRAME_PROP = "divas_frame"
#: Gaussians sampled for the import's ground-plane search (see :func:`scene_conversion`).
IMPORT_GROUND_POINTS = 6000
#: object custom property: how the up axis was chosen (one line, for the UI).
UP_REASON_PROP = "divas_up_reason"


@dataclass(frozen=True)
class SplatImportSettings:
    """``filepath``: a .ply (standard or compressed), .splat, .spz or SOG file;
    ``forward``/``up``: the file's axes (Blender axis names); ``up_from_scene``: take
    the up from the engine's estimate instead of ``up`` when it finds a ground plane;
    ``display``: add the display modifier; ``points``: point display (None: by size);
    ``view_dependent``: keep the SH coefficients for view-dependent colour;
    ``setup_scene``: set the view transform and render settings splats need;
    ``blend_display``: blend in display space like the capture (:mod:`.blend_space`) or
    in linear light; None (*Auto*): display space when the scene has nothing else to
    render and ``setup_scene`` is set, else the scene's setting is left as it is."""

    filepath: Path
    display: bool = True
    forward: str = "Z"
    up: str = "-Y"
    up_from_scene: bool = True
    points: bool | None = None
    view_dependent: bool = True
    setup_scene: bool = True
    blend_display: bool | None = None


@dataclass(frozen=True)
class GridImportSettings:
    """``filepath``: a NeRF density grid (.npz, instant-ngp .ingp/.msgpack, torch-ngp
    .pth, .vdb); ``min_opacity``: voxels whose cell opacity ``1 − exp(−σ·voxel)`` is below
    it are skipped; ``volume``: show the grid as a Volume (:mod:`.nerf_volume`) rather than
    as points (``display``: add the points display); ``cameras``: import the training
    cameras the file holds (an instant-ngp snapshot's)."""

    filepath: Path
    min_opacity: float = 0.01
    display: bool = True
    forward: str = "Y"
    up: str = "Z"
    volume: bool = True
    cameras: bool = True


#: Collection the training cameras are imported into (and looked up from).
TRAINING_CAMERAS = "DivAS Cameras"


@dataclass(frozen=True)
class CameraImportSettings:
    """``filepath``: cameras.json, transforms.json, a COLMAP model file or folder;
    ``parent``: parent the cameras to this object (its frame is theirs); otherwise
    ``forward``/``up`` convert them as the splat import does."""

    filepath: Path
    collection_name: str = TRAINING_CAMERAS
    forward: str = "Z"
    up: str = "-Y"
    parent: str | None = None


def _object_name(path: Path) -> str:
    return path.name.split(".")[0] or path.name


def _activate(context, obj) -> None:
    for o in context.view_layer.objects:
        if o.select_get():
            o.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj


def scene_conversion(
    scene: Scene, forward: str, up: str, up_from_scene: bool
) -> tuple[np.ndarray, str]:
    """``([3,3] rotation file → Blender, reason)`` for an import (module docstring)."""
    try:
        conv = axis_conversion(forward, up)
    except ValueError as e:
        raise DivasInputError(None, str(e)) from None
    if not up_from_scene:
        return conv, f"Forward {forward}, Up {up}"
    from divas_engine.views import ViewConfig, estimate_scene_up, scene_frame, scene_points
    from divas_engine.views.up_direction import UpSource

    pts, w = scene_points(scene)
    fr = scene_frame(scene)
    # the file axis that becomes +Z is the convention; the import only needs the axis it
    # snaps to, so it fits the ground to fewer Gaussians than the engine's default sample
    cfg = ViewConfig(convention_up=tuple(conv[2]), ground_points=IMPORT_GROUND_POINTS)
    est = estimate_scene_up(pts, w, fr.center, fr.radius, cfg)
    if est.source != UpSource.GROUND:
        return conv, f"Forward {forward}, Up {up} (no ground plane found)"
    return up_conversion(est.up), est.reason


def _new_points_object(context, name, table: PointTable, scene, frame) -> bpy.types.Object:
    if context.mode != "OBJECT" and context.active_object is not None:
        bpy.ops.object.mode_set(mode="OBJECT")  # new objects are made in object mode
    obj = bridge.new_point_cloud_object(
        name, table.positions, context.collection or context.scene.collection
    )
    # one column at a time, each dropped once written: the peak stays one copy
    for col in list(table.columns):
        bridge.write_attribute(obj.data, col, table.columns.pop(col), kind=table.kinds.get(col))
    source.tag_object(obj, scene)
    obj.matrix_world = Matrix(frame.tolist())
    obj[FRAME_PROP] = np.asarray(frame, np.float64).ravel().tolist()
    _activate(context, obj)
    return obj


def import_splats(context, settings: SplatImportSettings) -> bpy.types.Object:
    """A point-cloud object with one point per splat (attributes: see
    :mod:`divas_engine.point_attributes`), its axis conversion as the object transform."""
    path = Path(settings.filepath)
    wm = context.window_manager
    wm.progress_begin(0, 4)
    try:
        scene = load_scene(path)
        if isinstance(scene, DensityGrid):
            raise DivasInputError(path, "is a NeRF density grid; use File › Import › NeRF (DivAS)")
        wm.progress_update(1)
        source.remember_scene(scene)  # Start DivAS takes it from here (no second read)
        rot, reason = scene_conversion(scene, settings.forward, settings.up, settings.up_from_scene)
        wm.progress_update(2)
        table = surfel_point_table(scene, sh_display=settings.view_dependent)
        meta = table.meta
        obj = _new_points_object(context, _object_name(path), table, scene, conversion_matrix(rot))
        del scene, table
        wm.progress_update(3)
        obj[UP_REASON_PROP] = reason
        if settings.display:
            display.add_display_modifier(
                obj,
                points=settings.points,
                sh_range=meta["sh_range"],
                max_radius=meta["max_radius"],
            )
        if settings.setup_scene:
            display.setup_scene_for_splats(context.scene, context)
        blend = settings.blend_display
        if blend is None and settings.setup_scene:
            blend = not blend_space.has_other_renderables(context.scene, exclude=(obj,)) or None
        if blend is not None:
            blend_space.set_blend_display(context.scene, blend, context)
        memory.release_freed()  # the parse's and the point table's freed transients
        return obj
    finally:
        wm.progress_end()


def import_density_grid(
    context, settings: GridImportSettings, notes: list[str] | None = None
) -> bpy.types.Object:
    """A point cloud of the grid's occupied voxels (density, opacity, colour attributes):
    the session object, shown by a Volume child (or as points: asked for, or where the
    Volume cannot be made — one line on ``notes``); with the file's own training cameras
    in the same frame."""
    path = Path(settings.filepath)
    grid = load_scene(path)
    if isinstance(grid, SurfelScene):
        raise DivasInputError(path, "is a splat scene; use Import › Gaussian Splats")
    try:
        table = grid_point_table(grid, settings.min_opacity)
        rot = axis_conversion(settings.forward, settings.up)
    except ValueError as e:
        raise DivasInputError(path, str(e)) from None
    frame = conversion_matrix(rot)
    obj = _new_points_object(context, _object_name(path), table, grid, frame)
    source.remember_scene(grid)  # Start DivAS and the segmented volume take it from here
    volume = settings.volume
    if volume:
        from . import nerf_volume

        try:
            nerf_volume.add_display_volume(context, obj, grid)
        except DivasInputError as e:  # e.g. Blender read no grid from the file
            volume = False
            if notes is not None:
                notes.append(f"shown as points: {e.problem}")
    if not volume and (settings.display or settings.volume):
        display.add_display_modifier(obj, points=True)
    obj["divas_grid_shape"] = list(grid.density.shape)
    obj["divas_grid_aabb"] = np.asarray(grid.aabb, dtype=np.float64).ravel().tolist()
    if settings.cameras:
        from divas_engine.io.load import scene_cameras

        cams = scene_cameras(grid)
        if cams:
            _add_training_cameras(context, cams, frame)
            _activate(context, obj)
    return obj


def _camera_objects(cams, coll, frame: np.ndarray) -> list[bpy.types.Object]:
    """Blender cameras for ``cams`` in ``coll``, sized by the rig's spread."""
    centres = np.array([c.center for c in cams])
    spread = float(np.linalg.norm(centres.max(0) - centres.min(0))) if len(cams) > 1 else 1.0
    size = max(0.02 * spread, 1e-3)
    return [
        camera_objects.create_camera_object(
            c, coll, name=c.name or f"camera_{i:04d}", display_size=size, frame=frame
        )
        for i, c in enumerate(cams)
    ]


def _add_training_cameras(context, cams, frame: np.ndarray) -> list[bpy.types.Object]:
    coll = bpy.data.collections.get(TRAINING_CAMERAS)
    if coll is None:
        coll = bpy.data.collections.new(TRAINING_CAMERAS)
        context.scene.collection.children.link(coll)
    objs = _camera_objects(cams, coll, frame)
    camera_objects.apply_render_settings(context.scene, objs[0])
    return objs


def import_cameras(context, settings: CameraImportSettings) -> list[bpy.types.Object]:
    """Blender cameras for every camera in the file, in a new collection, in the frame
    of the splats (module docstring).

    The scene's render size and pixel aspect are set from the first camera; every
    camera remembers its own (see :mod:`.camera_objects`).
    """
    cams = load_cameras(settings.filepath)
    if not cams:
        raise DivasInputError(settings.filepath, "holds no cameras")
    parent = bpy.data.objects.get(settings.parent) if settings.parent else None
    if settings.parent and parent is None:
        raise DivasInputError(None, f"no object named {settings.parent!r} to parent to")
    try:
        frame = (
            np.eye(4)
            if parent is not None
            else conversion_matrix(axis_conversion(settings.forward, settings.up))
        )
    except ValueError as e:
        raise DivasInputError(settings.filepath, str(e)) from None
    coll = bpy.data.collections.new(settings.collection_name)
    context.scene.collection.children.link(coll)
    objs = _camera_objects(cams, coll, frame)
    if parent is not None:
        for o in objs:
            o.parent = parent
            o.matrix_parent_inverse.identity()
    camera_objects.apply_render_settings(context.scene, objs[0])
    return objs

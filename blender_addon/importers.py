"""Import scene files and camera files into Blender (the work behind the import operators).

Each function takes the context and a frozen settings dataclass, calls the engine
(which raises :class:`~divas_engine.errors.DivasInputError` naming the file on bad
input) and builds Blender data through :mod:`.bridge`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.io.cameras import load_cameras
from divas_engine.point_attributes import grid_point_table, surfel_point_table
from divas_engine.scene import DensityGrid, SurfelScene

from . import bridge, camera_objects, display, source

__all__ = [
    "SplatImportSettings",
    "GridImportSettings",
    "CameraImportSettings",
    "import_splats",
    "import_density_grid",
    "import_cameras",
]


@dataclass(frozen=True)
class SplatImportSettings:
    """``filepath``: a .ply (standard or compressed), .splat or .spz file;
    ``display``: add the Geometry Nodes display modifier."""

    filepath: Path
    display: bool = True


@dataclass(frozen=True)
class GridImportSettings:
    """``min_opacity``: voxels whose cell opacity ``1 − exp(−σ·voxel)`` is below it are skipped."""

    filepath: Path
    min_opacity: float = 0.01
    display: bool = True


#: Collection the training cameras are imported into (and looked up from).
TRAINING_CAMERAS = "DivAS Cameras"


@dataclass(frozen=True)
class CameraImportSettings:
    """``filepath``: cameras.json, transforms.json, a COLMAP model file or folder."""

    filepath: Path
    collection_name: str = TRAINING_CAMERAS


def _object_name(path: Path) -> str:
    return path.name.split(".")[0] or path.name


def _activate(context, obj) -> None:
    for o in context.view_layer.objects:
        if o.select_get():
            o.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj


def _new_points_object(context, name, table, scene, show: bool) -> bpy.types.Object:
    if context.mode != "OBJECT" and context.active_object is not None:
        bpy.ops.object.mode_set(mode="OBJECT")  # new objects are made in object mode
    obj = bridge.new_point_cloud_object(
        name, table.positions, context.collection or context.scene.collection
    )
    bridge.write_attributes(obj.data, table.columns)
    source.tag_object(obj, scene)
    if show:
        display.add_display_modifier(obj)
    _activate(context, obj)
    return obj


def import_splats(context, settings: SplatImportSettings) -> bpy.types.Object:
    """A point-cloud object with one point per splat (attributes: see
    :mod:`divas_engine.point_attributes`)."""
    path = Path(settings.filepath)
    wm = context.window_manager
    wm.progress_begin(0, 3)
    try:
        scene = load_scene(path)
        if isinstance(scene, DensityGrid):
            raise DivasInputError(
                path, "is a NeRF density grid; use Import › NeRF Density Grid (.npz)"
            )
        wm.progress_update(1)
        table = surfel_point_table(scene)
        wm.progress_update(2)
        return _new_points_object(context, _object_name(path), table, scene, settings.display)
    finally:
        wm.progress_end()


def import_density_grid(context, settings: GridImportSettings) -> bpy.types.Object:
    """A point cloud of the grid's occupied voxels (density, opacity, colour attributes)."""
    path = Path(settings.filepath)
    grid = load_scene(path)
    if isinstance(grid, SurfelScene):
        raise DivasInputError(path, "is a splat scene; use Import › Gaussian Splats")
    try:
        table = grid_point_table(grid, settings.min_opacity)
    except ValueError as e:
        raise DivasInputError(path, str(e)) from None
    obj = _new_points_object(context, _object_name(path), table, grid, settings.display)
    obj["divas_grid_shape"] = list(grid.density.shape)
    obj["divas_grid_aabb"] = np.asarray(grid.aabb, dtype=np.float64).ravel().tolist()
    return obj


def import_cameras(context, settings: CameraImportSettings) -> list[bpy.types.Object]:
    """Blender cameras for every camera in the file, in a new collection.

    The scene's render size and pixel aspect are set from the first camera; every
    camera remembers its own (see :mod:`.camera_objects`).
    """
    cams = load_cameras(settings.filepath)
    if not cams:
        raise DivasInputError(settings.filepath, "holds no cameras")
    coll = bpy.data.collections.new(settings.collection_name)
    context.scene.collection.children.link(coll)
    centres = np.array([c.center for c in cams])
    spread = float(np.linalg.norm(centres.max(0) - centres.min(0))) if len(cams) > 1 else 1.0
    size = max(0.02 * spread, 1e-3)
    objs = [
        camera_objects.create_camera_object(
            c, coll, name=c.name or f"camera_{i:04d}", display_size=size
        )
        for i, c in enumerate(cams)
    ]
    camera_objects.apply_render_settings(context.scene, objs[0])
    return objs

"""The link between a Blender object and the scene file it was imported from.

An imported (or extracted) object keeps three custom properties: the absolute source
path, the engine's format name (``ply``, ``compressed_ply``, ``splat``, ``spz``, ``npz``)
and its kind (``surfels`` / ``grid``); its points carry ``divas_index`` (file row, or
flat voxel index). That is all export needs: it reloads the file through the engine
and writes the rows the points' ``divas_selected`` attribute marks, in the file's own
format. The last loaded scene is cached (keyed by path, size and mtime) so repeated
exports do not reparse a large file. The importer hands the scene it has just read to
that cache (:func:`remember_scene`), so Start DivAS right after an import reads nothing
again: the engine then holds one copy of the scene, shared by the cache and
the session.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from divas_engine import load_scene
from divas_engine.errors import DivasInputError
from divas_engine.point_attributes import INDEX, SELECTED, scene_selection
from divas_engine.scene import DensityGrid, Scene

from . import bridge

__all__ = [
    "SourceRef",
    "tag_object",
    "source_of",
    "load_source_scene",
    "remember_scene",
    "selection_of",
    "clear_cache",
    "FORMAT_SUFFIX",
    "PATH_PROP",
    "FORMAT_PROP",
    "KIND_PROP",
]

PATH_PROP, FORMAT_PROP, KIND_PROP = "divas_source_path", "divas_source_format", "divas_kind"
#: file suffix an export in each engine format gets.
FORMAT_SUFFIX = {
    "ply": ".ply",
    "compressed_ply": ".ply",
    "splat": ".splat",
    "spz": ".spz",
    "sog": ".sog",
    "npz": ".npz",
    "ingp": ".ingp",
    "msgpack": ".msgpack",
    "torch_ngp": ".pth",
    "vdb": ".vdb",
}

_cache: dict[str, object] = {"key": None, "scene": None}


@dataclass(frozen=True)
class SourceRef:
    path: Path
    format: str
    kind: str


def tag_object(obj: bpy.types.Object, scene: Scene) -> None:
    """Remember where ``obj``'s points came from (custom properties)."""
    src = scene.source
    obj[PATH_PROP] = str(Path(src.path).resolve()) if src is not None else ""
    obj[FORMAT_PROP] = src.format if src is not None else ""
    obj[KIND_PROP] = "grid" if isinstance(scene, DensityGrid) else "surfels"


def source_of(obj: bpy.types.Object | None) -> SourceRef | None:
    """The source of an imported/extracted object, or None for any other object."""
    if obj is None or obj.type != "POINTCLOUD" or not obj.get(PATH_PROP):
        return None
    return SourceRef(
        Path(bpy.path.abspath(obj[PATH_PROP])),
        str(obj.get(FORMAT_PROP, "")),
        str(obj.get(KIND_PROP, "surfels")),
    )


def load_source_scene(ref: SourceRef) -> Scene:
    """The engine scene of ``ref`` (cached while the file is unchanged)."""
    try:
        st = os.stat(ref.path)
    except OSError as e:
        raise DivasInputError(
            ref.path, f"source file of this object is gone ({e.strerror})"
        ) from None
    key = (str(ref.path), st.st_size, st.st_mtime_ns)
    if _cache["key"] != key:
        _cache["scene"], _cache["key"] = None, None
        _cache["scene"] = load_scene(ref.path, fmt=ref.format or None)
        _cache["key"] = key
    return _cache["scene"]


def remember_scene(scene: Scene) -> None:
    """Make ``scene`` (just loaded from its source file, unchanged) the cached scene of
    that file, so :func:`load_source_scene` returns it instead of reading the file again."""
    src = scene.source
    if src is None or not src.path:
        return
    path = Path(src.path).resolve()
    try:
        st = os.stat(path)
    except OSError:
        return
    _cache["scene"], _cache["key"] = scene, (str(path), st.st_size, st.st_mtime_ns)


def clear_cache() -> None:
    """Drop the cached scene (its arrays can be large)."""
    _cache["scene"], _cache["key"] = None, None


def selection_of(obj: bpy.types.Object, scene: Scene) -> np.ndarray:
    """Engine selection mask of ``scene`` from ``obj``'s ``divas_selected`` points."""
    geom = obj.data
    if geom.attributes.get(SELECTED) is None:
        raise DivasInputError(None, f"{obj.name!r} has no selection (no {SELECTED!r} attribute)")
    try:
        return scene_selection(
            scene, bridge.read_attribute(geom, INDEX), bridge.read_attribute(geom, SELECTED)
        )
    except (KeyError, ValueError) as e:
        raise DivasInputError(
            scene.source.path if scene.source else None,
            f"{obj.name!r} does not match this file ({e})",
        ) from None

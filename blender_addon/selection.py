"""Extract and export the points a ``divas_selected`` attribute marks.

* :func:`export_selection` reloads the object's source file through the engine and
  writes the selected rows with :func:`divas_engine.export.export_selection`, so the
  output is byte-identical to the engine's export (standard PLY rows copied verbatim,
  other formats in their own encoding, grids as a masked ``.npz``) — or, with a
  :class:`ExportTransform`, with :func:`divas_engine.transform_export.
  export_transformed_selection` (positions, rotations, scales and SH rotated).
* :func:`extract_selection` builds a new point-cloud object holding exactly the
  selected points with every attribute (``divas_selected`` itself is left behind: the
  selection belongs to the source object), the same source link, transform and
  display. Works for extracted objects too (``divas_index`` keeps file rows).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import bpy
import numpy as np

from divas_engine.errors import DivasInputError
from divas_engine.export import ExportResult
from divas_engine.export import export_selection as engine_export
from divas_engine.point_attributes import SELECTED
from divas_engine.transform_export import export_transformed_selection

from . import bridge, display, source

__all__ = [
    "ExportSettings",
    "ExportTransform",
    "export_matrix",
    "export_selection",
    "extract_selection",
    "selected_count",
    "has_selection",
]


class ExportTransform(StrEnum):
    """What of the object's transform an export applies.

    ``NONE``: the rows as the file holds them (its own frame). ``OBJECT``: the object's
    transform *since import* (``frame⁻¹ · matrix_world``, ``frame`` = the import's axis
    conversion), so the file keeps its own axis convention with the user's moves, turns
    and scaling baked in. ``WORLD``: the whole ``matrix_world`` (Blender's Z-up world)."""

    NONE = "NONE"
    OBJECT = "OBJECT"
    WORLD = "WORLD"


@dataclass(frozen=True)
class ExportSettings:
    """``filepath``: output file (the source format's suffix is added when missing);
    ``write_labels``: also write ``<stem>_labels.npy`` (bool per input-file row);
    ``transform``: :class:`ExportTransform`."""

    filepath: Path
    write_labels: bool = False
    transform: ExportTransform = ExportTransform.NONE


def has_selection(obj) -> bool:
    """``obj`` is a point cloud with a ``divas_selected`` attribute (cheap: for polls)."""
    return (
        obj is not None
        and obj.type == "POINTCLOUD"
        and obj.data.attributes.get(SELECTED) is not None
    )


def selected_count(obj) -> int | None:
    """Selected points of ``obj``, or None without a ``divas_selected`` attribute."""
    if obj is None or obj.type != "POINTCLOUD" or obj.data.attributes.get(SELECTED) is None:
        return None
    return int(np.count_nonzero(bridge.read_attribute(obj.data, SELECTED)))


def _require_source(obj) -> source.SourceRef:
    ref = source.source_of(obj)
    if ref is None:
        name = getattr(obj, "name", None)
        raise DivasInputError(
            None,
            f"{name!r} is not a point cloud imported with DivAS: import the scene with "
            "File › Import › Gaussian Splats first",
        )
    return ref


def export_selection(obj, settings: ExportSettings) -> ExportResult:
    ref = _require_source(obj)
    scene = source.load_source_scene(ref)
    mask = source.selection_of(obj, scene)
    out = Path(settings.filepath)
    if not out.suffix:
        out = out.with_suffix(source.FORMAT_SUFFIX.get(ref.format, ".ply"))
    if not mask.any():
        raise DivasInputError(
            out,
            "nothing to export: no splat is selected. Select some (click the object in a "
            "DivAS session, or use the Select tools), then export again",
        )
    labels = (
        out.with_name(out.name.split(".")[0] + "_labels.npy") if settings.write_labels else None
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    matrix = export_matrix(obj, ExportTransform(settings.transform))
    if matrix is None:
        vdb = _vdb_beside(out) if ref.kind == "grid" and ref.format != "vdb" else None
        return engine_export(scene, mask, out, labels_path=labels, vdb_path=vdb)
    return export_transformed_selection(scene, mask, out, matrix, labels_path=labels)


def _vdb_beside(out: Path) -> Path:
    """``<out stem>.vdb`` for a grid export: the masked density as a volume (written
    through an OpenVDB module, or the engine's NumPy writer without one)."""
    return out.with_name(out.name.split(".")[0] + ".vdb")


def export_matrix(obj, transform: ExportTransform) -> np.ndarray | None:
    """The ``[4,4]`` an export applies to ``obj``'s splats (None: none)."""
    if transform == ExportTransform.NONE:
        return None
    world = np.array(obj.matrix_world, np.float64)
    if transform == ExportTransform.WORLD:
        return world
    frame = np.asarray(obj.get("divas_frame", np.eye(4).ravel().tolist()), np.float64)
    return np.linalg.inv(frame.reshape(4, 4)) @ world


def extract_selection(context, obj) -> bpy.types.Object:
    """A new object with the selected points of ``obj`` and all their attributes."""
    geom = obj.data
    if geom.attributes.get(SELECTED) is None:
        raise DivasInputError(
            None,
            f"{obj.name!r} has no selection yet: start a DivAS session on it or use the "
            "Select tools first",
        )
    sel = bridge.read_attribute(geom, SELECTED)
    if not sel.any():
        raise DivasInputError(
            None, f"nothing to extract: no splat of {obj.name!r} is selected. Select some first"
        )
    attrs = bridge.read_attributes(geom, [n for n in bridge.attribute_names(geom) if n != SELECTED])
    collection = obj.users_collection[0] if obj.users_collection else context.scene.collection
    new = bridge.new_point_cloud_object(
        f"{obj.name} selection", attrs.pop("position")[1][sel], collection
    )
    for name, (data_type, values) in attrs.items():
        bridge.write_attribute(new.data, name, values[sel], data_type=data_type)
    for key in (
        source.PATH_PROP,
        source.FORMAT_PROP,
        source.KIND_PROP,
        "divas_grid_shape",
        "divas_grid_aabb",
        "divas_frame",
        "divas_up_reason",
    ):
        if key in obj:
            new[key] = obj[key]
    new.matrix_world = obj.matrix_world.copy()
    old_mod = obj.modifiers.get(display.MODIFIER)
    if old_mod is not None:
        display.copy_display_inputs(old_mod, display.add_display_modifier(new))
    obj.select_set(False)
    new.select_set(True)
    context.view_layer.objects.active = new
    return new

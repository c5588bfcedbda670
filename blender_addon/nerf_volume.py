"""NeRF density grids as Blender Volume objects (import display and segmented results).

Blender builds volume grids only from OpenVDB files, so the engine writes the grid
(:func:`divas_engine.io.openvdb_grid.write_vdb`: ``density`` σ per unit, and ``color``: its
RGB grid or an instant-ngp network's colour baked at the voxels) into the extension's user
folder, keyed by content, and a Volume datablock reads it. Its Principled Volume material
emits as a NeRF renders (``_material``), so Cycles and EEVEE show the medium the grid
describes; the object's transform carries the axis conversion only, no scale. On import the
Volume is an unselectable child of the grid's session object (the point cloud of occupied
voxels), so clicks reach the session object; a segmented result is a new, selectable Volume
of the masked density. In full: docs/design-notes.md.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from divas_engine.errors import DivasInputError
from divas_engine.scene import DensityGrid

__all__ = [
    "MATERIAL",
    "VOLUME_PROP",
    "volume_dir",
    "grid_colors",
    "write_grid_vdb",
    "new_volume_object",
    "segmented_volume",
    "add_display_volume",
    "display_volume_of",
]

MATERIAL = "DivAS NeRF Volume"
#: custom property of a DivAS volume: "display" (child of a session object) or "segment"
VOLUME_PROP = "divas_volume"
ADDON_ID = "divas"


def volume_dir() -> Path:
    """The add-on's user folder for the ``.vdb`` files its volumes read (created)."""
    try:
        path = bpy.utils.extension_path_user(ADDON_ID, path="volumes", create=True)
    except ValueError:  # registered as a plain add-on (tests), not as an extension
        path = bpy.utils.user_resource("DATAFILES", path="divas/volumes", create=True)
    return Path(path)


def grid_colors(grid: DensityGrid) -> np.ndarray | None:
    """The colour a volume of ``grid`` shows: its RGB grid, else its network's colour
    baked at the occupied voxels, else None."""
    if grid.rgb is not None:
        return grid.rgb
    from divas_engine.render.ngp_renderer import bake_network_colors, has_ngp_network

    if has_ngp_network(grid):
        return bake_network_colors(grid, "cpu")
    return None


def write_grid_vdb(grid: DensityGrid, density: np.ndarray | None, tag: str) -> Path:
    """Write ``grid`` (its density, or ``density`` on its lattice) with :func:`grid_colors`
    to the volume folder under a content-keyed name; an existing file is reused."""
    from divas_engine.io.openvdb_grid import write_vdb

    from .compat import openvdb

    openvdb()  # Blender's own module where it has one (else the engine's NumPy writer)
    dens = np.asarray(grid.density if density is None else density, np.float32)
    h = hashlib.sha1(dens.tobytes())
    h.update(np.asarray(grid.aabb, np.float64).tobytes())
    rgb = grid_colors(grid)
    if rgb is not None:
        h.update(np.asarray(rgb, np.float32).tobytes())
    path = volume_dir() / f"{tag}_{h.hexdigest()[:16]}.vdb"
    if not path.is_file():
        from divas_engine.point_attributes import srgb_to_linear

        # NeRF colours are display-referred; Blender emits linear light
        lin = None if rgb is None else srgb_to_linear(np.clip(rgb, 0, 1)).astype(np.float32)
        write_vdb(path, DensityGrid(dens, grid.aabb, lin))
    return path


def _material() -> bpy.types.Material:
    """NeRF's own image formation, ``C = ∫ T σ c dt``: an absorbing medium of coefficient
    σ (``density``) that emits ``σ c`` (``color``, grey without one); no scattering, so the
    volume looks as the NeRF renders it whatever the scene's lights."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL)
    if mat.node_tree is None:  # Blender < 5.0 makes the node tree on request
        mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    dens = nt.nodes.new("ShaderNodeAttribute")
    dens.attribute_name = "density"
    col = nt.nodes.new("ShaderNodeAttribute")
    col.attribute_name = "color"
    # no colour grid: the attribute reads 0 everywhere; show grey there
    length = nt.nodes.new("ShaderNodeVectorMath")
    length.operation = "LENGTH"
    has = nt.nodes.new("ShaderNodeMath")
    has.operation = "GREATER_THAN"
    has.inputs[1].default_value = 0.0
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["A"].default_value = (0.45, 0.45, 0.45, 1.0)
    nt.links.new(col.outputs["Vector"], length.inputs[0])
    nt.links.new(length.outputs["Value"], has.inputs[0])
    nt.links.new(has.outputs["Value"], mix.inputs["Factor"])
    nt.links.new(col.outputs["Color"], mix.inputs["B"])
    absorb = nt.nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    nt.links.new(dens.outputs["Fac"], absorb.inputs["Density"])
    emit = nt.nodes.new("ShaderNodeEmission")
    nt.links.new(mix.outputs["Result"], emit.inputs["Color"])
    nt.links.new(dens.outputs["Fac"], emit.inputs["Strength"])
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(absorb.outputs["Volume"], add.inputs[0])
    nt.links.new(emit.outputs["Emission"], add.inputs[1])
    nt.links.new(add.outputs["Shader"], out.inputs["Volume"])
    return mat


def new_volume_object(
    context, name: str, vdb_path: Path, matrix: np.ndarray, kind: str, parent=None
) -> bpy.types.Object:
    """A Volume object reading ``vdb_path`` with the DivAS volume material."""
    vol = bpy.data.volumes.new(name)
    vol.filepath = str(vdb_path)
    vol.grids.load()
    if not len(vol.grids):
        raise DivasInputError(vdb_path, "Blender read no grid from this volume file")
    vol.materials.append(_material())
    obj = bpy.data.objects.new(name, vol)
    (context.collection or context.scene.collection).objects.link(obj)
    obj[VOLUME_PROP] = kind
    if parent is not None:
        obj.parent = parent
        obj.matrix_parent_inverse.identity()
        obj.matrix_local = Matrix.Identity(4)
    else:
        obj.matrix_world = Matrix(np.asarray(matrix, float).tolist())
    return obj


def add_display_volume(context, obj, grid: DensityGrid) -> bpy.types.Object:
    """Show ``grid`` as a Volume child of its session object ``obj`` (module docstring)."""
    path = write_grid_vdb(grid, None, "display")
    vol = new_volume_object(context, f"{obj.name} Volume", path, np.eye(4), "display", obj)
    vol.hide_select = True
    obj.display_type = "BOUNDS"
    obj.hide_render = True
    return vol


def display_volume_of(obj) -> bpy.types.Object | None:
    """The display Volume of a grid's session object, or None."""
    for c in getattr(obj, "children", ()):
        if c.type == "VOLUME" and c.get(VOLUME_PROP) == "display":
            return c
    return None


def segmented_volume(context, obj) -> bpy.types.Object:
    """A new, selectable Volume of ``obj``'s grid with the density zeroed outside its
    ``divas_selected`` voxels, in ``obj``'s frame; it becomes the active object."""
    from . import source

    ref = source.source_of(obj)
    if ref is None or ref.kind != "grid":
        raise DivasInputError(None, "the active object is not a NeRF grid imported with DivAS")
    grid = source.load_source_scene(ref)
    sel = source.selection_of(obj, grid)
    if not sel.any():
        raise DivasInputError(
            None, "nothing is selected: segment the object in a DivAS session first"
        )
    masked = np.where(sel, grid.density, 0).astype(np.float32)
    path = write_grid_vdb(grid, masked, "segment")
    new = new_volume_object(
        context, f"{obj.name} Segment", path, np.array(obj.matrix_world), "segment"
    )
    new["divas_voxels"] = int(sel.sum())
    for o in context.view_layer.objects:
        if o.select_get():
            o.select_set(False)
    new.select_set(True)
    context.view_layer.objects.active = new
    return new

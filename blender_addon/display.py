"""How imported splats and voxels look: one Geometry Nodes group, two materials, a quad.

Every imported point cloud gets the modifier "DivAS Display" running the node group "DivAS
Splat Display" (:mod:`.display_nodes`). Per splat it computes the display colour — the linear
``divas_color``, or with *View-Dependent Colour* the SH colour ``0.5 + Σ Y_k(d) c_k`` along the
direction ``d`` from the **scene camera**, decoded to linear — tinted where ``divas_selected``
is set, and shows it as **Splats** (a quad per splat of extent :data:`QUAD_EXTENT`, the 2DGS
cut-off √(2 ln 255) σ, material "DivAS Splat" evaluating ``α = min(0.99, opacity ·
exp(−(u²+v²)/2))``) or **Points** (material "DivAS Points", cheap for huge scenes).

The SH colour follows the scene camera, not the viewport: a shader sees the splat only after
instancing, where the object's rotation is no longer separable from the splat's own. Without
view-dependent colour the modifier runs the fixed-colour variant, which has no camera node, so
a session's camera switches do not re-evaluate the display (:func:`sync_display_group`); in
Solid mode the point display shows no splat colour, so the SH colour is skipped there unless
:func:`sync_viewport_colours` turns *Viewport Colours* on. Details: docs/design-notes.md.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from divas_engine.point_attributes import COLOR, sh_attribute_name

from . import bridge, compat, display_nodes

__all__ = [
    "DISPLAY_GROUP",
    "DISPLAY_GROUP_FIXED",
    "MATERIAL",
    "POINTS_MATERIAL",
    "MODIFIER",
    "QUAD_OBJECT",
    "SELECTED_TINT",
    "SPLATS_MAX_POINTS",
    "QUAD_EXTENT",
    "DisplayInputs",
    "ensure_material",
    "ensure_points_material",
    "ensure_display_group",
    "add_display_modifier",
    "set_display_inputs",
    "display_inputs",
    "copy_display_inputs",
    "sync_display_group",
    "display_group_outdated",
    "setup_scene_for_splats",
    "viewport_shows_colours",
    "sync_viewport_colours",
]

DISPLAY_GROUP = "DivAS Splat Display"
#: the camera-free variant (module docstring): View-Dependent Colour off or no SH.
DISPLAY_GROUP_FIXED = "DivAS Splat Display (Fixed Colour)"
MATERIAL = "DivAS Splat"
POINTS_MATERIAL = "DivAS Points"
MODIFIER = "DivAS Display"
QUAD_OBJECT = "DivAS Splat Quad"
#: colour (linear) mixed into selected points at half strength so they stand out.
SELECTED_TINT = (1.0, 0.35, 0.05, 1.0)
#: above this many splats an import shows points by default (the quads of 3M splats
#: take ~650 MB once realised).
SPLATS_MAX_POINTS = 1_000_000
#: quad half-size in σ: where a fully opaque Gaussian's α·G drops below 1/255.
QUAD_EXTENT = math.sqrt(2.0 * math.log(255.0))
#: bumped when the node group or a material changes; older ones are rebuilt.
VERSION = 8
_VERSION_PROP = "divas_display_version"


class DisplayInputs:
    """Modifier input names of the display group (the panel and operators set them)."""

    POINTS = "Points"
    SIZE = "Size"
    OPACITY_THRESHOLD = "Opacity Threshold"
    VIEW_DEPENDENT = "View-Dependent Colour"
    SH_RANGE = "SH Range"
    MAX_RADIUS = "Max Radius"
    VIEWPORT_COLOURS = "Viewport Colours"


#: 3D-view shading types that draw the splats' colours for the point display (Solid
#: and Wireframe draw point clouds in their material colour).
COLOUR_SHADINGS = frozenset({"MATERIAL", "RENDERED"})


def _outdated(idblock) -> bool:
    return idblock is not None and idblock.get(_VERSION_PROP) != VERSION


def _fresh_material(name: str) -> bpy.types.Material:
    mat = bpy.data.materials.get(name)
    if mat is None:
        mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    mat.node_tree.nodes.clear()
    mat[_VERSION_PROP] = VERSION
    if hasattr(mat, "surface_render_method"):
        mat.surface_render_method = "DITHERED"
    mat.use_backface_culling = False
    return mat


def ensure_material() -> bpy.types.Material:
    """The splat material (Gaussian alpha on the quad, module docstring)."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None and not _outdated(mat):
        return mat
    mat = _fresh_material(MATERIAL)
    display_nodes.build_splat_material(mat.node_tree)
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    return mat


def ensure_points_material() -> bpy.types.Material:
    """The point material: the display colour, opacity as alpha."""
    mat = bpy.data.materials.get(POINTS_MATERIAL)
    if mat is not None and not _outdated(mat):
        return mat
    mat = _fresh_material(POINTS_MATERIAL)
    display_nodes.build_points_material(mat.node_tree)
    return mat


def ensure_quad_object() -> bpy.types.Object:
    """The unit quad each splat instances (never linked into a scene): corners at ±1,
    ``divas_quad_uv`` = corners × :data:`QUAD_EXTENT` (σ units) and the active colour
    attribute ``divas_display`` the realised mesh inherits (so Solid mode shows it)."""
    obj = bpy.data.objects.get(QUAD_OBJECT)
    if obj is not None and obj.type == "MESH" and not _outdated(obj):
        return obj
    mesh = bpy.data.meshes.new(QUAD_OBJECT)
    corners = [(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1.0, 0.0), (-1.0, 1.0, 0.0)]
    mesh.from_pydata(corners, [], [(0, 1, 2, 3)])
    uv = mesh.attributes.new(display_nodes.QUAD_UV, "FLOAT2", "CORNER")
    uv.data.foreach_set("vector", (np.array(corners)[:, :2] * QUAD_EXTENT).ravel())
    col = mesh.color_attributes.new(display_nodes.DISPLAY_COLOR, "FLOAT_COLOR", "POINT")
    mesh.color_attributes.active_color = col
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    for name in [a.name for a in mesh.attributes if a.name.startswith(".select")]:
        mesh.attributes.remove(mesh.attributes[name])
    if obj is None:
        obj = bpy.data.objects.new(QUAD_OBJECT, mesh)
    else:
        old = obj.data
        obj.data = mesh
        if old is not None and old.users == 0:
            bpy.data.meshes.remove(old)
    obj[_VERSION_PROP] = VERSION
    return obj


def ensure_display_group(view_dependent: bool = True) -> bpy.types.GeometryNodeTree:
    """The display node group (module docstring), rebuilt in place when outdated;
    ``view_dependent=False``: the fixed-colour variant without a camera dependency."""
    name = DISPLAY_GROUP if view_dependent else DISPLAY_GROUP_FIXED
    ng = bpy.data.node_groups.get(name)
    if ng is not None and not _outdated(ng):
        return ng
    if ng is None:
        ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    else:
        ng.nodes.clear()
        ng.interface.clear()
    ng[_VERSION_PROP] = VERSION
    display_nodes.build_display_group(
        ng,
        splat_material=ensure_material(),
        points_material=ensure_points_material(),
        quad=ensure_quad_object(),
        tint=SELECTED_TINT,
        version=VERSION,
        view_dependent=view_dependent,
    )
    return ng


def _wants_view_dependent(mod) -> bool:
    """Whether ``mod`` needs the camera: View-Dependent Colour on and SH on the points
    (the view-dependent group shows the DC colour otherwise)."""
    ident = _input_ids(mod).get(DisplayInputs.VIEW_DEPENDENT)
    on = compat.modifier_input(mod, ident) if ident is not None else None
    if on is not None and not on:
        return False
    data = getattr(mod.id_data, "data", None)
    attrs = getattr(data, "attributes", None)
    return attrs is not None and attrs.get(sh_attribute_name(1)) is not None


def _is_ours(mod) -> bool:
    ng = mod.node_group if mod is not None and mod.type == "NODES" else None
    return ng is not None and ng.name in (DISPLAY_GROUP, DISPLAY_GROUP_FIXED)


def display_group_outdated(mod) -> bool:
    """``mod`` runs one of the display groups, not the one its inputs call for."""
    if not _is_ours(mod):
        return False
    return (mod.node_group.name == DISPLAY_GROUP) != _wants_view_dependent(mod)


def sync_display_group(mod) -> bool:
    """Give ``mod`` the display variant its inputs call for (module docstring), keeping
    every input value; returns whether the group changed. A user's own group is left."""
    if not display_group_outdated(mod):
        return False
    values = {k: v for k, v in display_inputs(mod).items() if v is not None}
    mod.node_group = ensure_display_group(mod.node_group.name != DISPLAY_GROUP)
    ids = _input_ids(mod)
    for name, value in values.items():
        if name in ids:
            compat.set_modifier_input(mod, ids[name], value)
    mod.id_data.update_tag()
    return True


def _input_ids(mod) -> dict[str, str]:
    return {
        item.name: item.identifier
        for item in mod.node_group.interface.items_tree
        if getattr(item, "in_out", None) == "INPUT" and item.socket_type != "NodeSocketGeometry"
    }


def set_display_inputs(mod, **values) -> None:
    """Set display-group inputs on modifier ``mod`` by their names
    (:class:`DisplayInputs`), e.g. ``set_display_inputs(mod, **{"Size": 0.5})``."""
    ids = _input_ids(mod)
    for name, value in values.items():
        if name not in ids:
            raise KeyError(f"the display group has no input {name!r}")
        compat.set_modifier_input(
            mod, ids[name], tuple(value) if isinstance(value, list | tuple) else value
        )
    sync_display_group(mod)
    mod.node_group.interface_update(bpy.context)
    mod.id_data.update_tag()


def display_inputs(mod) -> dict[str, object]:
    """The modifier's display-group input values by name."""
    out = {}
    for name, ident in _input_ids(mod).items():
        v = compat.modifier_input(mod, ident)
        out[name] = tuple(v) if hasattr(v, "__len__") and not isinstance(v, str) else v
    return out


def copy_display_inputs(src, dst) -> None:
    """Give modifier ``dst`` the display-input values of ``src`` that its group has (e.g.
    the *Size* a user set, for an extracted copy)."""
    if src.node_group is None:
        return
    ids = _input_ids(dst)
    values = {k: v for k, v in display_inputs(src).items() if k in ids and v is not None}
    set_display_inputs(dst, **values)


def add_display_modifier(
    obj: bpy.types.Object,
    *,
    points: bool | None = None,
    sh_range=(0.0, 0.0, 0.0),
    max_radius: float = 0.0,
) -> bpy.types.Modifier:
    """Give ``obj`` the display modifier (and both materials in its slots).

    ``points``: the fast point display (None: points above :data:`SPLATS_MAX_POINTS`
    splats, or when the object has no ``divas_rotation``, e.g. a density grid);
    ``sh_range``: the per-band ranges of the ``divas_sh_*`` codes; ``max_radius``: the
    point radius clip (0: none).
    """
    mod = obj.modifiers.get(MODIFIER) or obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = ensure_display_group()
    for mat in (ensure_material(), ensure_points_material()):
        if mat.name not in obj.data.materials:
            obj.data.materials.append(mat)
    if points is None:
        n = bridge.point_count(obj.data)
        has_frame = obj.data.attributes.get("divas_rotation") is not None
        points = n > SPLATS_MAX_POINTS or not has_frame
    set_display_inputs(
        mod,
        **{
            DisplayInputs.POINTS: bool(points),
            DisplayInputs.SH_RANGE: [float(r) for r in sh_range],
            DisplayInputs.MAX_RADIUS: float(max_radius),
            DisplayInputs.VIEWPORT_COLOURS: viewport_shows_colours(),
        },
    )
    return mod


def viewport_shows_colours(wm=None) -> bool:
    """Whether a 3D view of ``wm`` (default: the running window manager) is in a shading
    that draws the point display's colours (:data:`COLOUR_SHADINGS`); False with no
    window (headless)."""
    if wm is None:
        wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type != "VIEW_3D":
                continue
            for space in area.spaces:
                if space.type == "VIEW_3D" and space.shading.type in COLOUR_SHADINGS:
                    return True
    return False


def sync_viewport_colours(shows: bool | None = None) -> list[str]:
    """Set *Viewport Colours* of every DivAS display modifier to ``shows`` (default:
    :func:`viewport_shows_colours`) where it differs; returns the objects changed."""
    if shows is None:
        shows = viewport_shows_colours()
    changed = []
    for obj in bpy.data.objects:
        mod = obj.modifiers.get(MODIFIER)
        if not _is_ours(mod):
            continue
        ident = _input_ids(mod).get(DisplayInputs.VIEWPORT_COLOURS)
        current = compat.modifier_input(mod, ident) if ident is not None else None
        if current is None or bool(current) == shows:
            continue
        compat.set_modifier_input(mod, ident, shows)
        obj.update_tag()
        changed.append(obj.name)
    return changed


def setup_scene_for_splats(scene: bpy.types.Scene, context=None) -> None:
    """Render settings splats need (never lowered): the Standard view transform (so the
    decoded colours display as captured), enough Cycles transparent bounces to see
    through stacked splats, EEVEE samples for the dithered alpha to converge, and
    *Attribute* colour for Solid mode (the open 3D views and Workbench renders) so it
    shows the splats' colour attribute."""
    scene.display.shading.color_type = "VERTEX"
    wm = getattr(context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            for space in area.spaces:
                if space.type == "VIEW_3D":
                    space.shading.color_type = "VERTEX"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    cycles = getattr(scene, "cycles", None)
    if cycles is not None:
        cycles.transparent_max_bounces = max(cycles.transparent_max_bounces, 128)
    eevee = getattr(scene, "eevee", None)
    if eevee is not None:
        eevee.taa_render_samples = max(eevee.taa_render_samples, 64)


def is_splat_display(obj) -> bool:
    mod = obj.modifiers.get(MODIFIER) if obj is not None else None
    return mod is not None and mod.node_group is not None and COLOR in obj.data.attributes

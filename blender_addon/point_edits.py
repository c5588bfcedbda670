"""Manual selection and editing of an imported object's splats (box, lasso, brush,
sphere, all / none / invert, grow / shrink, by opacity or size; delete, hide, reveal,
separate) — the ``bpy`` half; the geometry is :mod:`divas_engine.selection_tools`.

The selection lives on the points (``divas_selected``). With a live session every edit
goes through the engine (:meth:`~divas_engine.session.Session.apply_selection` and
friends), so it composes with the semantic selection — a splat removed by hand stays
removed when a later view is fused — and exports and labels follow it; without one,
the attribute is written directly. Hidden splats (``divas_hidden``) are left out of
every tool, deselected, and not drawn: a Geometry Nodes modifier "DivAS Hide" removes
them from the evaluated object. Deleting rebuilds the point cloud without the deleted
points (the session also drops them from every selection, label and export).
"""

from __future__ import annotations

import bpy
import numpy as np

from divas_engine.errors import DivasInputError
from divas_engine.point_attributes import COLOR, INDEX, SELECTED, point_values, scene_selection
from divas_engine.selection_tools import SelectMode, combine

from . import bridge, session_registry, source
from .session_actions.points import write_selection

__all__ = [
    "HIDDEN",
    "HIDE_MODIFIER",
    "EditTarget",
    "edit_target",
    "positions",
    "selected",
    "visible",
    "point_sizes",
    "apply_region",
    "set_selection",
    "delete_selected",
    "hide",
    "reveal",
    "separate_selected",
    "as_step",
]

HIDDEN = "divas_hidden"
HIDE_MODIFIER, HIDE_GROUP = "DivAS Hide", "DivAS Hide Points"


class EditTarget:
    """An object whose points can be edited, with its live session (or None)."""

    def __init__(self, obj, live) -> None:
        self.obj, self.live = obj, live

    @property
    def geom(self):
        return self.obj.data


def edit_target(context) -> EditTarget:
    """The active DivAS point cloud, or the scene camera's session object."""
    obj = context.active_object
    if source.source_of(obj) is None:
        owner, live = session_registry.find(context)
        if owner is None:
            raise DivasInputError(
                None, "Select splats imported with DivAS first (click them in the viewport)"
            )
        return EditTarget(owner, live)
    return EditTarget(obj, session_registry.get(obj))


# ----------------------------------------------------------------------------- reading
def positions(t: EditTarget) -> np.ndarray:
    """``[N,3]`` point positions in the object's frame (the session's scene frame)."""
    return bridge.read_attribute(t.geom, "position")


def selected(t: EditTarget) -> np.ndarray:
    geom = t.geom
    if geom.attributes.get(SELECTED) is None:
        return np.zeros(bridge.point_count(geom), bool)
    return bridge.read_attribute(geom, SELECTED).astype(bool)


def visible(t: EditTarget) -> np.ndarray:
    geom = t.geom
    if geom.attributes.get(HIDDEN) is None:
        return np.ones(bridge.point_count(geom), bool)
    return ~bridge.read_attribute(geom, HIDDEN).astype(bool)


def point_opacities(t: EditTarget) -> np.ndarray:
    """Per-point opacity α: the alpha of the linear display colour (surfels: the splat's
    opacity; density grids: the cell opacity ``1 − exp(−σ·voxel)``)."""
    return bridge.read_attribute(t.geom, COLOR)[:, 3].astype(np.float64)


def point_sizes(t: EditTarget) -> np.ndarray:
    """Per-point size in scene units: the splat's ``sqrt(s₁ s₂)`` (unclipped) for surfel
    scenes, else the display radius (density grids: half a voxel)."""
    ref = source.source_of(t.obj)
    if ref is not None and ref.kind != "grid":
        try:
            scene = t.live.session.scene if t.live else source.load_source_scene(ref)
            s = np.sqrt(scene.scales[:, 0].astype(np.float64) * scene.scales[:, 1])
            return point_values(scene, bridge.read_attribute(t.geom, INDEX), s)
        except (DivasInputError, KeyError, ValueError, AttributeError):
            pass
    return bridge.read_attribute(t.geom, "divas_radius").astype(np.float64)


# ----------------------------------------------------------------------------- writing
def set_selection(t: EditTarget, new: np.ndarray, *, autosave: bool = True) -> int:
    """Make the points' selection ``new`` (through the session when there is one; its
    autosave skipped with ``autosave=False``, e.g. mid brush stroke); returns how many
    points are selected."""
    from . import draw

    draw.touch()  # the selection tint is drawn from the points' attribute
    new = np.asarray(new, bool)
    if t.live is None:
        bridge.write_attribute(t.geom, SELECTED, new)
        t.geom.update_tag()
        return int(new.sum())
    s = t.live.session
    index = bridge.read_attribute(t.geom, INDEX)
    within = scene_selection(s.scene, index, np.ones(len(index), bool))
    s.apply_selection(scene_selection(s.scene, index, new), within=within, autosave=autosave)
    write_selection(t.obj, t.live)
    return int(selected(t).sum())


def apply_region(
    t: EditTarget, region: np.ndarray, mode: SelectMode | str, *, autosave: bool = True
) -> int:
    """Combine a tool's region with the selection in ``mode``; hidden points never
    change. Returns how many points are selected."""
    cur, ok = selected(t), visible(t)
    new = np.where(ok, combine(cur, np.asarray(region, bool) & ok, mode), cur)
    return set_selection(t, new, autosave=autosave)


def _engine_mask(t: EditTarget, points_mask: np.ndarray) -> np.ndarray:
    index = bridge.read_attribute(t.geom, INDEX)
    return scene_selection(t.live.session.scene, index, points_mask)


def _keep_points(context, t: EditTarget, keep: np.ndarray) -> None:
    """Rebuild ``t.obj``'s point cloud with the ``keep`` points and all their attributes
    (the materials and modifiers stay on the object)."""
    old = t.geom
    attrs = bridge.read_attributes(old)
    pos = attrs.pop("position")[1][keep]
    tmp = bridge.new_point_cloud_object(f"{t.obj.name} (kept)", pos, context.scene.collection)
    new = tmp.data
    for name, (data_type, values) in attrs.items():
        bridge.write_attribute(new, name, values[keep], data_type=data_type)
    for mat in old.materials:
        new.materials.append(mat)
    bpy.data.objects.remove(tmp)
    name = old.name
    t.obj.data = new
    if old.users == 0:
        bpy.data.pointclouds.remove(old)
    new.name = name


def delete_selected(context, t: EditTarget) -> int:
    """Delete the selected points (from the object and, with a session, from every
    selection, label and export); returns how many."""
    sel = selected(t) & visible(t)
    n = int(sel.sum())
    if n == 0:
        raise DivasInputError(
            None, "Nothing is selected, so nothing was deleted: select splats first"
        )
    if n == len(sel):
        raise DivasInputError(
            None,
            "Every splat is selected: deleting them would leave the object empty. Delete the "
            "object itself (X), or deselect what you want to keep",
        )
    if t.live is not None:
        t.live.session.delete_primitives(_engine_mask(t, sel))
    _keep_points(context, t, ~sel)
    if t.live is not None:
        write_selection(t.obj, t.live, full=True)  # a new point cloud
    return n


def _hide_modifier(obj) -> None:
    """A first Geometry Nodes modifier deleting the points whose ``divas_hidden`` is set."""
    ng = bpy.data.node_groups.get(HIDE_GROUP)
    if ng is None:
        ng = bpy.data.node_groups.new(HIDE_GROUP, "GeometryNodeTree")
        ng.is_modifier = True
        ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
        attr = ng.nodes.new("GeometryNodeInputNamedAttribute")
        attr.data_type = "BOOLEAN"
        attr.inputs["Name"].default_value = HIDDEN
        delete = ng.nodes.new("GeometryNodeDeleteGeometry")
        delete.domain = "POINT"
        ng.links.new(gin.outputs["Geometry"], delete.inputs["Geometry"])
        ng.links.new(attr.outputs["Attribute"], delete.inputs["Selection"])
        ng.links.new(delete.outputs["Geometry"], gout.inputs["Geometry"])
        gin.location, attr.location, delete.location, gout.location = (
            (-400, 0),
            (-400, -150),
            (-150, 0),
            (100, 0),
        )
    mod = obj.modifiers.get(HIDE_MODIFIER)
    if mod is None:
        mod = obj.modifiers.new(HIDE_MODIFIER, "NODES")
        obj.modifiers.move(len(obj.modifiers) - 1, 0)
    mod.node_group = ng


def hide(t: EditTarget, *, unselected: bool = False) -> int:
    """Hide the selected (or the unselected) visible points; they are deselected.
    Returns how many were hidden."""
    ok = visible(t)
    sel = selected(t)
    mask = ok & (~sel if unselected else sel)
    n = int(mask.sum())
    if n == 0:
        what = "unselected" if unselected else "selected"
        raise DivasInputError(None, f"No {what} splat is visible, so nothing was hidden")
    if t.live is not None:
        t.live.session.hide_primitives(_engine_mask(t, mask))
        write_selection(t.obj, t.live)
    else:
        bridge.write_attribute(t.geom, SELECTED, sel & ~mask)
    bridge.write_attribute(t.geom, HIDDEN, ~ok | mask)
    _hide_modifier(t.obj)
    t.geom.update_tag()
    return n


def reveal(t: EditTarget) -> int:
    """Show every hidden point again (deselected); returns how many."""
    n = int((~visible(t)).sum())
    if t.live is not None:
        t.live.session.reveal_primitives()
    if t.geom.attributes.get(HIDDEN) is not None:
        bridge.remove_attribute(t.geom, HIDDEN)
    t.geom.update_tag()
    return n


def separate_selected(context, t: EditTarget):
    """Move the selected points into a new object (with the same source link and
    display); they are deleted from this one. Returns the new object."""
    from .selection import extract_selection

    sel = selected(t) & visible(t)
    if not sel.any():
        raise DivasInputError(
            None, "Nothing is selected, so nothing was separated: select splats first"
        )
    obj = t.obj
    new = extract_selection(context, obj)
    for name in (HIDDEN,):
        if new.data.attributes.get(name) is not None:
            bridge.remove_attribute(new.data, name)
    context.view_layer.objects.active = obj
    delete_selected(context, t)
    context.view_layer.objects.active = new
    return new


def as_step(t: EditTarget, what: str, fn, *args, **kwargs):
    """``fn`` as one session step when ``t`` has a session (:func:`..session_actions.run_step`),
    else a plain call (Blender's undo restores the points by itself)."""
    from .session_actions import run_step

    if t.live is None:
        return fn(*args, **kwargs)
    return run_step(t.obj, t.live, what, fn, *args, **kwargs)

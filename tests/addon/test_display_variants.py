"""The display's two node-group variants: with *View-Dependent Colour* off, or
without SH on the points, the modifier runs the fixed-colour group, which has no camera
dependency — switching or moving the scene camera (every click and accept of a session
does) does not re-evaluate the display — and shows exactly what the view-dependent group
shows with the SH colour switched off (every colour, position and radius, bit-equal)."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from blender_addon import bridge, compat, display, handlers
from divas_engine.point_attributes import SELECTED


@pytest.fixture(scope="module")
def sh3(tmp_path_factory):
    """A small synthetic 2DGS scene with SH degree 3 on disk."""
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_sh3")
    generate_scene("ribs", out, size=3000, seed=0, sh_degree=3, grid_resolution=32)
    return out / "scene.ply"


def _import(path, **kw) -> bpy.types.Object:
    assert bpy.ops.divas.import_splats(filepath=str(path), **kw) == {"FINISHED"}
    return bpy.context.active_object


def _cameras():
    cams = []
    for i, loc in enumerate(((0.3, -4.0, 1.0), (-3.0, 2.0, 2.5))):
        cam = bpy.data.objects.new(f"view {i}", bpy.data.cameras.new(f"view {i}"))
        cam.location = loc
        bpy.context.scene.collection.objects.link(cam)
        cams.append(cam)
    bpy.context.scene.camera = cams[0]
    return cams


def _raw_set(mod, name: str, value) -> None:
    """Set a modifier input as the modifier panel does (no variant switch)."""
    compat.set_modifier_input(mod, display._input_ids(mod)[name], value)
    mod.id_data.update_tag()
    bpy.context.view_layer.update()


def _evaluated(obj) -> dict[str, np.ndarray]:
    """Everything the display shows: points (position, radius, shade) or quads (vertex
    positions and their display colour)."""
    dg = bpy.context.evaluated_depsgraph_get()
    out = {}
    for inst in dg.object_instances:
        if inst.object.name != obj.name:
            continue
        data = inst.object.data
        if inst.object.type == "POINTCLOUD":
            n = len(data.points)
            for name, key, width in (
                ("position", "vector", 3),
                ("radius", "value", 1),
                (display.display_nodes.SHADE, "color", 4),
            ):
                if name not in data.attributes:
                    continue  # the splat display's empty point cloud
                a = np.empty(n * width, np.float32)
                data.attributes[name].data.foreach_get(key, a)
                out[f"points {name}"] = a
        elif inst.object.type == "MESH":
            n = len(data.vertices)
            a = np.empty(n * 3, np.float32)
            data.vertices.foreach_get("co", a)
            out["quad co"] = a
            c = np.empty(n * 4, np.float32)
            data.attributes[display.display_nodes.DISPLAY_COLOR].data.foreach_get("color", c)
            out["quad colour"] = c
    assert out, "the display evaluated to nothing"
    return out


@pytest.mark.parametrize("points", [True, False])
def test_fixed_colour_group_shows_the_same_display(sh3, points):
    obj = _import(sh3)
    _cameras()
    mod = obj.modifiers[display.MODIFIER]
    assert mod.node_group.name == display.DISPLAY_GROUP  # SH on the points, colour on
    sel = np.zeros(len(obj.data.points), bool)
    sel[::3] = True  # the selection tint goes through both variants too
    bridge.write_attribute(obj.data, SELECTED, sel)
    # (Viewport Colours: a 3D view shows material colours, so the points' SH colour is
    # evaluated in the viewport too; test_viewport_colours has it off)
    display.set_display_inputs(
        mod, **{"Points": points, "Opacity Threshold": 0.0, "Viewport Colours": True}
    )
    with_sh = _evaluated(obj)
    # View-Dependent Colour off, still on the view-dependent group (its DC branch)
    _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, False)
    assert mod.node_group.name == display.DISPLAY_GROUP
    before = _evaluated(obj)
    assert display.sync_display_group(mod)
    bpy.context.view_layer.update()
    assert mod.node_group.name == display.DISPLAY_GROUP_FIXED
    after = _evaluated(obj)
    assert before.keys() == after.keys()
    for k in before:
        np.testing.assert_array_equal(after[k], before[k], err_msg=k)
    # and it is the DC colour (NumPy reference), not the view-dependent one
    if points:
        shade = after[f"points {display.display_nodes.SHADE}"].reshape(-1, 4)
        dc = np.maximum(bridge.read_attribute(obj.data, "divas_color")[:, :3], 0)
        tint = np.array(display.SELECTED_TINT[:3], np.float32)
        want = np.where(sel[:, None], dc + 0.5 * (tint - dc), dc)
        np.testing.assert_allclose(shade[:, :3], want, atol=1e-6)
        assert (
            np.abs(
                with_sh[f"points {display.display_nodes.SHADE}"]
                - after[f"points {display.display_nodes.SHADE}"]
            ).max()
            > 1e-3
        )
    # every other input kept across the switch
    got = display.display_inputs(mod)
    assert got["Points"] is points or got["Points"] == points
    assert got["Opacity Threshold"] == 0.0 and not got[display.DisplayInputs.VIEW_DEPENDENT]


def _geometry_updates(fn) -> list[bool]:
    """Run ``fn``; per depsgraph update, whether the splat object's geometry re-evaluated."""
    seen: list[bool] = []

    def record(_scene, depsgraph):
        seen.append(
            any(
                u.is_updated_geometry
                for u in depsgraph.updates
                if isinstance(u.id, bpy.types.Object) and u.id.name == "scene"
            )
        )

    bpy.app.handlers.depsgraph_update_post.append(record)
    try:
        fn()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(record)
    return seen


def test_camera_switch_leaves_the_fixed_display_alone(sh3):
    obj = _import(sh3)
    assert obj.name == "scene"
    cams = _cameras()
    mod = obj.modifiers[display.MODIFIER]
    display.set_display_inputs(mod, **{"Points": True})
    bpy.context.view_layer.update()
    scene = bpy.context.scene

    def switch_and_move():
        scene.camera = cams[1]
        bpy.context.view_layer.update()
        cams[1].location.x += 0.5
        bpy.context.view_layer.update()
        scene.camera = cams[0]
        bpy.context.view_layer.update()

    # view-dependent: the camera is an input of the display (the check can fail)
    assert any(_geometry_updates(switch_and_move))
    display.set_display_inputs(mod, **{display.DisplayInputs.VIEW_DEPENDENT: False})
    assert mod.node_group.name == display.DISPLAY_GROUP_FIXED
    bpy.context.view_layer.update()
    dg = bpy.context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(dg).data.as_pointer()
    seen = _geometry_updates(switch_and_move)
    assert seen and not any(seen)
    assert obj.evaluated_get(dg).data.as_pointer() == evaluated  # not rebuilt
    # a selection change still re-evaluates it
    bridge.write_attribute(obj.data, SELECTED, np.ones(len(obj.data.points), bool))

    def reselect():
        obj.data.update_tag()
        bpy.context.view_layer.update()

    assert any(_geometry_updates(reselect))


def test_panel_toggle_switches_the_variant(sh3):
    """The input toggled in the modifier panel: the depsgraph handler schedules the switch
    (a timer; headless tests run it by hand), both ways."""
    obj = _import(sh3)
    _cameras()
    mod = obj.modifiers[display.MODIFIER]
    _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, False)
    assert bpy.app.timers.is_registered(handlers._display_timer)
    bpy.app.timers.unregister(handlers._display_timer)
    handlers._display_timer()
    assert mod.node_group.name == display.DISPLAY_GROUP_FIXED
    _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, True)
    assert bpy.app.timers.is_registered(handlers._display_timer)
    bpy.app.timers.unregister(handlers._display_timer)
    handlers._display_timer()
    assert mod.node_group.name == display.DISPLAY_GROUP
    assert display.display_inputs(mod)[display.DisplayInputs.VIEW_DEPENDENT]


def test_scene_without_sh_gets_the_fixed_group(tmp_path):
    from divas_engine.synthetic import generate_scene

    generate_scene("ribs", tmp_path, size=2000, seed=0, sh_degree=0, grid_resolution=32)
    obj = _import(tmp_path / "scene.ply")
    mod = obj.modifiers[display.MODIFIER]
    assert mod.node_group.name == display.DISPLAY_GROUP_FIXED
    assert display.display_inputs(mod)[display.DisplayInputs.VIEW_DEPENDENT]  # as imported

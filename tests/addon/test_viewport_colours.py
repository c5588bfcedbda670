"""*Viewport Colours*: Solid mode draws the point display in its material
colour, so while no 3D view shows material colours the view-dependent group takes the
fixed colour in the viewport — its SH nodes are not evaluated when a click switches the
scene camera — and everything that can show the colours is unchanged:

* a Workbench (Solid) render of the points is pixel-identical with the SH colour on or
  off (what the gate relies on);
* with the input on (a 3D view in Material Preview / Rendered), the viewport's point
  colours are the SH colour (NumPy reference: ``srgb_to_linear(max(0, Σ Y_k(d) c_k))``)
  and bit-equal to what the group gave before the gate (no gate node at all);
* off, they are exactly the fixed colour, bit-equal to the camera-free group's;
* the splat (quad) display, which Solid mode does show in colour, keeps the SH colour;
* renders (not the viewport) evaluate the SH colour either way: a Cycles render with the
  input off equals the one with it on, and differs from the fixed colour's;
* the add-on sets the input from the 3D views' shading (checked on every 3D-view redraw,
  written from a timer).
"""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from blender_addon import bridge, display, display_nodes, handlers
from divas_engine.point_attributes import (
    SELECTED,
    dequantize_sh,
    linear_to_srgb,
    sh_attribute_name,
    srgb_to_linear,
)
from divas_engine.sh_rotation import SH_C0, eval_sh
from tests.addon.test_display_variants import _cameras, _evaluated, _import, _raw_set

VC = display.DisplayInputs.VIEWPORT_COLOURS
SHADE = f"points {display_nodes.SHADE}"


@pytest.fixture(scope="module")
def sh3(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_sh3_vc")
    generate_scene("ribs", out, size=3000, seed=0, sh_degree=3, grid_resolution=32)
    return out / "scene.ply"


def _numpy_sh_colour(obj, mod, cam) -> np.ndarray:
    """The display's SH colour from the stored codes (NumPy, float64): the DC colour
    re-encoded to sRGB plus ``Σ Y_k(d) c_k``, clamped at 0, decoded to linear."""
    ranges = np.array(display.display_inputs(mod)[display.DisplayInputs.SH_RANGE])
    codes = [bridge.read_attribute(obj.data, sh_attribute_name(k)) for k in range(1, 16)]
    lin = bridge.read_attribute(obj.data, "divas_color")[:, :3].astype(np.float64)
    dc = (linear_to_srgb(lin) - 0.5) / SH_C0
    sh = np.concatenate([dc[:, None, :], dequantize_sh(codes, ranges)], 1)
    pos = bridge.read_attribute(obj.data, "position").astype(np.float64)
    eye = np.linalg.inv(np.array(obj.matrix_world)) @ np.array([*cam.location, 1.0])
    d = pos - eye[:3]  # the camera in the object's frame (the import's up-axis turn)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return srgb_to_linear(np.maximum(eval_sh(sh, d), 0.0))


def _ungated_group(mod) -> None:
    """The group without the gate: its output Switch's True input wired past."""
    ng = mod.node_group
    gate = next(
        n
        for n in ng.nodes
        if n.bl_idname == "GeometryNodeSwitch"
        and any(
            link.from_node.bl_idname == "FunctionNodeBooleanMath"
            and link.from_node.operation == "IMPLY"
            for link in n.inputs["Switch"].links
        )
    )
    source = gate.inputs["True"].links[0].from_socket
    for link in list(gate.outputs[0].links):
        ng.links.new(source, link.to_socket)
    ng.nodes.remove(gate)


def test_solid_mode_shows_no_point_colours(sh3):
    """What the gate relies on: Workbench draws the points in the material colour."""
    obj = _import(sh3)
    _cameras()
    mod = obj.modifiers[display.MODIFIER]
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.color_type = "VERTEX"
    scene.render.resolution_x, scene.render.resolution_y = 96, 72
    pixels = []
    for vd in (True, False):
        display.set_display_inputs(mod, **{"Points": True, "Size": 3.0, VC: True})
        _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, vd)  # same group both times
        bpy.ops.render.render()
        pixels.append(_render_pixels())
    assert pixels[0].std() > 0.01  # the points are there
    np.testing.assert_array_equal(pixels[0], pixels[1])


def _render_pixels() -> np.ndarray:
    img = bpy.data.images["Render Result"]
    path = bpy.app.tempdir + "divas_vc_render.exr"
    img.save_render(path)
    loaded = bpy.data.images.load(path)
    px = np.empty(loaded.size[0] * loaded.size[1] * 4, np.float32)
    loaded.pixels.foreach_get(px)
    bpy.data.images.remove(loaded)
    return px


def test_viewport_point_colours_follow_the_input(sh3):
    obj = _import(sh3)
    cams = _cameras()
    mod = obj.modifiers[display.MODIFIER]
    assert display.display_inputs(mod)[VC] is False or display.display_inputs(mod)[VC] == 0
    sel = np.zeros(len(obj.data.points), bool)
    sel[::3] = True
    bridge.write_attribute(obj.data, SELECTED, sel)
    display.set_display_inputs(mod, **{"Points": True, "Opacity Threshold": 0.0, VC: True})
    on = _evaluated(obj)
    shade = on[SHADE].reshape(-1, 4)[:, :3]
    tint = np.array(display.SELECTED_TINT[:3])
    want = _numpy_sh_colour(obj, mod, cams[0])
    want = np.where(sel[:, None], want + 0.5 * (tint - want), want)
    np.testing.assert_allclose(shade, want, atol=2e-4)
    # bit-equal to the group without the gate (the path before it)
    _raw_set(mod, VC, False)
    off = _evaluated(obj)
    _ungated_group(mod)
    obj.update_tag()
    bpy.context.view_layer.update()
    before = _evaluated(obj)
    for k in before:
        np.testing.assert_array_equal(on[k], before[k], err_msg=k)
    # off: exactly the camera-free group's colour, not the SH colour
    display.ensure_display_group(True)  # (rebuilt: the ungated copy was a test's)
    mod.node_group.name  # noqa: B018 - still ours
    bpy.data.node_groups.remove(mod.node_group)
    mod.node_group = display.ensure_display_group(True)
    display.set_display_inputs(mod, **{"Points": True, "Opacity Threshold": 0.0, VC: False})
    _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, False)
    assert display.sync_display_group(mod)
    bpy.context.view_layer.update()
    fixed = _evaluated(obj)
    for k in fixed:
        np.testing.assert_array_equal(off[k], fixed[k], err_msg=k)
    assert np.abs(off[SHADE] - on[SHADE]).max() > 1e-3


def test_splat_quads_keep_the_sh_colour_in_the_viewport(sh3):
    obj = _import(sh3)
    _cameras()
    mod = obj.modifiers[display.MODIFIER]
    display.set_display_inputs(mod, **{"Points": False, "Opacity Threshold": 0.0, VC: True})
    on = _evaluated(obj)
    _raw_set(mod, VC, False)
    off = _evaluated(obj)
    for k in on:
        np.testing.assert_array_equal(on[k], off[k], err_msg=k)


def _aim(cam, obj) -> None:
    from mathutils import Vector

    pos = bridge.read_attribute(obj.data, "position").astype(np.float64)
    centre = np.array(obj.matrix_world) @ np.array([*pos.mean(0), 1.0])
    cam.rotation_euler = (Vector(centre[:3]) - cam.location).to_track_quat("-Z", "Y").to_euler()


def test_renders_evaluate_the_sh_colour_either_way(sh3):
    obj = _import(sh3)
    _aim(_cameras()[0], obj)
    mod = obj.modifiers[display.MODIFIER]
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 48, 36
    display.set_display_inputs(mod, **{"Points": True, "Size": 3.0})
    got = {}
    for vc, vd in ((True, True), (False, True), (False, False)):
        _raw_set(mod, VC, vc)
        _raw_set(mod, display.DisplayInputs.VIEW_DEPENDENT, vd)  # same group each time
        bpy.ops.render.render()
        got[(vc, vd)] = _render_pixels()
    assert got[(True, True)].reshape(-1, 4)[:, :3].std() > 0.02  # the points are in view
    np.testing.assert_array_equal(got[(False, True)], got[(True, True)])
    assert np.abs(got[(False, True)] - got[(False, False)]).max() > 1e-3


def _wm(*shadings: str):
    spaces = [SimpleNamespace(type="VIEW_3D", shading=SimpleNamespace(type=t)) for t in shadings]
    areas = [SimpleNamespace(type="VIEW_3D", spaces=[s]) for s in spaces]
    areas.append(SimpleNamespace(type="PROPERTIES", spaces=[SimpleNamespace(type="PROPERTIES")]))
    return SimpleNamespace(windows=[SimpleNamespace(screen=SimpleNamespace(areas=areas))])


def test_the_views_shading_sets_the_input(sh3, monkeypatch):
    assert not display.viewport_shows_colours(_wm())
    assert not display.viewport_shows_colours(_wm("SOLID", "WIREFRAME"))
    assert display.viewport_shows_colours(_wm("SOLID", "MATERIAL"))
    assert display.viewport_shows_colours(_wm("RENDERED"))
    obj = _import(sh3)
    mod = obj.modifiers[display.MODIFIER]
    assert not display.display_inputs(mod)[VC]  # headless: no view shows colours
    shown = ["SOLID"]
    plain = display.viewport_shows_colours
    monkeypatch.setattr(display, "viewport_shows_colours", lambda wm=None: plain(wm or _wm(*shown)))
    handlers._viewport_colours[0] = None
    for shading, expect in (("MATERIAL", True), ("SOLID", False), ("RENDERED", True)):
        shown[0] = shading
        assert handlers.request_viewport_colours_sync()  # as a 3D view's redraw does
        assert not handlers.request_viewport_colours_sync()  # scheduled once
        bpy.app.timers.unregister(handlers._viewport_colours_timer)
        handlers._viewport_colours_timer()
        assert bool(display.display_inputs(mod)[VC]) is expect
        assert not handlers.request_viewport_colours_sync()  # nothing changed since

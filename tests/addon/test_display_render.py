"""What an imported capture looks like when Blender renders it.

Cycles renders the shared biker and guitar captures (Standard view transform) from a
camera the engine renders too (``blender_scripts/compare_render.py`` does the same at
any size and writes the pictures). Mean absolute differences inside the object (the
engine's alpha > 0.5), 160×120, 16 samples, 1-px box filter, against the engine's
render of that camera supersampled 8× (what a Blender pixel integrates; the native
160-px render widens every sub-pixel splat with its 2DGS low-pass of √2/2 *pixel*,
which is most of its difference to its own supersampled picture, see BENCHMARKS.md):

* the default import blends like the capture (display space, :mod:`blender_addon.
  blend_space`): ≤ 0.06 for both captures;
* switched off (biker), Blender blends in linear light: ≤ 0.06 from the engine's render
  composited in linear light (far more from the display-space reference).

Workbench (what Solid mode draws) shows the splat colours: the same figure, not grey.
"""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from .compare_script import CMP


def _luma(rgb: np.ndarray) -> np.ndarray:
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


@pytest.mark.parametrize(
    "capture, check_linear",
    [
        ("playcanvas-splats/guitar.compressed.ply", False),
        ("playcanvas-splats/biker.compressed.ply", True),  # dark leathers: where it shows most
    ],
)
def test_cycles_render_matches_the_engine(real_data, tmp_path, capture, check_linear):
    from blender_addon import blend_space

    path = real_data / capture
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    assert bpy.ops.divas.import_splats(filepath=str(path)) == {"FINISHED"}
    obj = bpy.context.active_object
    scene = bpy.context.scene
    assert getattr(scene, blend_space.BLEND_FLAG)  # the default in an empty scene
    from divas_engine import load_scene

    cam = CMP.view_camera(load_scene(path), 160, 30.0, 15.0, (0, -1, 0))
    refs, inside = CMP.engine_references(path, cam)
    assert inside.sum() > 500
    got = CMP.render_blender(bpy.context, obj, cam, "CYCLES", 16, tmp_path / "cycles.png")
    assert scene.view_settings.view_transform == "Standard"
    mads = {k: CMP.mad(got, v, inside) for k, v in refs.items()}
    assert mads["engine_aa"] <= 0.06, mads
    gap = abs(_luma(got)[inside].mean() - _luma(refs["engine_aa"])[inside].mean())
    assert gap <= 0.02, (gap, mads)
    assert _luma(got)[~inside].mean() < 0.02  # nothing drawn where the engine has nothing
    if not check_linear:
        return
    # switched off: Blender's linear blending, which matches the engine composited in
    # linear light instead
    blend_space.set_blend_display(scene, False)
    lin = CMP.render_blender(bpy.context, obj, cam, "CYCLES", 16, tmp_path / "linear.png")
    lin_mads = {k: CMP.mad(lin, v, inside) for k, v in refs.items()}
    assert lin_mads["engine_linear_aa"] <= 0.06, lin_mads
    assert lin_mads["engine_aa"] >= mads["engine_aa"] + 0.02, (lin_mads, mads)


def test_solid_mode_shows_the_splat_colours(real_data, tmp_path):
    path = real_data / "playcanvas-splats" / "biker.compressed.ply"
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    assert bpy.ops.divas.import_splats(filepath=str(path)) == {"FINISHED"}
    obj = bpy.context.active_object
    from divas_engine import load_scene

    cam = CMP.view_camera(load_scene(path), 160, 30.0, 15.0, (0, -1, 0))
    refs, inside = CMP.engine_references(path, cam)
    got = CMP.render_blender(bpy.context, obj, cam, "BLENDER_WORKBENCH", 1, tmp_path / "wb.png")
    drawn = got.sum(-1) > 0.02
    # the figure is drawn where the engine draws it, in colour (not a flat grey)
    assert (drawn & inside).sum() >= 0.9 * inside.sum()
    assert got[inside].std(axis=0).mean() > 0.05  # varied colours, not one flat shade
    assert abs(_luma(got)[inside].mean() - _luma(refs["engine"])[inside].mean()) <= 0.15

"""Display-space blending ("Blend Like the Capture", :mod:`blender_addon.blend_space`)
against hand-computed pixels: two large surfels facing the camera, one in front of the
other, rendered 8 × 8 by Cycles and EEVEE. At the centre pixels the Gaussians are ≈ 1
(σ = 50 against a view 5 units wide: G ≥ 0.998), so the pixel is the two-layer
over-composite of their colours:

* like the capture (the trainers' sum, in display values):
  ``C = α_A s_A + (1 − α_A) α_B s_B``;
* linear (Blender's own): ``E(α_A L(s_A) + (1 − α_A) α_B L(s_B))``, ``E``/``L`` the sRGB
  encoding/decoding.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np
import pytest

from blender_addon import blend_space, compat
from divas_engine.camera import Camera
from divas_engine.io.ply import write_surfel_ply
from divas_engine.point_attributes import linear_to_srgb, srgb_to_linear
from divas_engine.scene import SH_C0, SurfelScene

from .compare_script import CMP

#: display colours and opacities of the front (A) and back (B) surfel
S_A, ALPHA_A = np.array([0.10, 0.50, 0.02]), 0.6
S_B, ALPHA_B = np.array([0.90, 0.30, 0.70]), 0.9


def _display() -> np.ndarray:
    return ALPHA_A * S_A + (1 - ALPHA_A) * ALPHA_B * S_B


def _linear() -> np.ndarray:
    return linear_to_srgb(
        ALPHA_A * srgb_to_linear(S_A) + (1 - ALPHA_A) * ALPHA_B * srgb_to_linear(S_B)
    )


@pytest.fixture
def two_layers(tmp_path) -> Path:
    scene = SurfelScene(
        means=np.array([[0, 0, 0], [0, 0, 1]], np.float32),
        quats=np.array([[1, 0, 0, 0]] * 2, np.float32),
        scales=np.full((2, 2), 50.0, np.float32),
        opacities=np.array([ALPHA_A, ALPHA_B], np.float32),
        sh=((np.stack([S_A, S_B]) - 0.5) / SH_C0).astype(np.float32)[:, None, :],
        sh_degree=0,
    )
    path = tmp_path / "two_layers.ply"
    write_surfel_ply(path, scene)
    return path


def _camera() -> Camera:
    return Camera.look_at(
        np.array([0.0, 0, -5]), np.zeros(3), np.array([0.0, -1, 0]), width=8, height=8, fx=8.0
    )


def _import(path, **kw):
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    done = bpy.ops.divas.import_splats(filepath=str(path), up_from_scene=False, **kw)
    assert done == {"FINISHED"}
    return bpy.context.active_object


#: (samples, tolerance): EEVEE dithers the alpha (16 samples: within ~0.02 of the
#: converged two-layer composite, slow on a CPU); Cycles blends it exactly.
RENDER = {"CYCLES": (4, 0.012), "BLENDER_EEVEE": (16, 0.03), "BLENDER_WORKBENCH": (1, 0.01)}


def _centre(obj, engine: str, out: Path) -> np.ndarray:
    samples = RENDER[engine][0]
    rgb = CMP.render_blender(bpy.context, obj, _camera(), engine, samples, out)
    return rgb[2:6, 2:6].reshape(-1, 3).mean(0)


def test_the_engine_composites_like_the_capture(two_layers):
    """The hand-made reference is the engine's own compositing (so "like the capture"
    means like the engine's render)."""
    from divas_engine import load_scene
    from divas_engine.render import make_renderer

    rgb = make_renderer(load_scene(two_layers), "cpu").render(_camera()).rgb
    np.testing.assert_allclose(rgb[3:5, 3:5].reshape(-1, 3).mean(0), _display(), atol=0.005)
    assert np.abs(_display() - _linear()).max() > 0.1  # the two spaces differ here


@pytest.mark.parametrize("engine", ["CYCLES", "BLENDER_EEVEE"])
def test_blend_like_the_capture_and_back_to_linear(two_layers, tmp_path, engine):
    tol = RENDER[engine][1]
    obj = _import(two_layers)  # Auto, into an empty scene: like the capture
    scene = bpy.context.scene
    assert getattr(scene, blend_space.BLEND_FLAG)
    assert len(blend_space.decode_nodes(scene)) == 1
    np.testing.assert_allclose(_centre(obj, engine, tmp_path / "d.png"), _display(), atol=tol)
    blend_space.set_blend_display(scene, False)
    assert blend_space.decode_nodes(scene) == [] and compat.compositor_tree(scene) is None
    assert bpy.data.node_groups.get(blend_space.COMPOSITOR_GROUP) is None
    np.testing.assert_allclose(_centre(obj, engine, tmp_path / "l.png"), _linear(), atol=tol)
    if engine == "CYCLES":  # the property itself (the panel's toggle), back on
        setattr(scene, blend_space.BLEND_FLAG, True)
        np.testing.assert_allclose(_centre(obj, engine, tmp_path / "d2.png"), _display(), atol=tol)


def test_workbench_is_not_decoded(two_layers, tmp_path):
    """Solid mode's colours (the linear attribute, opaque front quad) look the same
    whichever space the splats blend in."""
    obj = _import(two_layers)
    on = _centre(obj, "BLENDER_WORKBENCH", tmp_path / "on.png")
    blend_space.set_blend_display(bpy.context.scene, False)
    off = _centre(obj, "BLENDER_WORKBENCH", tmp_path / "off.png")
    np.testing.assert_allclose(on, S_A, atol=0.01)
    np.testing.assert_allclose(off, S_A, atol=0.01)


def test_auto_keeps_linear_beside_other_objects(two_layers):
    bpy.ops.mesh.primitive_cube_add()
    assert bpy.ops.divas.import_splats(filepath=str(two_layers)) == {"FINISHED"}
    scene = bpy.context.scene
    assert not getattr(scene, blend_space.BLEND_FLAG)
    assert blend_space.decode_nodes(scene) == []
    # an explicit choice wins; the cube is why Auto did not make it
    assert bpy.ops.divas.import_splats(filepath=str(two_layers), blend_space="DISPLAY") == {
        "FINISHED"
    }
    assert getattr(scene, blend_space.BLEND_FLAG)
    assert blend_space.has_other_renderables(scene)


def test_a_compositor_of_the_users_own_is_kept(two_layers):
    """The decode goes right after Render Layers; switching off restores the links."""
    scene = bpy.context.scene
    group = compat.new_compositor_tree(scene, "mine")  # Render Layers → output
    (layers,) = [n for n in group.nodes if n.bl_idname == "CompositorNodeRLayers"]
    out = layers.outputs["Image"].links[0].to_socket
    blur = group.nodes.new("CompositorNodeBlur")
    group.links.new(layers.outputs["Image"], blur.inputs[0])
    group.links.new(blur.outputs[0], out)
    _import(two_layers, blend_space="DISPLAY")
    (node,) = blend_space.decode_nodes(scene)
    assert node.inputs[0].links[0].from_socket == layers.outputs["Image"]
    assert blur.inputs[0].links[0].from_node == node
    assert (node.from_color_space, node.to_color_space) == ("sRGB", "Linear Rec.709")
    blend_space.set_blend_display(scene, False)
    assert compat.compositor_tree(scene) == group
    assert blur.inputs[0].links[0].from_socket == layers.outputs["Image"]
    assert [n.bl_idname for n in group.nodes].count("CompositorNodeConvertColorSpace") == 0

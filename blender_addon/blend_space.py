"""Where splats are blended: in display (sRGB) space like the capture, or Blender's linear.

The 3DGS/2DGS trainers — and the engine — composite the splats' *display* colours,
``C = Σ_i T_i α_i c_i``; Blender composites in linear light, ``E(Σ T_i α_i L(c_i))`` (``E`` =
sRGB encoding, ``L = E⁻¹``), which brightens pixels where dark and bright splats mix.

With the scene property ``divas_blend_display`` ("Blend Like the Capture"): the splat and point
materials emit ``E(c_lin)`` (read through a View Layer Attribute node,
:func:`.display_nodes.srgb_encode`), so Cycles and EEVEE sum display values as the trainer does
(the stored ``divas_color`` and Solid mode stay linear), and the compositor decodes the result,
``L(C)`` (OCIO's sRGB → Linear Rec.709), so the Standard view transform shows ``C``.

The decode applies to the whole frame, darkening anything else in the scene: hence an option,
which *Auto* turns on at import only when the scene has nothing else to render. Workbench
renders are not decoded (:func:`on_render_pre` mutes the node). Material Preview and Rendered
shading need the viewport compositor (turned on for the open 3D views). Turning it off removes
the decode node and its node group, and the materials emit the linear colour again.
"""

from __future__ import annotations

import contextlib

import bpy
from bpy.props import BoolProperty

from . import compat
from .display import is_splat_display
from .display_nodes import BLEND_FLAG

__all__ = [
    "BLEND_FLAG",
    "DECODE_NODE",
    "COMPOSITOR_GROUP",
    "set_blend_display",
    "has_other_renderables",
    "decode_nodes",
    "on_render_pre",
    "register",
    "unregister",
]

#: name (and label) of the compositor node that decodes the display-space blend.
DECODE_NODE = "DivAS Display Decode"
#: the compositor node group made when the scene had none (removed again when off).
COMPOSITOR_GROUP = "DivAS Display Blend"
_OURS = "divas_blend_group"
#: object types that render something (lights and cameras do not: splats are unlit).
_RENDERABLE = {
    "MESH",
    "CURVE",
    "CURVES",
    "SURFACE",
    "META",
    "FONT",
    "VOLUME",
    "POINTCLOUD",
    "GREASEPENCIL",
}


def decode_nodes(scene) -> list:
    """The decode nodes in ``scene``'s compositor."""
    group = compat.compositor_tree(scene)
    if group is None:
        return []
    return [n for n in group.nodes if n.name.startswith(DECODE_NODE)]


def _add_decode(scene) -> None:
    """A decode node after every Render Layers' Image (the scene's own compositor is
    kept: what it does then works on the linear values it expects)."""
    group = compat.compositor_tree(scene)
    if group is None:
        group = compat.new_compositor_tree(scene, COMPOSITOR_GROUP)
        group[_OURS] = True
    for layers in [n for n in group.nodes if n.bl_idname == "CompositorNodeRLayers"]:
        image = layers.outputs["Image"]
        targets = [link.to_socket for link in image.links]
        node = group.nodes.new("CompositorNodeConvertColorSpace")
        node.name = node.label = DECODE_NODE
        node.from_color_space, node.to_color_space = "sRGB", "Linear Rec.709"
        node.location = (layers.location.x + 150, layers.location.y + 120)
        group.links.new(image, node.inputs[0])
        for sock in targets:
            group.links.new(node.outputs[0], sock)


def _remove_decode(scene) -> None:
    group = compat.compositor_tree(scene)
    for node in decode_nodes(scene):
        src = [link.from_socket for link in node.inputs[0].links]
        targets = [link.to_socket for link in node.outputs[0].links]
        group.nodes.remove(node)
        for sock in targets if src else ():
            group.links.new(src[0], sock)
    if group is not None and group.get(_OURS):
        del group[_OURS]
        compat.remove_compositor_tree(scene)


def _mute_for_engine(scene) -> None:
    for node in decode_nodes(scene):
        node.mute = scene.render.engine == "BLENDER_WORKBENCH"


def _viewport_compositor(context) -> None:
    wm = getattr(context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            for space in area.spaces:
                if space.type == "VIEW_3D" and space.shading.use_compositor == "DISABLED":
                    space.shading.use_compositor = "ALWAYS"


def _apply(scene, context) -> None:
    """Bring the compositor in line with the scene property (module docstring)."""
    on = bool(getattr(scene, BLEND_FLAG, False))
    have = bool(decode_nodes(scene))
    if on and not have:
        _add_decode(scene)
        scene.render.use_compositing = True
        _viewport_compositor(context)
    elif not on and have:
        _remove_decode(scene)
    _mute_for_engine(scene)


def set_blend_display(scene, on: bool, context=None) -> None:
    """Blend ``scene``'s splats in display space (``on``) or in linear light."""
    setattr(scene, BLEND_FLAG, bool(on))
    _apply(scene, context or bpy.context)  # the update callback does it too; idempotent


def has_other_renderables(scene, exclude=()) -> bool:
    """Whether ``scene`` renders something besides DivAS splat displays and ``exclude``."""
    skip = {o.name for o in exclude}
    for obj in scene.objects:
        if obj.name in skip or obj.type not in _RENDERABLE or obj.hide_render:
            continue
        if obj.type == "POINTCLOUD" and is_splat_display(obj):
            continue
        return True
    return False


@bpy.app.handlers.persistent
def on_render_pre(scene, *_args) -> None:
    """Workbench draws the colour attribute opaque (no encoded emission): no decode."""
    with contextlib.suppress(AttributeError, ReferenceError):  # never raise into Blender
        _mute_for_engine(scene)


def register() -> None:
    setattr(
        bpy.types.Scene,
        BLEND_FLAG,
        BoolProperty(
            name="Blend Like the Capture",
            default=False,
            description="Blend splats in display (sRGB) space, as the 3DGS/2DGS trainers "
            "do, so renders show the capture's own colours (Standard view transform). "
            "Adds a decode node to the compositor, which also darkens the mid-tones of "
            "any other object in the scene; off: Blender's linear blending",
            update=_apply,
        ),
    )


def unregister() -> None:
    if hasattr(bpy.types.Scene, BLEND_FLAG):
        delattr(bpy.types.Scene, BLEND_FLAG)

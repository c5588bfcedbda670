"""How imported splats and voxels look: a Geometry Nodes group and one material.

The node group "DivAS Point Display" (a modifier on every imported point cloud):
``Set Point Radius`` from the ``divas_radius`` attribute × a "Radius Scale" input,
then ``Set Material`` "DivAS Splat". The material reads the point attributes:
``divas_color`` as an unlit (emission) colour, tinted by ``divas_selected`` (so a
selection shows live when the attribute changes), mixed with a transparent BSDF by
``divas_opacity`` (EEVEE dithers it, Cycles blends it). Both are built once per file
and reused; a user may edit them freely.
"""

from __future__ import annotations

import bpy

__all__ = [
    "DISPLAY_GROUP",
    "MATERIAL",
    "MODIFIER",
    "SELECTED_TINT",
    "ensure_material",
    "ensure_display_group",
    "add_display_modifier",
]

DISPLAY_GROUP = "DivAS Point Display"
MATERIAL = "DivAS Splat"
MODIFIER = "DivAS Display"
#: colour mixed into selected points (half strength) so they stand out.
SELECTED_TINT = (1.0, 0.35, 0.05, 1.0)


def _socket(sockets, identifier: str):
    for s in sockets:
        if s.identifier == identifier:
            return s
    raise KeyError(identifier)


def ensure_material() -> bpy.types.Material:
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL)
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()

    def attr(name: str, y: float):
        n = nt.nodes.new("ShaderNodeAttribute")
        n.attribute_type, n.attribute_name, n.location = "GEOMETRY", name, (-700, y)
        return n

    color, selected, opacity = (
        attr("divas_color", 200),
        attr("divas_selected", 0),
        attr("divas_opacity", -200),
    )
    tint = nt.nodes.new("ShaderNodeMix")
    tint.data_type, tint.location = "RGBA", (-450, 150)
    nt.links.new(selected.outputs["Factor"], _socket(tint.inputs, "Factor_Float"))
    nt.links.new(color.outputs["Color"], _socket(tint.inputs, "A_Color"))
    _socket(tint.inputs, "B_Color").default_value = SELECTED_TINT
    emission = nt.nodes.new("ShaderNodeEmission")
    emission.location = (-200, 150)
    nt.links.new(_socket(tint.outputs, "Result_Color"), emission.inputs["Color"])
    transparent = nt.nodes.new("ShaderNodeBsdfTransparent")
    transparent.location = (-200, -50)
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.location = (50, 50)
    nt.links.new(opacity.outputs["Factor"], mix.inputs[0])
    nt.links.new(transparent.outputs["BSDF"], mix.inputs[1])
    nt.links.new(emission.outputs["Emission"], mix.inputs[2])
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.location = (250, 50)
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    if hasattr(mat, "surface_render_method"):
        mat.surface_render_method = "DITHERED"
    return mat


def ensure_display_group() -> bpy.types.GeometryNodeTree:
    ng = bpy.data.node_groups.get(DISPLAY_GROUP)
    if ng is not None:
        return ng
    ng = bpy.data.node_groups.new(DISPLAY_GROUP, "GeometryNodeTree")
    ng.is_modifier = True
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    scale = ng.interface.new_socket("Radius Scale", in_out="INPUT", socket_type="NodeSocketFloat")
    scale.default_value, scale.min_value, scale.max_value = 1.0, 0.0, 100.0
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = ng.nodes, ng.links
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    gin.location, gout.location = (-600, 0), (400, 0)
    radius = nodes.new("GeometryNodeInputNamedAttribute")
    radius.data_type, radius.location = "FLOAT", (-600, -200)
    radius.inputs["Name"].default_value = "divas_radius"
    mul = nodes.new("ShaderNodeMath")
    mul.operation, mul.location = "MULTIPLY", (-350, -150)
    links.new(radius.outputs["Attribute"], mul.inputs[0])
    links.new(gin.outputs["Radius Scale"], mul.inputs[1])
    set_radius = nodes.new("GeometryNodeSetPointRadius")
    set_radius.location = (-100, 0)
    links.new(gin.outputs["Geometry"], set_radius.inputs["Points"])
    links.new(mul.outputs["Value"], set_radius.inputs["Radius"])
    set_mat = nodes.new("GeometryNodeSetMaterial")
    set_mat.location = (150, 0)
    set_mat.inputs["Material"].default_value = ensure_material()
    links.new(set_radius.outputs["Points"], set_mat.inputs["Geometry"])
    links.new(set_mat.outputs["Geometry"], gout.inputs["Geometry"])
    return ng


def add_display_modifier(obj: bpy.types.Object) -> bpy.types.Modifier:
    """Give ``obj`` the display modifier (and the material in its slot for Cycles/EEVEE)."""
    mod = obj.modifiers.get(MODIFIER) or obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = ensure_display_group()
    mat = ensure_material()
    if mat.name not in obj.data.materials:
        obj.data.materials.append(mat)
    return mod

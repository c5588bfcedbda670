"""``blender_addon.compat`` on the running release: each difference takes the side this
release has (its own RNA says which), and the calls round-trip."""

from __future__ import annotations

import bpy
import pytest

from blender_addon import compat


def test_eevee_is_an_engine_of_this_release():
    scene = bpy.context.scene
    scene.render.engine = compat.EEVEE  # an unknown identifier raises TypeError
    assert scene.render.engine == compat.EEVEE
    assert compat.render_engine("BLENDER_EEVEE") == compat.EEVEE
    assert compat.render_engine("BLENDER_EEVEE_NEXT") == compat.EEVEE
    assert compat.render_engine("CYCLES") == "CYCLES"


def test_compositor_tree_round_trip():
    scene = bpy.context.scene
    assert compat.compositor_tree(scene) is None  # the startup file composites nothing
    tree = compat.new_compositor_tree(scene, "DivAS test compositor")
    assert compat.compositor_tree(scene) == tree
    (layers,) = [n for n in tree.nodes if n.bl_idname == "CompositorNodeRLayers"]
    (link,) = layers.outputs["Image"].links
    assert link.to_node.bl_idname in ("NodeGroupOutput", "CompositorNodeComposite")
    compat.remove_compositor_tree(scene)
    assert compat.compositor_tree(scene) is None


@pytest.fixture
def nodes_modifier():
    obj = bpy.data.objects.new("inputs", bpy.data.pointclouds.new("inputs"))
    bpy.context.scene.collection.objects.link(obj)
    ng = bpy.data.node_groups.new("inputs", "GeometryNodeTree")
    ng.is_modifier = True
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ids = {
        kind: ng.interface.new_socket(
            kind, in_out="INPUT", socket_type=f"NodeSocket{kind}"
        ).identifier
        for kind in ("Float", "Bool", "Vector")
    }
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    mod = obj.modifiers.new("inputs", "NODES")
    mod.node_group = ng
    return mod, ids


def test_modifier_inputs_round_trip(nodes_modifier):
    mod, ids = nodes_modifier
    values = {"Float": 2.5, "Bool": True, "Vector": (1.0, -2.0, 3.0)}
    for kind, value in values.items():
        compat.set_modifier_input(mod, ids[kind], value)
    got = {kind: compat.modifier_input(mod, ident) for kind, ident in ids.items()}
    assert got["Float"] == pytest.approx(2.5) and bool(got["Bool"]) is True
    assert tuple(got["Vector"]) == pytest.approx(values["Vector"])
    assert compat.modifier_input(mod, "Socket_999") is None


def test_openvdb_where_the_release_has_it():
    vdb = compat.openvdb()
    if bpy.app.version >= (4, 4, 0):  # the bpy module exposes Blender's bundled modules
        assert vdb is not None and hasattr(vdb, "FloatGrid")
    else:
        assert vdb is None or hasattr(vdb, "FloatGrid")

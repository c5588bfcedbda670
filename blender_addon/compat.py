"""What differs between the Blender releases the add-on supports: 4.2 LTS to 5.2 LTS.

Everything else runs one code path on every release. Each function here names the
release where the API changed and why the add-on needs both sides:

* EEVEE's engine identifier: ``BLENDER_EEVEE_NEXT`` in 4.2–4.5, ``BLENDER_EEVEE`` from 5.0.
* The compositor: ``scene.use_nodes`` / ``scene.node_tree`` (a Composite node) in 4.x; a node
  group ``scene.compositing_node_group`` (a Group Output) from 5.0.
* Geometry Nodes modifier inputs: ID properties (``mod[identifier]``) in 4.2–5.0; RNA structs
  ``mod.properties.inputs.<identifier>.value`` in 5.2 (found by feature: 5.1 takes its side).
* Bundled Python modules (OpenVDB, OpenImageIO, USD): importable inside Blender; the PyPI
  ``bpy`` exposes them with ``bpy.utils.expose_bundled_modules()`` from 4.4, none before.
"""

from __future__ import annotations

import importlib
from functools import lru_cache
from types import ModuleType

import bpy

__all__ = [
    "EEVEE",
    "render_engine",
    "compositor_tree",
    "new_compositor_tree",
    "remove_compositor_tree",
    "modifier_input",
    "set_modifier_input",
    "bundled_module",
    "openvdb",
]

#: EEVEE's identifier in ``scene.render.engine`` on this release.
EEVEE = "BLENDER_EEVEE_NEXT" if bpy.app.version < (5, 0, 0) else "BLENDER_EEVEE"
_EEVEE_NAMES = frozenset({"BLENDER_EEVEE", "BLENDER_EEVEE_NEXT"})


def render_engine(name: str) -> str:
    """``name`` as this release spells it (either EEVEE name maps to :data:`EEVEE`)."""
    return EEVEE if name in _EEVEE_NAMES else name


def _has_group_compositor(scene) -> bool:
    return "compositing_node_group" in scene.bl_rna.properties  # 5.0+


def compositor_tree(scene):
    """The node tree ``scene`` composites with, or None when it composites nothing."""
    if _has_group_compositor(scene):
        return scene.compositing_node_group
    return scene.node_tree if scene.use_nodes else None


def new_compositor_tree(scene, name: str):
    """Give ``scene`` a compositor that passes the render through (Render Layers' Image
    to the output) and return it; ``scene`` must have none (:func:`compositor_tree`)."""
    if _has_group_compositor(scene):
        tree = bpy.data.node_groups.new(name, "CompositorNodeTree")
        tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
        out = tree.nodes.new("NodeGroupOutput")
        scene.compositing_node_group = tree
    else:
        scene.use_nodes = True  # 4.x fills a new tree with its default nodes: ours instead
        tree = scene.node_tree
        tree.nodes.clear()
        out = tree.nodes.new("CompositorNodeComposite")
    layers = tree.nodes.new("CompositorNodeRLayers")
    layers.location, out.location = (-300, 0), (300, 0)
    tree.links.new(layers.outputs["Image"], out.inputs[0])
    return tree


def remove_compositor_tree(scene) -> None:
    """Undo :func:`new_compositor_tree`: ``scene`` composites nothing again."""
    if _has_group_compositor(scene):
        tree = scene.compositing_node_group
        scene.compositing_node_group = None
        if tree is not None and tree.users == 0:
            bpy.data.node_groups.remove(tree)
    else:
        scene.use_nodes = False


def _rna_inputs(mod):
    """5.2+: the modifier's input structs; None where inputs are ID properties."""
    return getattr(getattr(mod, "properties", None), "inputs", None)


def modifier_input(mod, identifier: str):
    """The value of the Geometry Nodes modifier input ``identifier`` (None if absent)."""
    inputs = _rna_inputs(mod)
    if inputs is None:
        return mod.get(identifier)
    item = getattr(inputs, identifier, None)
    return None if item is None else item.value


def set_modifier_input(mod, identifier: str, value) -> None:
    """Set the Geometry Nodes modifier input ``identifier`` to ``value``."""
    inputs = _rna_inputs(mod)
    if inputs is None:
        mod[identifier] = value
    else:
        getattr(inputs, identifier).value = value


def bundled_module(name: str) -> ModuleType | None:
    """Blender's bundled module ``name`` (e.g. ``"openvdb"``), or None where this Blender
    has none (the ``bpy`` module before 4.4, or a build without it)."""
    try:
        return importlib.import_module(name)
    except ImportError:
        pass
    expose = getattr(bpy.utils, "expose_bundled_modules", None)
    if expose is None:
        return None
    expose()
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


def openvdb() -> ModuleType | None:
    """Blender's OpenVDB Python module (``openvdb`` from 4.4, ``pyopenvdb`` in the Blender
    4.2 and 4.3 applications), or None: this release's bundled modules are exposed where
    it can, then the engine's own finder
    (:func:`divas_engine.io.openvdb_grid.openvdb_module`) decides, so the add-on and the
    engine read and write ``.vdb`` with the same module."""
    from divas_engine.io import openvdb_grid

    _expose_bundled_modules()
    return openvdb_grid.openvdb_module()


@lru_cache(maxsize=1)
def _expose_bundled_modules() -> None:
    """``bpy.utils.expose_bundled_modules()`` once per process, where this release has it."""
    expose = getattr(bpy.utils, "expose_bundled_modules", None)
    if expose is not None:
        expose()

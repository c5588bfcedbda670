"""The first look (:mod:`blender_addon.first_look`): an import switches the 3D views that
show the new object from Solid or Wireframe to Material Preview, and Blender's undo and
redo of the import (run for real, headless) take the views back and forth with it.

Headless Blender has no windows, so the views are stand-ins with the attributes the
module reads (a window's view layer, a screen's areas, a space's type, shading and
local view); the object, the operator and the undo steps are real.
"""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import pytest

from blender_addon import first_look

UNDO = ("EXEC_DEFAULT", True)  # a script's operator call that pushes its undo step


def _space(shading: str, local_view=None):
    return SimpleNamespace(
        type="VIEW_3D", shading=SimpleNamespace(type=shading), local_view=local_view
    )


def _wm(*windows):
    return SimpleNamespace(windows=list(windows))


def _window(view_layer, *spaces):
    areas = [SimpleNamespace(spaces=[s]) for s in spaces]
    return SimpleNamespace(view_layer=view_layer, screen=SimpleNamespace(areas=areas))


@pytest.fixture
def views(monkeypatch):
    """A Solid, a Wireframe, a Rendered view and one in local view, all in one window
    of the running view layer; the operator sees these."""
    spaces = {
        "solid": _space("SOLID"),
        "wire": _space("WIREFRAME"),
        "rendered": _space("RENDERED"),
        "local": _space("SOLID", local_view=object()),
    }
    wm = _wm(_window(bpy.context.view_layer, *spaces.values()))
    real = first_look.views_showing
    monkeypatch.setattr(first_look, "views_showing", lambda obj, _wm=None: real(obj, wm))
    yield spaces
    first_look.forget()


def _shadings(views) -> dict[str, str]:
    return {k: s.shading.type for k, s in views.items()}


BEFORE = {"solid": "SOLID", "wire": "WIREFRAME", "rendered": "RENDERED", "local": "SOLID"}
AFTER = {**BEFORE, "solid": "MATERIAL", "wire": "MATERIAL"}


def test_import_switches_views_and_undo_takes_them_back(ribs, views):
    assert bpy.ops.divas.import_splats(*UNDO, filepath=str(ribs / "scene.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    assert obj.get(first_look.TOKEN_PROP)
    assert _shadings(views) == AFTER  # Rendered shows colours already; local view not it
    bpy.ops.ed.undo()
    assert not [o for o in bpy.data.objects if o.get(first_look.TOKEN_PROP)]
    assert _shadings(views) == BEFORE
    bpy.ops.ed.redo()
    assert _shadings(views) == AFTER


def test_a_view_switched_by_the_user_stays(ribs, views):
    assert bpy.ops.divas.import_splats(*UNDO, filepath=str(ribs / "scene.ply")) == {"FINISHED"}
    views["solid"].shading.type = "SOLID"  # the user's own choice after the import
    bpy.ops.mesh.primitive_cube_add()
    bpy.ops.ed.undo_push(message="cube")
    bpy.ops.ed.undo()  # the cube goes, the splats stay: no view changes
    assert views["solid"].shading.type == "SOLID"
    assert views["wire"].shading.type == "MATERIAL"


def test_option_off_leaves_the_views(ribs, views):
    done = bpy.ops.divas.import_splats(filepath=str(ribs / "scene.ply"), material_preview=False)
    assert done == {"FINISHED"}
    assert _shadings(views) == BEFORE
    assert first_look.TOKEN_PROP not in bpy.context.active_object


def test_views_showing_follow_the_windows_view_layer(ribs):
    assert bpy.ops.divas.import_splats(filepath=str(ribs / "scene.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    coll = bpy.data.collections.new("splats")
    bpy.context.scene.collection.children.link(coll)
    for c in list(obj.users_collection):
        c.objects.unlink(obj)
    coll.objects.link(obj)
    other = bpy.context.scene.view_layers.new("without the splats")
    other.layer_collection.children[coll.name].exclude = True
    other.update()
    assert other.objects.get(obj.name) is None
    here, there = _space("SOLID"), _space("SOLID")
    wm = _wm(_window(bpy.context.view_layer, here), _window(other, there))
    shown = first_look.views_showing(obj, wm)
    assert len(shown) == 1 and shown[0] is here and there is not here
    assert first_look.views_showing(obj, _wm()) == []  # headless: no windows

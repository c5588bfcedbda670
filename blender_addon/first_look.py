"""The first look: right after an import, the 3D views show the capture in its colours.

Solid shading, Blender's default, draws the splat quads opaque in their colour attribute
(hard shards) and the point display in one material colour; Material Preview draws them
through EEVEE, which blends each splat's Gaussian alpha: the capture as it was trained.
The splat import (option *Show in Material Preview*, on by default) therefore switches
every 3D view that shows the new object and draws in Solid or Wireframe to Material
Preview (:func:`show_in_material_preview`).

A 3D view's shading is screen (UI) data, which Blender's undo leaves alone. Each switch is
remembered with a token the imported object carries; after every undo and redo
(:func:`follow_undo`), a view whose object came and went with the step is switched with
it: back to its own shading when the import was undone, to Material Preview again when it
was redone. A view the user switched since is left as it is unless the import's own step
is undone or redone.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

import bpy

__all__ = [
    "TOKEN_PROP",
    "LOOK",
    "views_showing",
    "show_in_material_preview",
    "follow_undo",
    "forget",
]

#: object custom property: the token of the import that switched views for it.
TOKEN_PROP = "divas_first_look"
#: the shading the first look switches to.
LOOK = "MATERIAL"
#: shadings switched (the others show material colours already).
_SWITCHED_FROM = frozenset({"SOLID", "WIREFRAME"})


@dataclass
class _Switch:
    space: object  # a SpaceView3D (UI data: it outlives undo steps)
    before: str
    token: str
    present: bool = True


_switches: list[_Switch] = []


def views_showing(obj, wm=None) -> list:
    """The 3D-view spaces of ``wm``'s windows (default: the running window manager) that
    show ``obj``: their window's view layer holds it and they are not in local view."""
    if wm is None:
        wm = getattr(bpy.context, "window_manager", None)
    out = []
    for window in getattr(wm, "windows", ()):
        layer = getattr(window, "view_layer", None)
        if layer is not None and layer.objects.get(obj.name) is None:
            continue
        for area in window.screen.areas:
            for space in area.spaces:
                if space.type == "VIEW_3D" and getattr(space, "local_view", None) is None:
                    out.append(space)
    return out


def show_in_material_preview(obj, wm=None) -> int:
    """Switch the views showing ``obj`` (:func:`views_showing`) from Solid or Wireframe
    to Material Preview and remember each switch for undo; returns how many switched."""
    token = uuid.uuid4().hex
    switched = 0
    for space in views_showing(obj, wm):
        before = space.shading.type
        if before not in _SWITCHED_FROM:
            continue
        space.shading.type = LOOK
        _switches.append(_Switch(space, before, token))
        switched += 1
    if switched:
        obj[TOKEN_PROP] = token
    return switched


def follow_undo() -> int:
    """Switch the remembered views with their object (module docstring) after an undo
    or redo; returns how many views changed."""
    if not _switches:
        return 0
    present = {o.get(TOKEN_PROP) for o in bpy.data.objects}
    changed = 0
    for s in list(_switches):
        now = s.token in present
        if now == s.present:
            continue
        s.present = now
        try:
            s.space.shading.type = LOOK if now else s.before
        except ReferenceError:  # the view was closed
            _switches.remove(s)
            continue
        changed += 1
    return changed


def forget() -> None:
    """Drop every remembered switch (another file is loaded)."""
    _switches.clear()

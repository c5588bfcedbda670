"""The add-on's ``bpy.app.handlers``: what keeps the live sessions in step with the file.

* ``load_pre`` — close every session (:func:`.session_registry.on_load_pre`);
* ``load_post`` — resume the opened file's saved sessions (preference);
* ``save_pre`` / ``save_post`` — scene paths relative to the .blend, pending images packed
  (:func:`.bridge.pack_pending`), each session written beside it (:mod:`.session_actions.files`);
* ``undo_post`` / ``redo_post`` — move each session to the step Blender's undo restored
  (:mod:`.session_actions.history`) and the 3D views an import switched to Material Preview
  with their object (:func:`.first_look.follow_undo`);
* ``depsgraph_update_post`` — a one-shot timer renders an anchor camera that became the scene
  camera or active object before its view was rendered (anchors render lazily; ID data cannot
  be written during the update), and swaps a display modifier running the wrong colour variant
  (:func:`.display.sync_display_group`);
* ``render_pre`` — no display-space decode for Workbench renders
  (:func:`.blend_space.on_render_pre`);
* a 3D-view draw handler (``PRE_VIEW``) — when whether some 3D view shows material colours
  changed, a one-shot timer sets the modifiers' *Viewport Colours*
  (:func:`.display.sync_viewport_colours`).

Every handler is ``@persistent`` (it outlives file loads) and registered once.
"""

from __future__ import annotations

import sys

import bpy
from bpy.app.handlers import persistent

from . import blend_space, bridge, display, draw, first_look, session_registry
from .session_actions import files, sync_after_undo
from .session_actions.view_cameras import cameras_needing_background, fill_backgrounds

__all__ = [
    "register",
    "unregister",
    "on_undo_redo",
    "request_background_fill",
    "request_display_sync",
    "request_viewport_colours_sync",
]


def _fill_timer() -> None:
    try:
        if fill_backgrounds(bpy.context):
            draw.touch()
    except Exception as e:  # noqa: BLE001 - a timer must not raise into Blender
        print(f"DivAS: could not render the anchor view ({type(e).__name__}: {e})", file=sys.stderr)
    return None  # one shot


def request_background_fill(context=None) -> bool:
    """Schedule the render of the anchor view the user looks at, when it is missing;
    returns whether one was scheduled (not when one is scheduled already)."""
    if bpy.app.timers.is_registered(_fill_timer):
        return False
    try:
        need = cameras_needing_background(context or bpy.context)
    except (AttributeError, ReferenceError):
        return False
    if not need:
        return False
    bpy.app.timers.register(_fill_timer, first_interval=0.0)
    return True


_pending_display: set[str] = set()


def _display_timer() -> None:
    names = sorted(_pending_display)
    _pending_display.clear()
    for name in names:
        obj = bpy.data.objects.get(name)
        mod = obj.modifiers.get(display.MODIFIER) if obj is not None else None
        try:
            display.sync_display_group(mod)
        except (AttributeError, ReferenceError, KeyError) as e:
            print(f"DivAS: could not switch the display of {name!r} ({e})", file=sys.stderr)
    return None  # one shot


def request_display_sync(depsgraph) -> bool:
    """Schedule :func:`.display.sync_display_group` for the updated objects whose display
    modifier runs the wrong variant; returns whether one was scheduled."""
    for u in getattr(depsgraph, "updates", ()):
        obj = u.id.original if isinstance(u.id, bpy.types.Object) else None
        mod = obj.modifiers.get(display.MODIFIER) if obj is not None else None
        if mod is not None and display.display_group_outdated(mod):
            _pending_display.add(obj.name)
    if not _pending_display or bpy.app.timers.is_registered(_display_timer):
        return False
    bpy.app.timers.register(_display_timer, first_interval=0.0)
    return True


#: what :func:`request_viewport_colours_sync` last saw (None: not checked since a load)
_viewport_colours: list[bool | None] = [None]


def _viewport_colours_timer() -> None:
    shows = display.viewport_shows_colours()
    try:
        display.sync_viewport_colours(shows)
        _viewport_colours[0] = shows
    except (AttributeError, ReferenceError, KeyError) as e:
        print(f"DivAS: could not set the viewport colours ({e})", file=sys.stderr)
    return None  # one shot


def request_viewport_colours_sync(wm=None) -> bool:
    """Schedule :func:`.display.sync_viewport_colours` when whether a 3D view shows
    material colours changed since the last sync; returns whether one was scheduled
    (ID data is not written while drawing)."""
    try:
        shows = display.viewport_shows_colours(wm)
    except (AttributeError, ReferenceError):
        return False
    if shows == _viewport_colours[0] or bpy.app.timers.is_registered(_viewport_colours_timer):
        return False
    bpy.app.timers.register(_viewport_colours_timer, first_interval=0.0)
    return True


def _on_view_draw() -> None:
    request_viewport_colours_sync()


@persistent
def _on_depsgraph_update(_scene=None, depsgraph=None, *_args) -> None:
    request_background_fill()
    if depsgraph is not None:
        request_display_sync(depsgraph)


def _sync_sessions() -> None:
    for line in sync_after_undo():
        print(line, file=sys.stderr)


@persistent
def on_undo_redo(*_args) -> None:
    """Blender undid or redid a step: the sessions follow (never raises into Blender)."""
    for follow in (first_look.follow_undo, _sync_sessions):
        try:
            follow()
        except Exception as e:  # noqa: BLE001 - a handler must not break Blender's undo
            print(f"DivAS: could not follow the undo ({type(e).__name__}: {e})", file=sys.stderr)
    draw.touch()


@persistent
def _on_load_pre(*args) -> None:
    session_registry.on_load_pre(*args)
    bridge.forget_pending()  # the images to pack were the old file's
    first_look.forget()  # the views' switches were for the old file's objects
    _viewport_colours[0] = None  # the next file's modifiers are checked on its first draw
    draw.touch()


_HANDLERS = (
    ("load_pre", _on_load_pre),
    ("load_post", files.on_load_post),
    ("save_pre", files.on_save_pre),
    ("save_post", files.on_save_post),
    ("undo_post", on_undo_redo),
    ("redo_post", on_undo_redo),
    ("depsgraph_update_post", _on_depsgraph_update),
    ("render_pre", blend_space.on_render_pre),
)


_view_draw: list = []


def register() -> None:
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn not in handlers:
            handlers.append(fn)
    draw.register()
    if not _view_draw:
        space = bpy.types.SpaceView3D
        _view_draw.append(space.draw_handler_add(_on_view_draw, (), "WINDOW", "PRE_VIEW"))


def unregister() -> None:
    while _view_draw:
        bpy.types.SpaceView3D.draw_handler_remove(_view_draw.pop(), "WINDOW")
    _viewport_colours[0] = None
    bridge.forget_pending()
    draw.unregister()
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        while fn in handlers:
            handlers.remove(fn)

"""DivAS for Blender: interactive, training-free segmentation of Gaussian splats and NeRF grids.

A thin ``bpy`` layer over the pure-Python ``divas_engine`` (bundled as a wheel):
import operators, training/anchor cameras, the live session (start, click-to-segment
modal in any 3D view, accept/reset/finish, Blender's undo and redo, saved with the
.blend and resumed), manual selection tools, feedback drawn over the viewport, extract
and export. Arrays cross into Blender only in :mod:`.bridge`. Internal imports are
relative, so the package works under any extension repository name
(``bl_ext.<repo>.divas``).
"""

from __future__ import annotations

import bpy

from . import (
    blend_space,
    handlers,
    operators,
    preferences,
    properties,
    session_registry,
    source,
    ui,
)

CLASSES = (preferences.DIVAS_AddonPreferences, *operators.CLASSES, *ui.CLASSES)


def register() -> None:
    properties.register()  # scene.divas first: the panel and operators read it
    blend_space.register()
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for menu, func in operators.MENU_ENTRIES:
        getattr(bpy.types, menu).append(func)
    handlers.register()


def unregister() -> None:
    handlers.unregister()
    session_registry.clear()
    for menu, func in reversed(operators.MENU_ENTRIES):
        getattr(bpy.types, menu).remove(func)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    blend_space.unregister()
    properties.unregister()
    source.clear_cache()

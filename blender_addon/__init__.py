"""DivAS for Blender: interactive, training-free segmentation of Gaussian splats and NeRF grids.

A thin ``bpy`` layer over the pure-Python ``divas_engine`` (bundled as a wheel):
import operators, training/anchor cameras, extract and export. Arrays cross into
Blender only in :mod:`.bridge`. Internal imports are relative, so the package works
under any extension repository name (``bl_ext.<repo>.divas``).
"""

from __future__ import annotations

import bpy

from . import operators, preferences, source, ui

CLASSES = (preferences.DIVAS_AddonPreferences, *operators.CLASSES, *ui.CLASSES)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for menu, func in operators.MENU_ENTRIES:
        getattr(bpy.types, menu).append(func)


def unregister() -> None:
    for menu, func in reversed(operators.MENU_ENTRIES):
        getattr(bpy.types, menu).remove(func)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    source.clear_cache()

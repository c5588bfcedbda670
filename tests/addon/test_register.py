"""Registration: every class in, menus appended, preferences keyed by the package; clean
unregister (twice round)."""

from __future__ import annotations

import bpy

import blender_addon
from blender_addon.preferences import DivasSettings, get_preferences, get_settings

OPERATORS = (
    "import_splats",
    "import_density_grid",
    "import_cameras",
    "export_selection",
    "extract_selection",
    "activate_camera",
)


def _registered() -> list[bool]:
    return [cls.is_registered for cls in blender_addon.CLASSES]


def test_classes_registered_and_named():
    assert all(_registered())
    for op in OPERATORS:
        assert hasattr(bpy.ops.divas, op)
        assert bpy.ops.divas.__getattr__(op).idname() == f"DIVAS_OT_{op}"
    assert bpy.types.DIVAS_PT_main.bl_category == "DivAS"
    names = [c.__name__ for c in blender_addon.CLASSES]
    assert all(n.startswith(("DIVAS_OT_", "DIVAS_PT_")) for n in names[1:])
    assert len(set(names)) == len(names)


def test_preferences_keyed_by_package():
    prefs = get_preferences()
    assert (
        prefs is not None and type(prefs).bl_idname == blender_addon.__package__ == "blender_addon"
    )
    # the test conftest sets the anchor resolution to 0 (fast anchors); the add-on's default
    rna = type(prefs).bl_rna.properties["anchor_resolution"]
    assert rna.default == DivasSettings().anchor_resolution >= 640
    assert get_settings() == DivasSettings(anchor_resolution=prefs.anchor_resolution)
    prefs.device, prefs.segmenter = "cuda", "sam_onnx"
    prefs.sam_encoder_path = "/models/enc.onnx"
    s = get_settings()
    assert (s.device, s.segmenter, s.sam_encoder_path) == ("cuda", "sam_onnx", "/models/enc.onnx")
    prefs.device, prefs.segmenter, prefs.sam_encoder_path = "cpu", "classic", ""


def test_menu_entries_present():
    from blender_addon.operators import MENU_ENTRIES

    for menu, func in MENU_ENTRIES:
        assert func in getattr(bpy.types, menu)._dyn_ui_initialize()


def test_unregister_register_twice():
    for _ in range(2):
        blender_addon.unregister()
        assert not any(_registered())
        assert not hasattr(bpy.types, "DIVAS_OT_import_splats")
        from blender_addon.operators import MENU_ENTRIES

        for menu, func in MENU_ENTRIES:
            assert func not in getattr(bpy.types, menu)._dyn_ui_initialize()
        blender_addon.register()
        assert all(_registered())
    assert bpy.ops.divas.import_splats.poll()

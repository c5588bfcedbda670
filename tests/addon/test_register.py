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
    prefs.device, prefs.segmenter = "cuda", "sam-onnx"
    prefs.sam_encoder_path = "/models/enc.onnx"
    s = get_settings()
    assert (s.device, s.segmenter, s.sam_encoder_path) == ("cuda", "sam-onnx", "/models/enc.onnx")
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


def test_segmenter_names_and_default_are_the_engines():
    """One spelling (the CLI's ``sam-onnx``) and one default everywhere."""
    from blender_addon.preferences import SEGMENTERS
    from blender_addon.session_actions import StartSettings
    from divas_engine.segment import DEFAULT_SEGMENTER, SegmenterKind, SegmenterSettings
    from divas_engine.session import SessionConfig

    assert {key for key, _, _ in SEGMENTERS} <= {k.value for k in SegmenterKind}
    prefs = get_preferences()
    rna = type(prefs).bl_rna.properties["segmenter"]
    assert rna.default == DivasSettings().segmenter == DEFAULT_SEGMENTER.value
    assert StartSettings(SessionConfig()).segmenter == DEFAULT_SEGMENTER.value
    assert SegmenterSettings().kind is DEFAULT_SEGMENTER is SegmenterKind.GRAPH3D


def test_segmenter_saved_with_the_old_spelling_reads_back(tmp_path):
    """Blender saves an enum property as its item's position (in a .blend, and so in the
    saved preferences): a value saved when the SAM items were spelled ``sam_onnx`` /
    ``sam_torch`` reads back as the engine's names."""
    from bpy.props import EnumProperty

    from blender_addon.preferences import SEGMENTERS

    old = [(k.replace("-", "_"), name, doc) for k, name, doc in SEGMENTERS]
    path = str(tmp_path / "old.blend")
    bpy.types.Scene.divas_test_segmenter = EnumProperty(items=old)
    try:
        bpy.context.scene.divas_test_segmenter = "sam_onnx"
        bpy.ops.wm.save_as_mainfile(filepath=path)
        bpy.types.Scene.divas_test_segmenter = EnumProperty(items=SEGMENTERS)
        bpy.ops.wm.open_mainfile(filepath=path)
        assert bpy.context.scene.divas_test_segmenter == "sam-onnx"
    finally:
        del bpy.types.Scene.divas_test_segmenter

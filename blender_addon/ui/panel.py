"""The N-panel tab "DivAS": import, settings, the active object's selection, extract/export."""

from __future__ import annotations

import bpy

from .. import source
from ..camera_objects import RESOLUTION_PROP
from ..preferences import get_preferences
from ..selection import selected_count


class DIVAS_PT_main(bpy.types.Panel):
    bl_idname = "DIVAS_PT_main"
    bl_label = "DivAS"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "DivAS"

    def draw(self, context):
        layout = self.layout
        col = layout.column(align=True)
        col.label(text="Import")
        col.operator("divas.import_splats", text="Gaussian Splats", icon="POINTCLOUD_DATA")
        col.operator("divas.import_density_grid", text="NeRF Density Grid", icon="VOLUME_DATA")
        col.operator("divas.import_cameras", text="Training Cameras", icon="CAMERA_DATA")

        prefs = get_preferences(context)
        box = layout.box()
        box.label(text="Settings")
        if prefs is None:
            box.label(text="Preferences unavailable (add-on not enabled)", icon="INFO")
        else:
            box.use_property_split = True
            box.prop(prefs, "device")
            box.prop(prefs, "segmenter")

        obj = context.active_object
        if obj is not None and obj.type == "CAMERA":
            row = layout.row()
            row.operator("divas.activate_camera", icon="VIEW_CAMERA")
            if RESOLUTION_PROP in obj:
                w, h = obj[RESOLUTION_PROP]
                row.label(text=f"{w} x {h}")

        ref = source.source_of(obj)
        if ref is None:
            return
        box = layout.box()
        box.label(text=obj.name, icon="OUTLINER_OB_POINTCLOUD")
        box.label(text=f"{ref.path.name} ({ref.format})")
        n = len(obj.data.points)
        count = selected_count(obj)
        box.label(text=f"{n:,} points" + ("" if count is None else f", {count:,} selected"))
        col = box.column(align=True)
        col.operator("divas.extract_selection", icon="DUPLICATE")
        col.operator("divas.export_selection", icon="EXPORT")

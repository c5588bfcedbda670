"""Segmented Volume: a new Volume object of the selected voxels of a NeRF grid."""

from __future__ import annotations

import bpy

from ..nerf_volume import segmented_volume
from ..reporting import USER_ERRORS, report_failure
from ..selection import has_selection
from ..source import source_of


class DIVAS_OT_segmented_volume(bpy.types.Operator):
    """Make a new Volume object of the density inside the selected voxels (undoable)"""

    bl_idname = "divas.segmented_volume"
    bl_label = "Segmented Volume"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ref = source_of(context.active_object)
        if ref is None or ref.kind != "grid":
            cls.poll_message_set("The active object is not a NeRF grid imported with DivAS")
            return False
        if not has_selection(context.active_object):
            cls.poll_message_set("The grid has no selection yet ('divas_selected')")
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        try:
            new = segmented_volume(context, context.active_object)
        except USER_ERRORS as e:
            return report_failure(self, e)
        self.report({"INFO"}, f"{new['divas_voxels']:,} voxels in the new volume {new.name!r}")
        return {"FINISHED"}

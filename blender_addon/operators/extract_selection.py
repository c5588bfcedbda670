"""Extract Selection: a new object with the selected points and all their attributes."""

from __future__ import annotations

import bpy

from ..reporting import USER_ERRORS, report_failure
from ..selection import extract_selection, has_selection


class DIVAS_OT_extract_selection(bpy.types.Operator):
    """Copy the points marked by 'divas_selected' into a new object (undoable)"""

    bl_idname = "divas.extract_selection"
    bl_label = "Extract Selection"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not has_selection(context.active_object):
            cls.poll_message_set("The active point cloud has no selection ('divas_selected')")
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        try:
            new = extract_selection(context, context.active_object)
        except USER_ERRORS as e:
            return report_failure(self, e)
        self.report({"INFO"}, f"Extracted {len(new.data.points):,} points into {new.name!r}")
        return {"FINISHED"}

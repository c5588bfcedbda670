"""Delete Selected Splats: out of the object, and (with a session) out of every
selection, label and export (one undo step)."""

from __future__ import annotations

import bpy

from .. import point_edits
from .point_edit_base import PointEditOperator


class DIVAS_OT_delete_selected(PointEditOperator, bpy.types.Operator):
    """Delete the selected splats (Ctrl+Z brings them back)"""

    bl_idname = "divas.delete_selected"
    bl_label = "Delete Selected Splats"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        return self.run(
            context,
            "Delete splats",
            lambda t: point_edits.delete_selected(context, t),
            done="Deleted {n} splats: they are left out of every export (Ctrl+Z brings them back)",
        )

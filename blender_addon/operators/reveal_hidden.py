"""Reveal Hidden Splats: show every hidden splat again, deselected (one undo step)."""

from __future__ import annotations

import bpy

from .. import point_edits
from .point_edit_base import PointEditOperator


class DIVAS_OT_reveal_hidden(PointEditOperator, bpy.types.Operator):
    """Show every hidden splat again"""

    bl_idname = "divas.reveal_hidden"
    bl_label = "Reveal Hidden Splats"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        return self.run(context, "Reveal splats", point_edits.reveal, done="{n} splats shown again")

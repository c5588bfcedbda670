"""Separate Selected Splats: move them into a new object of their own (one undo step)."""

from __future__ import annotations

import bpy

from .. import point_edits
from .point_edit_base import PointEditOperator


class DIVAS_OT_separate_selected(PointEditOperator, bpy.types.Operator):
    """Move the selected splats into a new object (exportable on its own)"""

    bl_idname = "divas.separate_selected"
    bl_label = "Separate Selected Splats"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        return self.run(
            context,
            "Separate splats",
            lambda t: point_edits.separate_selected(context, t).name,
            done="Moved the selected splats into {n!r}: export it on its own, or keep segmenting",
        )

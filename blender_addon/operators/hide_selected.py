"""Hide Splats: hide the selected (or the unselected) splats; hidden ones are not drawn
and no tool touches them until Reveal (one undo step)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty

from .. import point_edits
from .point_edit_base import PointEditOperator


class DIVAS_OT_hide_selected(PointEditOperator, bpy.types.Operator):
    """Hide the selected splats (or the unselected ones) until Reveal"""

    bl_idname = "divas.hide_selected"
    bl_label = "Hide Splats"
    bl_options = {"REGISTER", "UNDO"}

    unselected: BoolProperty(name="Unselected", default=False)

    def execute(self, context):
        return self.run(
            context,
            "Hide splats",
            lambda t: point_edits.hide(t, unselected=self.unselected),
            done="Hid {n} splats: Reveal Hidden shows them again",
        )

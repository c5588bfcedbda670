"""Select All Splats: select, deselect or invert every visible splat (one undo step)."""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import EnumProperty

from .. import point_edits
from .point_edit_base import PointEditOperator

ACTIONS = (
    ("SELECT", "Select All", "Select every visible splat"),
    ("DESELECT", "Deselect All", "Deselect every splat"),
    ("INVERT", "Invert", "Select what is not selected, and the reverse"),
)


class DIVAS_OT_select_all(PointEditOperator, bpy.types.Operator):
    """Select, deselect or invert every visible splat"""

    bl_idname = "divas.select_all"
    bl_label = "Select All Splats"
    bl_options = {"REGISTER", "UNDO"}

    action: EnumProperty(name="Action", items=ACTIONS, default="INVERT")

    def execute(self, context):
        def select(t):
            n = len(point_edits.selected(t))
            mode = {"SELECT": "ADD", "DESELECT": "SUB", "INVERT": "XOR"}[self.action]
            return point_edits.apply_region(t, np.ones(n, bool), mode)

        what = dict((a, label) for a, label, _ in ACTIONS)[self.action]
        return self.run(context, what, select, done="{n} splats selected")

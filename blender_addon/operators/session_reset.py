"""Reset: drop the current object's views and selection (optionally every label)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty

from ..reporting import report_exception
from ..session_actions import reset
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_reset(SessionOperator, bpy.types.Operator):
    """Drop the current object's views and selection"""

    bl_idname = "divas.session_reset"
    bl_label = "Reset"
    bl_options = {"REGISTER"}

    all_objects: BoolProperty(
        name="All Objects", default=False, description="Also drop every finished object's label"
    )

    def execute(self, context):
        obj, live = live_session(context)
        try:
            reset(context, obj, live, all_objects=self.all_objects)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, "DivAS session reset")
        return {"FINISHED"}

"""Reset: drop the current object's views and selection (optionally every label; one
undo step)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty

from ..reporting import report_exception
from ..session_actions import reset, run_step
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_reset(SessionOperator, bpy.types.Operator):
    """Drop the current object's views and selection"""

    bl_idname = "divas.session_reset"
    bl_label = "Reset"
    bl_options = {"REGISTER", "UNDO"}

    all_objects: BoolProperty(
        options={"SKIP_SAVE"},
        name="All Objects",
        default=False,
        description="Also drop every finished object's label",
    )

    def execute(self, context):
        obj, live = live_session(context)
        try:
            run_step(obj, live, "Reset", reset, context, obj, live, all_objects=self.all_objects)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        what = "every object's views and labels" if self.all_objects else "this object's views"
        self.report(
            {"INFO"},
            f"Cleared {what} and the selection: click the object on an anchor to start "
            "again (Ctrl+Z brings it back)",
        )
        return {"FINISHED"}

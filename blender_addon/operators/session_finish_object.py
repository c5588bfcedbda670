"""Finish Object: commit the selection as the next label and start a new object (one
undo step)."""

from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..reporting import report_exception
from ..session_actions import finish_object, run_step
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_finish_object(SessionOperator, bpy.types.Operator):
    """Commit the selection as the next label ('divas_label') and start a new object"""

    bl_idname = "divas.session_finish_object"
    bl_label = "Finish Object"
    bl_options = {"REGISTER", "UNDO"}

    name: StringProperty(
        options={"SKIP_SAVE"},
        name="Name",
        default="",
        description="Object name (default object_<k>)",
    )

    def execute(self, context):
        obj, live = live_session(context)
        try:
            rec = run_step(
                obj, live, "Finish object", finish_object, context, obj, live, self.name or None
            )
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report(
            {"INFO"},
            f"Saved {rec.name} as label {rec.label} ({int(rec.selection.sum()):,} selected): "
            "click the next object on an anchor, or Export Objects",
        )
        return {"FINISHED"}

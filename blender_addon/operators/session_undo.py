"""Undo View: undo the last accepted view (exact)."""

from __future__ import annotations

import bpy

from ..reporting import report_exception
from ..session_actions import undo
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_undo(SessionOperator, bpy.types.Operator):
    """Undo the last accepted view (exact)"""

    bl_idname = "divas.session_undo"
    bl_label = "Undo View"
    bl_options = {"REGISTER"}

    def execute(self, context):
        obj, live = live_session(context)
        try:
            v = undo(context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        if v is None:
            self.report({"WARNING"}, "Nothing to undo")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Undid view {v.id}")
        return {"FINISHED"}

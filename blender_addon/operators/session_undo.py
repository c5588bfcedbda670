"""Take Back Last View: undo the last accepted view (exact; one undo step itself).

Ctrl+Z undoes any step (Blender's undo, :mod:`..session_actions.history`); this takes
back the last *accepted* view whatever came after it, and is what headless scripts use.
"""

from __future__ import annotations

import bpy

from ..reporting import report_exception
from ..session_actions import run_step, undo
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_undo(SessionOperator, bpy.types.Operator):
    """Take back the last accepted view (exact): it opens again for more clicks"""

    bl_idname = "divas.session_undo"
    bl_label = "Take Back Last View"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        obj, live = live_session(context)
        try:
            v = run_step(obj, live, "Take back last view", undo, context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        if v is None:
            self.report({"WARNING"}, "No accepted view to take back: accept a view first")
            return {"CANCELLED"}
        self.report(
            {"INFO"},
            "Took back the last accepted view: it is open again, so click to fix its mask "
            "and press Enter, or click another anchor",
        )
        return {"FINISHED"}

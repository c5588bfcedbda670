"""Sync Pending Views: fuse every pending NeRF mask now (one undo step)."""

from __future__ import annotations

import bpy

from ..reporting import report_exception
from ..session_actions import run_step, sync
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_sync(SessionOperator, bpy.types.Operator):
    """Fuse every pending NeRF mask now"""

    bl_idname = "divas.session_sync"
    bl_label = "Sync Pending Views"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        obj, live = live_session(context)
        try:
            res = run_step(obj, live, "Sync pending views", sync, context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        msg = f"Added {len(res.fused)} waiting view(s) to the selection"
        if res.rejected:
            msg += (
                f"; {len(res.rejected)} were not added (open them to add clicks, then "
                "press Enter again)"
            )
        self.report({"INFO"}, msg)
        return {"FINISHED"}

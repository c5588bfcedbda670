"""Sync Pending Views: fuse every pending NeRF mask now."""

from __future__ import annotations

import bpy

from ..reporting import report_exception
from ..session_actions import sync
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_sync(SessionOperator, bpy.types.Operator):
    """Fuse every pending NeRF mask now"""

    bl_idname = "divas.session_sync"
    bl_label = "Sync Pending Views"
    bl_options = {"REGISTER"}

    def execute(self, context):
        obj, live = live_session(context)
        try:
            res = sync(context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, f"{len(res.fused)} views fused, {len(res.rejected)} rejected")
        return {"FINISHED"}

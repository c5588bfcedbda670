"""Resume DivAS Session: reload the active object's saved session (replayed by the
engine; no segmenter runs)."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, StringProperty

from .. import source
from ..reporting import report_exception
from ..session_actions import autosave_path, resume
from .start_session import DEVICE_ITEMS, SEGMENTER_ITEMS, start_settings


class DIVAS_OT_resume_session(bpy.types.Operator):
    """Reload the autosaved DivAS session of the active object (replayed, no segmenter runs)"""

    bl_idname = "divas.resume_session"
    bl_label = "Resume DivAS Session"
    bl_options = {"REGISTER"}

    filepath: StringProperty(
        name="Session File",
        subtype="FILE_PATH",
        description="Saved session .json (default: the autosave)",
    )
    segmenter: EnumProperty(name="Segmenter", items=SEGMENTER_ITEMS, default="PREFERENCES")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="PREFERENCES")
    cameras: StringProperty(name="Training Cameras", subtype="FILE_PATH")
    gt_labels: StringProperty(name="Ground Truth", subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        if source.source_of(context.active_object) is None:
            cls.poll_message_set("Select the DivAS-imported point cloud the session was made on")
            return False
        return True

    def execute(self, context):
        obj = context.active_object
        path = bpy.path.abspath(self.filepath) if self.filepath else str(autosave_path(obj))
        try:
            settings = start_settings(
                context,
                obj,
                segmenter=self.segmenter,
                device=self.device,
                cameras=self.cameras,
                gt_labels=self.gt_labels,
                autosave=path,
            )
            live = resume(context, obj, path, settings)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        c = live.counts()
        ok = "" if live.session.replay_matches else " (replay differs from the saved labels!)"
        self.report(
            {"INFO" if ok == "" else "WARNING"},
            f"Resumed {c['accepted']} accepted views, {c['selected']:,} selected{ok}",
        )
        return {"FINISHED"}

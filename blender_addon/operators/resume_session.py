"""Resume DivAS Session: reload the active object's saved session (replayed by the
engine; no segmenter runs) — the one beside the open .blend, else its recovery autosave
(:func:`..session_actions.saved_session_path`)."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, StringProperty

from .. import source
from ..reporting import report_exception
from ..session_actions import resume, saved_session_path
from .start_session import DEVICE_ITEMS, SEGMENTER_ITEMS, start_settings


class DIVAS_OT_resume_session(bpy.types.Operator):
    """Reload the saved DivAS session of the active object (replayed, no segmenter runs)"""

    bl_idname = "divas.resume_session"
    bl_label = "Resume DivAS Session"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(
        name="Session File",
        subtype="FILE_PATH",
        description="Saved session .json (default: the one saved with this .blend, else "
        "the recovery autosave)",
    )
    segmenter: EnumProperty(name="Segmenter", items=SEGMENTER_ITEMS, default="PREFERENCES")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="PREFERENCES")
    cameras: StringProperty(name="Training Cameras", subtype="FILE_PATH")
    gt_labels: StringProperty(name="Ground Truth", subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        if source.source_of(context.active_object) is None:
            cls.poll_message_set("Select the imported splats the session was made on, then Resume")
            return False
        return True

    def execute(self, context):
        obj = context.active_object
        try:
            if self.filepath:
                path = bpy.path.abspath(self.filepath)
            else:
                found = saved_session_path(obj)
                if found is None:
                    raise ValueError(
                        f"No saved DivAS session was found for {obj.name!r}: press Start "
                        "DivAS to begin one"
                    )
                path = str(found)
            settings = start_settings(
                context,
                obj,
                segmenter=self.segmenter,
                device=self.device,
                cameras=self.cameras,
                gt_labels=self.gt_labels,
            )
            live = resume(context, obj, path, settings)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        c = live.counts()
        msg = (
            f"Resumed where you left off: {c['accepted']} accepted views, "
            f"{c['selected']:,} selected. Click the object to add more"
        )
        if not live.session.replay_matches:
            msg = (
                "Resumed, but the replayed selection differs from the saved one (the scene "
                "file or DivAS changed since): check it before exporting"
            )
        self.report({"INFO" if live.session.replay_matches else "WARNING"}, msg)
        return {"FINISHED"}

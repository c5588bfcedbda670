"""Add Camera as Anchor: manual anchor selection, when the offered anchors do not show
the whole target."""

from __future__ import annotations

import bpy
from bpy.props import StringProperty

from ..reporting import report_exception
from ..session_actions import add_anchor, run_step
from .session_base import SessionOperator, live_session


class DIVAS_OT_session_add_anchor(SessionOperator, bpy.types.Operator):
    """Add a camera as one more anchor (manual anchor selection): a training camera, or one
    you aligned to the viewport, when the offered anchors do not show the whole target"""

    bl_idname = "divas.session_add_anchor"
    bl_label = "Add Camera as Anchor"
    bl_options = {"REGISTER", "UNDO"}

    camera: StringProperty(
        options={"SKIP_SAVE"},
        name="Camera",
        default="",
        description="Camera object (default: the active object when it is "
        "a camera, else the scene camera)",
    )

    def execute(self, context):
        obj, live = live_session(context)
        try:
            if self.camera:
                cam = bpy.data.objects.get(self.camera)
                if cam is None:
                    raise ValueError(
                        f"There is no object named {self.camera!r}: pick a camera from the list"
                    )
            else:
                act = context.active_object
                cam = act if act is not None and act.type == "CAMERA" else context.scene.camera
            i = run_step(obj, live, "Add anchor", add_anchor, context, obj, live, cam)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report(
            {"INFO"}, f"{cam.name} is now anchor {i}: click the object on it to open a view"
        )
        return {"FINISHED"}

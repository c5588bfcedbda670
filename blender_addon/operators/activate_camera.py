"""Look through a DivAS camera with the render size and pixel aspect it was made for."""

from __future__ import annotations

import bpy

from ..camera_objects import apply_render_settings, is_divas_camera
from ..session_actions.view_cameras import fill_backgrounds


class DIVAS_OT_activate_camera(bpy.types.Operator):
    """Make the active camera the scene camera, set its own resolution and look through it"""

    bl_idname = "divas.activate_camera"
    bl_label = "Look Through Camera"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.active_object is not None and context.active_object.type == "CAMERA"

    def execute(self, context):
        obj = context.active_object
        fill_backgrounds(context)  # a lazy anchor's view renders when first looked through
        apply_render_settings(context.scene, obj)
        space = context.space_data
        if space is not None and space.type == "VIEW_3D":
            space.region_3d.view_perspective = "CAMERA"
        if not is_divas_camera(obj):
            self.report({"INFO"}, f"{obj.name} has no stored DivAS resolution; scene size kept")
        return {"FINISHED"}

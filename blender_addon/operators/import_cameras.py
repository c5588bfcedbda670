"""File › Import › Training Cameras: cameras.json, transforms.json or a COLMAP model."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ImportHelper, orientation_helper

from .. import source
from ..importers import CameraImportSettings, import_cameras
from ..reporting import USER_ERRORS, report_failure


@orientation_helper(axis_forward="Z", axis_up="-Y")
class DIVAS_OT_import_cameras(bpy.types.Operator, ImportHelper):
    """Import training cameras with exact intrinsics (lens, sensor, shift, pixel aspect),
    in the frame of the splats they were trained with"""

    bl_idname = "divas.import_cameras"
    bl_label = "Import Training Cameras"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json;*.bin;*.txt", options={"HIDDEN"})
    collection_name: StringProperty(name="Collection", default="DivAS Cameras")
    parent_to_active: BoolProperty(
        name="Parent to Active Splats",
        default=True,
        description="Parent the cameras to the active DivAS splat object, so they share "
        "its transform (Forward/Up are then not used)",
    )

    def execute(self, context):
        active = context.active_object
        parent = (
            active.name if self.parent_to_active and source.source_of(active) is not None else None
        )
        settings = CameraImportSettings(
            Path(self.filepath),
            self.collection_name,
            forward=self.axis_forward,
            up=self.axis_up,
            parent=parent,
        )
        try:
            objs = import_cameras(context, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        where = f", parented to {parent!r}" if parent else ""
        self.report({"INFO"}, f"Imported {len(objs)} cameras from {settings.filepath.name}{where}")
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(
        DIVAS_OT_import_cameras.bl_idname,
        text="Training Cameras (cameras.json, COLMAP, transforms.json)",
    )

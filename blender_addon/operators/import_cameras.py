"""File › Import › Training Cameras: cameras.json, transforms.json or a COLMAP model."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import StringProperty
from bpy_extras.io_utils import ImportHelper

from ..importers import CameraImportSettings, import_cameras
from ..reporting import USER_ERRORS, report_failure


class DIVAS_OT_import_cameras(bpy.types.Operator, ImportHelper):
    """Import training cameras with exact intrinsics (lens, sensor, shift, pixel aspect)"""

    bl_idname = "divas.import_cameras"
    bl_label = "Import Training Cameras"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json;*.bin;*.txt", options={"HIDDEN"})
    collection_name: StringProperty(name="Collection", default="DivAS Cameras")

    def execute(self, context):
        settings = CameraImportSettings(Path(self.filepath), self.collection_name)
        try:
            objs = import_cameras(context, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        self.report({"INFO"}, f"Imported {len(objs)} cameras from {settings.filepath.name}")
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(
        DIVAS_OT_import_cameras.bl_idname,
        text="Training Cameras (cameras.json, COLMAP, transforms.json)",
    )

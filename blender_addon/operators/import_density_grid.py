"""File › Import › NeRF Density Grid (.npz): occupied voxels as a point cloud."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper, orientation_helper

from ..importers import GridImportSettings, import_density_grid
from ..reporting import USER_ERRORS, report_failure


@orientation_helper(axis_forward="Y", axis_up="Z")
class DIVAS_OT_import_density_grid(bpy.types.Operator, ImportHelper):
    """Import a NeRF density grid (.npz) as a point cloud of its occupied voxels"""

    bl_idname = "divas.import_density_grid"
    bl_label = "Import NeRF Density Grid"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".npz"
    filter_glob: StringProperty(default="*.npz", options={"HIDDEN"})
    min_opacity: FloatProperty(
        name="Minimum Opacity",
        default=0.01,
        min=0.0,
        max=1.0,
        description="Skip voxels whose cell opacity 1 - exp(-density * voxel) is below this",
    )
    display: BoolProperty(name="Display", default=True)

    def execute(self, context):
        settings = GridImportSettings(
            Path(self.filepath),
            self.min_opacity,
            self.display,
            forward=self.axis_forward,
            up=self.axis_up,
        )
        try:
            obj = import_density_grid(context, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        self.report(
            {"INFO"}, f"Imported {len(obj.data.points):,} voxels from {settings.filepath.name}"
        )
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(DIVAS_OT_import_density_grid.bl_idname, text="NeRF Density Grid (.npz)")

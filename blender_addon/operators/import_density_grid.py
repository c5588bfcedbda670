"""File › Import › NeRF (DivAS): a density grid as a Volume (or points) with its cameras."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ImportHelper, orientation_helper

from ..importers import GridImportSettings, import_density_grid
from ..reporting import USER_ERRORS, report_failure


@orientation_helper(axis_forward="Y", axis_up="Z")
class DIVAS_OT_import_density_grid(bpy.types.Operator, ImportHelper):
    """Import a NeRF density grid (.npz, instant-ngp .ingp/.msgpack, torch-ngp .pth, .vdb)
    as a Volume of its density (or as points), with the training cameras it holds"""

    bl_idname = "divas.import_density_grid"
    bl_label = "Import NeRF"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ingp"
    filter_glob: StringProperty(default="*.npz;*.ingp;*.msgpack;*.pth;*.vdb", options={"HIDDEN"})
    min_opacity: FloatProperty(
        name="Minimum Opacity",
        default=0.01,
        min=0.0,
        max=1.0,
        description="Skip voxels whose cell opacity 1 - exp(-density * voxel) is below this",
    )
    display_as: EnumProperty(
        name="Display",
        items=(
            ("VOLUME", "Volume", "A Volume object of the density (Cycles, EEVEE)"),
            ("POINTS", "Points", "The occupied voxels as points"),
        ),
        default="VOLUME",
    )
    display: BoolProperty(name="Points Display", default=True)
    cameras: BoolProperty(
        name="Training Cameras",
        default=True,
        description="Import the training cameras the file holds (instant-ngp snapshots)",
    )

    def execute(self, context):
        settings = GridImportSettings(
            Path(self.filepath),
            self.min_opacity,
            self.display,
            forward=self.axis_forward,
            up=self.axis_up,
            volume=self.display_as == "VOLUME",
            cameras=self.cameras,
        )
        try:
            notes: list[str] = []
            obj = import_density_grid(context, settings, notes)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        msg = f"Imported {len(obj.data.points):,} voxels from {settings.filepath.name}"
        if notes:
            self.report({"WARNING"}, f"{msg}, {notes[0]}")
        else:
            self.report({"INFO"}, msg)
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(DIVAS_OT_import_density_grid.bl_idname, text="NeRF (DivAS)")

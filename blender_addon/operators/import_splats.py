"""File › Import › Gaussian Splats: 2DGS/3DGS .ply, compressed .ply, .splat, .spz."""

from __future__ import annotations

import time
from pathlib import Path

import bpy
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..importers import SplatImportSettings, import_splats
from ..reporting import USER_ERRORS, report_failure


class DIVAS_OT_import_splats(bpy.types.Operator, ImportHelper):
    """Import a Gaussian-splat scene as a point cloud carrying every file property"""

    bl_idname = "divas.import_splats"
    bl_label = "Import Gaussian Splats"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply;*.splat;*.spz", options={"HIDDEN"})
    display: BoolProperty(
        name="Display",
        default=True,
        description="Add the DivAS Geometry Nodes display (radius, colour, opacity)",
    )

    def execute(self, context):
        settings = SplatImportSettings(Path(self.filepath), display=self.display)
        t0 = time.perf_counter()
        try:
            obj = import_splats(context, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        n = len(obj.data.points)
        self.report(
            {"INFO"},
            f"Imported {n:,} splats from {settings.filepath.name} "
            f"in {time.perf_counter() - t0:.1f} s",
        )
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(
        DIVAS_OT_import_splats.bl_idname, text="Gaussian Splats (.ply, .splat, .spz)"
    )

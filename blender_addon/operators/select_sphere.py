"""Select Splats in Sphere: the splats within a radius of a 3D point (default: the 3D
cursor), in Blender's modes (one undo step)."""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, FloatVectorProperty

from divas_engine.selection_tools import in_sphere

from .. import point_edits
from .point_edit_base import PointEditOperator, mode_property


class DIVAS_OT_select_sphere(PointEditOperator, bpy.types.Operator):
    """Select the splats inside a sphere around the 3D cursor (or a given centre)"""

    bl_idname = "divas.select_sphere"
    bl_label = "Select Splats in Sphere"
    bl_options = {"REGISTER", "UNDO"}

    use_cursor: BoolProperty(name="At 3D Cursor", default=True)
    center: FloatVectorProperty(name="Centre", size=3, subtype="XYZ")
    radius: FloatProperty(name="Radius", default=0.25, min=0.0, subtype="DISTANCE")
    mode: mode_property("ADD")

    def execute(self, context):
        centre = (
            np.array(context.scene.cursor.location) if self.use_cursor else np.array(self.center)
        )

        def select(t):
            mw = np.array(t.obj.matrix_world, np.float64)
            world = point_edits.positions(t) @ mw[:3, :3].T + mw[:3, 3]
            return point_edits.apply_region(t, in_sphere(world, centre, self.radius), self.mode)

        return self.run(context, "Sphere select", select, done="{n} splats selected")

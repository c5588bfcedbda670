"""Select by Opacity / Size: splats whose opacity or size lies in a range (one undo
step) — e.g. faint floaters (opacity below 0.1) or huge blurry splats."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty

from divas_engine.selection_tools import in_range

from .. import point_edits
from .point_edit_base import PointEditOperator, mode_property

ATTRIBUTES = (
    ("OPACITY", "Opacity", "The splat's opacity α, 0–1"),
    ("SIZE", "Size", "The splat's size √(s₁s₂) in the scene's units"),
)


class DIVAS_OT_select_by_attribute(PointEditOperator, bpy.types.Operator):
    """Select the splats whose opacity or size lies between Minimum and Maximum"""

    bl_idname = "divas.select_by_attribute"
    bl_label = "Select by Opacity / Size"
    bl_options = {"REGISTER", "UNDO"}

    attribute: EnumProperty(name="By", items=ATTRIBUTES, default="OPACITY")
    use_minimum: BoolProperty(name="Use Minimum", default=False)
    minimum: FloatProperty(name="Minimum", default=0.0)
    use_maximum: BoolProperty(name="Use Maximum", default=True)
    maximum: FloatProperty(name="Maximum", default=0.1)
    mode: mode_property()

    def execute(self, context):
        def select(t):
            if self.attribute == "OPACITY":
                values = point_edits.point_opacities(t)
            else:
                values = point_edits.point_sizes(t)
            region = in_range(
                values,
                self.minimum if self.use_minimum else None,
                self.maximum if self.use_maximum else None,
            )
            return point_edits.apply_region(t, region, self.mode)

        return self.run(
            context, f"Select by {self.attribute.lower()}", select, done="{n} splats selected"
        )

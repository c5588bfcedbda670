"""Grow / Shrink Selection: by the splats' 3D neighbourhood (one undo step)."""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty

from divas_engine.selection_tools import grow, neighbour_radius, shrink

from .. import point_edits
from .point_edit_base import PointEditOperator

#: the automatic radius of the last object (its k-d tree is slow to build on a large scene).
_radius_cache: dict[tuple, float] = {}


def auto_radius(geom, pts) -> float:
    """:func:`~divas_engine.selection_tools.neighbour_radius` of the points, cached while
    they do not change."""
    key = (geom.name, len(pts), float(pts.sum(dtype=np.float64)))
    if key not in _radius_cache:
        _radius_cache.clear()
        _radius_cache[key] = neighbour_radius(pts)
    return _radius_cache[key]


class DIVAS_OT_select_grow(PointEditOperator, bpy.types.Operator):
    """Grow (or shrink) the selection by the splats within a radius of it, in 3D"""

    bl_idname = "divas.select_grow"
    bl_label = "Grow / Shrink Selection"
    bl_options = {"REGISTER", "UNDO"}

    shrink: BoolProperty(name="Shrink", default=False)
    radius: FloatProperty(
        name="Radius",
        default=0.0,
        min=0.0,
        subtype="DISTANCE",
        description="Neighbourhood radius in the object's units (0: twice the typical "
        "spacing of the splats)",
    )
    steps: IntProperty(name="Steps", default=1, min=1, soft_max=20)

    def execute(self, context):
        def select(t):
            pts, ok = point_edits.positions(t), point_edits.visible(t)
            r = self.radius or auto_radius(t.geom, pts)
            fn = shrink if self.shrink else grow
            new = fn(pts, point_edits.selected(t), r, self.steps, allowed=ok)
            return point_edits.set_selection(t, new)

        what = "Shrink selection" if self.shrink else "Grow selection"
        return self.run(context, what, select, done="{n} splats selected")

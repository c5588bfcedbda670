"""Select Splats in Region: box, lasso or circle (brush) select of splats in a 3D view,
in Blender's modes (one undo step).

The region shape is in region pixels (origin bottom-left); the view is the region's
``perspective_matrix`` and size — given as properties (scripts, tests), else read from
the context's 3D view. The geometry is :mod:`divas_engine.selection_tools`.
"""

from __future__ import annotations

import json

import bpy
import numpy as np
from bpy.props import (
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntVectorProperty,
    StringProperty,
)

from divas_engine.selection_tools import RegionView, in_box, in_circle, in_lasso, project_to_region

from .. import point_edits
from .point_edit_base import PointEditOperator, mode_property

_IDENTITY = tuple(np.eye(4).ravel())
SHAPES = (
    ("BOX", "Box", "A rectangle: two opposite corners"),
    ("LASSO", "Lasso", "A closed outline of three or more points"),
    ("CIRCLE", "Circle", "A brush: its centre and Radius"),
)


def region_of(context, matrix, size) -> RegionView:
    """The view to select in: the given matrix and size, else the context's 3D view."""
    if size[0] > 0 and size[1] > 0:
        return RegionView(np.array(matrix, np.float64).reshape(4, 4), int(size[0]), int(size[1]))
    rv3d, region = getattr(context, "region_data", None), getattr(context, "region", None)
    if rv3d is None or region is None or region.type != "WINDOW":
        raise ValueError("Select in a 3D view: there is no 3D view here to select in")
    return RegionView(np.array(rv3d.perspective_matrix), region.width, region.height)


def region_mask(t, view: RegionView, shape: str, pts: np.ndarray, radius: float) -> np.ndarray:
    """The points of ``t`` inside the region shape."""
    xy, front = project_to_region(point_edits.positions(t), view, np.array(t.obj.matrix_world))
    if shape == "BOX":
        if len(pts) != 2:
            raise ValueError("A box needs two corners [[x0, y0], [x1, y1]]")
        return in_box(xy, front, (*pts[0], *pts[1]))
    if shape == "LASSO":
        if len(pts) < 3:
            raise ValueError("A lasso needs at least three points: draw a longer outline")
        return in_lasso(xy, front, pts)
    if len(pts) != 1:
        raise ValueError("A circle needs its centre [[x, y]]")
    return in_circle(xy, front, pts[0], radius)


class DIVAS_OT_select_region(PointEditOperator, bpy.types.Operator):
    """Select the splats inside a box, lasso or circle of a 3D view"""

    bl_idname = "divas.select_region"
    bl_label = "Select Splats in Region"
    bl_options = {"REGISTER", "UNDO"}

    shape: EnumProperty(options={"SKIP_SAVE"}, name="Shape", items=SHAPES, default="BOX")
    points: StringProperty(
        options={"SKIP_SAVE"},
        name="Points",
        default="",
        description="JSON [[x, y], ...] in region pixels",
    )
    radius: FloatProperty(name="Radius", default=25.0, min=0.0, subtype="PIXEL")
    mode: mode_property()
    perspective_matrix: FloatVectorProperty(
        options={"SKIP_SAVE"}, name="View", size=16, default=_IDENTITY
    )
    region_size: IntVectorProperty(
        options={"SKIP_SAVE"}, name="Region Size", size=2, default=(0, 0), min=0
    )

    def execute(self, context):
        try:
            pts = np.asarray(json.loads(self.points or "[]"), np.float64).reshape(-1, 2)
            view = region_of(context, self.perspective_matrix, self.region_size)
        except (ValueError, TypeError) as e:
            self.report({"ERROR"}, f"{e}: give the shape's points as JSON [[x, y], ...]")
            return {"CANCELLED"}

        def select(t):
            region = region_mask(t, view, self.shape, pts, self.radius)
            return point_edits.apply_region(t, region, self.mode)

        return self.run(
            context,
            f"{self.shape.title()} select",
            select,
            done="{n} splats selected. Shift adds, Ctrl subtracts; Ctrl+Z undoes",
        )

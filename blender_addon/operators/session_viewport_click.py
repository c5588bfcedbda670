"""Click in View: a click on the object in any 3D view turns the view into an anchor (its
camera reconstructed exactly from the region's view and window matrices and size) and
proceeds as a click on that anchor (one undo step).

From a script, pass the region's matrices and size (``RegionView3D.view_matrix``,
``window_matrix``, the region's width and height) and the click's region pixel; run from
a 3D view without them, the operator reads them from the context's region.
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatVectorProperty, IntVectorProperty

from ..reporting import report_exception
from ..session_actions import run_step, viewport_click
from .session_base import SessionOperator, live_session
from .session_click import click_message

_IDENTITY = tuple(np.eye(4).ravel())


def region_view(context):
    """``(view_matrix, window_matrix, (width, height))`` of the context's 3D view region."""
    rv3d, region = getattr(context, "region_data", None), getattr(context, "region", None)
    if rv3d is None or region is None or getattr(region, "type", "") != "WINDOW":
        raise ValueError(
            "Run Click in View from a 3D view (or pass its matrices and size): "
            "there is no 3D view here"
        )
    return (
        np.array(rv3d.view_matrix, np.float64),
        np.array(rv3d.window_matrix, np.float64),
        (int(region.width), int(region.height)),
    )


class DIVAS_OT_session_viewport_click(SessionOperator, bpy.types.Operator):
    """Click the object in this 3D view: the view becomes an anchor and the click opens a
    close-up view, as on an anchor camera"""

    bl_idname = "divas.session_viewport_click"
    bl_label = "Click in View"
    bl_options = {"REGISTER", "UNDO"}

    view_matrix: FloatVectorProperty(
        options={"SKIP_SAVE"}, name="View Matrix", size=16, default=_IDENTITY
    )
    window_matrix: FloatVectorProperty(
        options={"SKIP_SAVE"}, name="Window Matrix", size=16, default=_IDENTITY
    )
    region_size: IntVectorProperty(
        options={"SKIP_SAVE"}, name="Region Size", size=2, default=(0, 0), min=0
    )
    mouse: IntVectorProperty(options={"SKIP_SAVE"}, name="Region Pixel", size=2, default=(0, 0))
    positive: BoolProperty(options={"SKIP_SAVE"}, name="Positive", default=True)

    def execute(self, context):
        obj, live = live_session(context)
        try:
            if self.region_size[0] > 0 and self.region_size[1] > 0:
                vm = np.array(self.view_matrix, np.float64).reshape(4, 4)
                wm = np.array(self.window_matrix, np.float64).reshape(4, 4)
                size = (int(self.region_size[0]), int(self.region_size[1]))
            else:
                vm, wm, size = region_view(context)
            what = f"{'Click' if self.positive else 'Negative click'} in a 3D view"
            anchor, _ = run_step(
                obj,
                live,
                what,
                viewport_click,
                context,
                obj,
                live,
                vm,
                wm,
                size,
                tuple(self.mouse),
                self.positive,
            )
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, click_message(anchor, self.positive))
        return {"FINISHED"}

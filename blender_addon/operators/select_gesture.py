"""Box / Lasso / Brush Select: draw the shape in a 3D view to select splats (a modal;
the selection itself is :mod:`.select_region`'s, one undo step per gesture).

Plain drag: set; Shift: extend; Ctrl: subtract; Shift+Ctrl: intersect (the brush adds,
or subtracts with Ctrl, while the button is held; the wheel changes its size). Esc or
RMB cancels. The event logic is the pure :class:`..modal_logic.Gesture`.
"""

from __future__ import annotations

import bpy
import numpy as np
from bpy.props import EnumProperty, FloatProperty

from divas_engine.selection_tools import RegionView

from .. import draw, point_edits
from ..modal_logic import Gesture
from ..reporting import report_exception
from ..session_actions import commit, rollback
from .point_edit_base import PointEditOperator
from .select_region import SHAPES, region_mask


class DIVAS_OT_select_gesture(PointEditOperator, bpy.types.Operator):
    """Draw a box, a lasso or a brush stroke in the 3D view to select splats"""

    bl_idname = "divas.select_gesture"
    bl_label = "Select Splats (Draw)"
    bl_options = {"REGISTER"}

    shape: EnumProperty(name="Shape", items=SHAPES, default="BOX")
    radius: FloatProperty(name="Brush Radius", default=25.0, min=2.0, subtype="PIXEL")

    @classmethod
    def poll(cls, context):
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Run it from a 3D Viewport")
            return False
        return super().poll(context)

    def invoke(self, context, event):
        area = context.area
        self._region = next((r for r in area.regions if r.type == "WINDOW"), None)
        self._rv3d = area.spaces.active.region_3d
        self._area = area
        self._gesture = Gesture(self.shape, self.radius)
        self._stroke = False
        try:
            self._target = point_edits.edit_target(context)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self._initial = point_edits.selected(self._target)  # back to it if cancelled
        self._handle = draw.add_gesture_handler(self._gesture)
        area.header_text_set(
            "Drag to select · Shift: extend · Ctrl: subtract · Shift+Ctrl: intersect · Esc: cancel"
        )
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _undo_stroke(self) -> None:
        """A cancelled brush stroke leaves the selection as it was."""
        if not self._stroke:
            return
        t = self._target
        if t.live is not None:
            rollback(t.obj, t.live)
        else:
            point_edits.set_selection(t, self._initial)

    def _finish(self, result: set[str]) -> set[str]:
        draw.remove_handler(self._handle)
        self._area.header_text_set(None)
        self._area.tag_redraw()
        return result

    def modal(self, context, event):
        r = self._region
        x, y = event.mouse_x - r.x, event.mouse_y - r.y
        act = self._gesture.feed(event.type, event.value, x, y, shift=event.shift, ctrl=event.ctrl)
        self._area.tag_redraw()
        if act.kind == "pass":
            return {"PASS_THROUGH"}
        if act.kind == "cancel":
            self._undo_stroke()
            return self._finish({"CANCELLED"})
        if act.kind != "apply":
            return {"RUNNING_MODAL"}
        t = self._target
        try:
            if act.points:
                view = RegionView(np.array(self._rv3d.perspective_matrix), r.width, r.height)
                pts = np.asarray(act.points, np.float64)
                region = region_mask(t, view, act.shape, pts, act.radius)
                point_edits.apply_region(t, region, act.mode, autosave=False)
                self._stroke = True
            if act.final and self._stroke:
                what = f"{act.shape.title()} select"
                if t.live is not None:
                    commit(t.obj, t.live, what)
                    save = t.live.session.config.autosave
                    if save:
                        t.live.session.save(save)
                bpy.ops.ed.undo_push(message=f"DivAS: {what}")
        except Exception as e:  # noqa: BLE001
            report_exception(self, e)
            self._undo_stroke()
            return self._finish({"CANCELLED"})
        return self._finish({"FINISHED"}) if act.final else {"RUNNING_MODAL"}

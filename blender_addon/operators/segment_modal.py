"""Click to Segment: a modal operator in the 3D viewport, looking through a DivAS camera.

LMB positive, Shift+LMB / RMB negative, Enter accept, Backspace undo, Esc leave (the
header shows the keys). What an event means is decided by the pure
:mod:`..modal_logic`; :class:`ModalController` only maps the mouse onto the camera's
image (:func:`..view3d.click_to_camera_pixel`) and runs the resulting step with
:mod:`..session_actions`. The operator keeps the 3D view's main region from ``invoke``
(it may be started from the sidebar, whose region is not the one clicked in).
"""

from __future__ import annotations

from collections.abc import Callable

import bpy

from divas_engine.kinds import ViewStatus

from .. import session_registry
from ..modal_logic import HEADER_TEXT, KeyKind, Step, StepKind, decide, plan
from ..reporting import report_exception
from ..session_actions import accept, activate_camera, add_prompt, camera_target, click, undo
from ..view3d import click_to_camera_pixel

__all__ = ["DIVAS_OT_segment_modal", "ModalController"]


class ModalController:
    """Runs the modal's events against the live session of ``object_name``.

    Args:
        report: ``operator.report``.
        region, rv3d: the 3D view's main (``WINDOW``) region and its ``RegionView3D``.
        area: the 3D view area (header text, redraws); None headless.
        pixel_fn: ``(region, rv3d, scene, camera, mouse_xy) -> (u, v) | None``.
    """

    def __init__(
        self,
        object_name: str,
        report: Callable,
        *,
        region=None,
        rv3d=None,
        area=None,
        pixel_fn: Callable = click_to_camera_pixel,
    ) -> None:
        self.object_name = object_name
        self.report = report
        self.region, self.rv3d, self.area = region, rv3d, area
        self.pixel_fn = pixel_fn
        self.last_step: Step | None = None

    # ------------------------------------------------------------------ helpers
    def _mouse(self, event) -> tuple[int, int] | None:
        """Mouse position in the main region, None outside it or over a region drawn on top
        of it (sidebar, toolbar, header … with Region Overlap)."""
        r = self.region
        if r is None:
            return None
        x, y = event.mouse_x, event.mouse_y
        if not _inside(r, x, y):
            return None
        for other in getattr(self.area, "regions", ()):
            if (
                other.type != "WINDOW"
                and other.width > 1
                and other.height > 1
                and _inside(other, x, y)
            ):
                return None
        return x - r.x, y - r.y

    def header(self, live=None) -> str:
        if live is None:
            return HEADER_TEXT
        c = live.session.counts()
        return f"{HEADER_TEXT}   |   {c['accepted']} views fused, {c['selected']:,} selected"

    def set_header(self, text: str | None) -> None:
        if self.area is not None:
            self.area.header_text_set(text)
            self.area.tag_redraw()

    def close(self) -> None:
        self.set_header(None)

    # ------------------------------------------------------------------ events
    def handle(self, context, event) -> set[str]:
        obj = bpy.data.objects.get(self.object_name)
        live = session_registry.get(obj)
        if live is None:
            self.report({"WARNING"}, "The DivAS session has ended")
            self.close()
            return {"CANCELLED"}
        mouse = self._mouse(event)
        key = decide(event.type, event.value, shift=event.shift, in_region=mouse is not None)
        if key.kind is KeyKind.PASS:
            return {"PASS_THROUGH"}
        cam = context.scene.camera
        target = camera_target(live, cam)
        xy = None
        if key.kind is KeyKind.CLICK and (target.is_anchor or target.is_view):
            xy = self.pixel_fn(self.region, self.rv3d, context.scene, cam, mouse)
        step = plan(key, target, xy)
        self.last_step = step
        return self.run(context, obj, live, step)

    def run(self, context, obj, live, step: Step) -> set[str]:
        k = step.kind
        if k is StepKind.PASS:
            return {"PASS_THROUGH"}
        if k is StepKind.NOTHING:
            return {"RUNNING_MODAL"}
        if k is StepKind.EXIT:
            self.close()
            return {"FINISHED"}
        if k is StepKind.MESSAGE:
            self.report({"WARNING"}, step.message)
            return {"RUNNING_MODAL"}
        try:
            if k in (StepKind.SPAWN, StepKind.ANCHOR_NEGATIVE):
                click(context, obj, live, step.anchor, step.xy, step.positive)
            elif k is StepKind.PROMPT:
                add_prompt(context, obj, live, step.view_id, step.xy, step.positive)
            elif k is StepKind.ACCEPT:
                res = accept(context, obj, live, step.view_id)
                if res.view.status == ViewStatus.REJECTED:
                    self.report(
                        {"WARNING"},
                        f"View rejected: {res.view.reason}; add points and press Enter again",
                    )
            elif k is StepKind.UNDO and undo(context, obj, live) is None:
                self.report({"WARNING"}, "Nothing to undo")
        except Exception as e:  # noqa: BLE001 - reported; the modal keeps running
            report_exception(_Reporter(self.report), e)
        self.set_header(self.header(live))
        return {"RUNNING_MODAL"}


def _inside(region, x: int, y: int) -> bool:
    return region.x <= x < region.x + region.width and region.y <= y < region.y + region.height


class _Reporter:
    """Adapts a ``report`` callable to what :func:`report_exception` expects."""

    def __init__(self, report: Callable) -> None:
        self.report = report


class DIVAS_OT_segment_modal(bpy.types.Operator):
    """Click the object in a DivAS view to segment it (LMB add, Shift+LMB/RMB remove,
    Enter accept, Backspace undo, Esc leave)"""

    bl_idname = "divas.segment_modal"
    bl_label = "Click to Segment"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Run it from a 3D Viewport")
            return False
        if session_registry.find(context)[1] is None:
            cls.poll_message_set("No DivAS session: select the imported object and Start DivAS")
            return False
        return True

    def invoke(self, context, event):
        obj, live = session_registry.find(context)
        area = context.area
        region = next((r for r in area.regions if r.type == "WINDOW"), None)
        space = area.spaces.active
        self._ctl = ModalController(
            obj.name, self.report, region=region, rv3d=space.region_3d, area=area
        )
        cam = context.scene.camera
        t = camera_target(live, cam)
        if not (t.is_anchor or t.is_view):
            cam = bpy.data.objects.get(live.anchor_cameras[0]) if live.anchor_cameras else None
        if cam is None:
            self.report({"ERROR"}, "The session's anchor cameras are gone; Start DivAS again")
            return {"CANCELLED"}
        activate_camera(context, cam)
        self._ctl.set_header(self._ctl.header(live))
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        return self._ctl.handle(context, event)

    def cancel(self, context):
        self._ctl.close()

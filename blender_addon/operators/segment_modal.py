"""Click to Segment: a modal operator in the 3D viewport — through a DivAS camera, or in
any free 3D view (the view becomes an anchor).

LMB positive, Shift+LMB / RMB negative — on an anchor, a centroid view (an accepted one:
a correction of the selection) or a free view, every click a 3D constraint that the
viewport shows at once —, Enter accept, Ctrl+Z / Backspace undo,
Ctrl+Shift+Z redo, Esc leave (the header shows the keys). What an event means is decided
by the pure :mod:`..modal_logic`; :class:`ModalController` only maps the mouse onto the
camera's image (:func:`..view3d.click_to_camera_pixel`) or the free view's own camera,
runs the resulting step with :mod:`..session_actions` as one session step, and pushes
one Blender undo step for it (``ed.undo_push``: a modal operator gets none of its own).
Undo and redo are Blender's (``ed.undo`` / ``ed.redo``); the session follows them
(:mod:`..session_actions.history`). The operator keeps the 3D view's main region from
``invoke`` (it may be started from the sidebar, whose region is not the one clicked in).
"""

from __future__ import annotations

from collections.abc import Callable

import bpy
import numpy as np

from divas_engine.kinds import ViewStatus

from .. import session_registry
from ..modal_logic import HEADER_TEXT, KeyKind, Step, StepKind, Target, decide, plan
from ..reporting import advice_message, report_exception, view_rejection_message
from ..session_actions import (
    accept,
    add_prompt,
    camera_target,
    click,
    correct_view,
    correction_summary,
    run_step,
    viewport_click,
)
from ..view3d import click_to_camera_pixel

__all__ = ["DIVAS_OT_segment_modal", "ModalController"]

#: the history / undo name of each step.
_WHAT = {
    StepKind.SPAWN: "Click on anchor",
    StepKind.ANCHOR_NEGATIVE: "Negative click on anchor",
    StepKind.PROMPT: "Add point to view",
    StepKind.CORRECT_VIEW: "Click on accepted view",
    StepKind.VIEWPORT_CLICK: "Click in a 3D view",
    StepKind.ACCEPT: "Accept view",
}


def _through_camera(rv3d) -> bool:
    return getattr(rv3d, "view_perspective", "CAMERA") == "CAMERA"


class ModalController:
    """Runs the modal's events against the live session of ``object_name``.

    Args:
        report: ``operator.report``.
        region, rv3d: the 3D view's main (``WINDOW``) region and its ``RegionView3D``.
        area: the 3D view area (header text, redraws); None headless.
        pixel_fn: ``(region, rv3d, scene, camera, mouse_xy) -> (u, v) | None``.
        undo_push: ``(message) -> None``, one Blender undo step after each session step.
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
        undo_push: Callable | None = None,
    ) -> None:
        self.object_name = object_name
        self.report = report
        self.region, self.rv3d, self.area = region, rv3d, area
        self.pixel_fn = pixel_fn
        self.undo_push = undo_push or (lambda msg: bpy.ops.ed.undo_push(message=msg))
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
        c = live.counts()  # never waits for the engine's warm-up
        return f"{HEADER_TEXT}   |   {c['accepted']} views added, {c['selected']:,} selected"

    def set_header(self, text: str | None) -> None:
        if self.area is not None:
            self.area.header_text_set(text)
            self.area.tag_redraw()

    def close(self) -> None:
        self.set_header(None)

    def target(self, live, scene) -> Target:
        """Through one of the session's cameras, or a free view (any other view)."""
        if _through_camera(self.rv3d):
            t = camera_target(live, scene.camera)
            if t.is_anchor or t.is_view:
                return t
        return Target(free=True)

    # ------------------------------------------------------------------ events
    def handle(self, context, event) -> set[str]:
        obj = bpy.data.objects.get(self.object_name)
        live = session_registry.get(obj)
        if live is None:
            self.report({"WARNING"}, "The DivAS session has ended (Esc to leave)")
            self.close()
            return {"CANCELLED"}
        mouse = self._mouse(event)
        key = decide(
            event.type,
            event.value,
            shift=event.shift,
            in_region=mouse is not None,
            ctrl=getattr(event, "ctrl", False),
        )
        if key.kind is KeyKind.PASS:
            return {"PASS_THROUGH"}
        target = self.target(live, context.scene)
        xy = None
        if key.kind is KeyKind.CLICK and (target.is_anchor or target.is_view):
            xy = self.pixel_fn(self.region, self.rv3d, context.scene, context.scene.camera, mouse)
        elif key.kind is KeyKind.CLICK and target.is_free and mouse is not None:
            xy = (float(mouse[0]), float(mouse[1]))
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
        if k in (StepKind.UNDO, StepKind.REDO):
            self._undo_redo(k)
            live = session_registry.get(bpy.data.objects.get(self.object_name))
        else:
            try:
                self._session_step(context, obj, live, step)
            except Exception as e:  # noqa: BLE001 - reported; the modal keeps running
                report_exception(_Reporter(self.report), e)
        self.set_header(self.header(live))
        return {"RUNNING_MODAL"}

    def _session_step(self, context, obj, live, step: Step) -> None:
        k = step.kind
        what = _WHAT[k]
        hinted = None  # the previewed object: its segmenter's hint is shown
        last = live.session.last_correction
        if k in (StepKind.SPAWN, StepKind.ANCHOR_NEGATIVE):
            hinted = run_step(obj, live, f"{what} {step.anchor}", click, context, obj, live,
                              step.anchor, step.xy, step.positive)  # fmt: skip
        elif k is StepKind.PROMPT:
            hinted = run_step(obj, live, what, add_prompt, context, obj, live, step.view_id,
                              step.xy, step.positive)  # fmt: skip
        elif k is StepKind.CORRECT_VIEW:
            res = run_step(obj, live, what, correct_view, context, obj, live, step.view_id,
                           step.xy, step.positive)  # fmt: skip
            self.report({"INFO"}, f"{what}: {correction_summary(res)}")
        elif k is StepKind.VIEWPORT_CLICK:
            r, rv = self.region, self.rv3d
            _, hinted = run_step(obj, live, what, viewport_click, context, obj, live,
                                 np.array(rv.view_matrix), np.array(rv.window_matrix),
                                 (int(r.width), int(r.height)),
                                 (int(step.xy[0]), int(step.xy[1])), step.positive)  # fmt: skip
        elif k is StepKind.ACCEPT:
            res = run_step(obj, live, what, accept, context, obj, live, step.view_id)
            v = res.view
            if v.status == ViewStatus.REJECTED:
                msg = view_rejection_message(live.session, v)
                self.report({"WARNING"}, "View not added. " + msg)
        corr = live.session.last_correction
        if k is not StepKind.CORRECT_VIEW and not step.positive and corr is not last:
            self.report({"INFO"}, f"{what}: {correction_summary(corr)}")
        hint = advice_message(getattr(hinted, "advice", None))
        if hint:
            self.report({"INFO"}, hint)
        self.undo_push(f"DivAS: {what}")

    def _undo_redo(self, kind: StepKind) -> None:
        op = bpy.ops.ed.undo if kind is StepKind.UNDO else bpy.ops.ed.redo
        word = "undo" if kind is StepKind.UNDO else "redo"
        if not op.poll():
            self.report({"WARNING"}, f"Nothing to {word}")
            return
        try:
            op()
        except RuntimeError as e:
            self.report({"WARNING"}, f"Could not {word} here ({e}): press Esc, then Ctrl+Z")


def _inside(region, x: int, y: int) -> bool:
    return region.x <= x < region.x + region.width and region.y <= y < region.y + region.height


class _Reporter:
    """Adapts a ``report`` callable to what :func:`report_exception` expects."""

    def __init__(self, report: Callable) -> None:
        self.report = report


class DIVAS_OT_segment_modal(bpy.types.Operator):
    """Click the object to segment it, through a DivAS camera or in any 3D view
    (LMB add, Shift+LMB/RMB remove, Enter accept, Ctrl+Z undo, Esc leave)"""

    bl_idname = "divas.segment_modal"
    bl_label = "Click to Segment"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.area is None or context.area.type != "VIEW_3D":
            cls.poll_message_set("Run it from a 3D Viewport")
            return False
        if session_registry.find(context)[1] is None:
            cls.poll_message_set("No DivAS session yet: select the imported splats and Start DivAS")
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
        self._ctl.set_header(self._ctl.header(live))
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        return self._ctl.handle(context, event)

    def cancel(self, context):
        self._ctl.close()

"""The session's steps as plain (``EXEC``) operators: click, accept, sync, undo, reset,
finish object, resume. The panel's buttons and headless scripts call these; the modal
(:mod:`.segment_modal`) runs the same :mod:`..session_actions` functions.

Coordinates are rendered-image pixels of the anchor (the session's), or full-camera
pixels with ``full_resolution`` (the prompts file's). RNA floats are single precision,
so ``xy`` / ``points`` also take decimal text, for clicks that must be bit-identical to
``divas segment`` (the headless script passes them so).
"""

from __future__ import annotations

import json

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from .. import session_registry, source
from ..session_actions import (
    accept,
    add_anchor,
    autosave_path,
    click,
    finish_object,
    full_to_session_xy,
    report_exception,
    reset,
    resume,
    sync,
    undo,
)
from .start_session import DEVICE_ITEMS, SEGMENTER_ITEMS, start_settings


def _live(context):
    return session_registry.find(context)


class _SessionOperator:
    """Shared poll: a live session for the active object (or the scene camera's owner)."""

    @classmethod
    def poll(cls, context):
        if _live(context)[1] is None:
            cls.poll_message_set("No DivAS session: select the imported object and Start DivAS")
            return False
        return True


def _parse_xy(text: str) -> tuple[float, float]:
    parts = text.replace(",", " ").split()
    if len(parts) != 2:
        raise ValueError(f"xy must be two numbers 'x y', got {text!r}")
    return float(parts[0]), float(parts[1])


def _parse_points(text: str):
    try:
        doc = json.loads(text)
        pts = [(float(p[0]), float(p[1])) for p in doc]
        labs = [int(bool(p[2])) if len(p) > 2 else 1 for p in doc]
    except (ValueError, TypeError, IndexError, KeyError) as e:
        raise ValueError(
            f"points must be JSON [[x, y, positive], ...], got {text!r} ({e})"
        ) from None
    return pts, labs


class DIVAS_OT_session_click(_SessionOperator, bpy.types.Operator):
    """Click on an anchor: positive spawns a centroid view, negative adds a negative prompt"""

    bl_idname = "divas.session_click"
    bl_label = "Click Anchor"
    bl_options = {"REGISTER"}

    anchor: IntProperty(name="Anchor", default=0, min=0)
    x: FloatProperty(name="X", default=0.0)
    y: FloatProperty(name="Y", default=0.0)
    xy: StringProperty(
        name="XY (exact)",
        default="",
        description="'x y' as decimal text (double precision); overrides X/Y",
    )
    positive: BoolProperty(name="Positive", default=True)
    full_resolution: BoolProperty(
        name="Full-Resolution Pixels",
        default=False,
        description="X/Y are pixels of the full camera (the prompts "
        "file's), not of the rendered image",
    )
    preview: BoolProperty(
        name="Preview",
        default=True,
        description="Segment the default prompt at once (the mask preview)",
    )

    def execute(self, context):
        obj, live = _live(context)
        try:
            xy = _parse_xy(self.xy) if self.xy else (self.x, self.y)
            if self.full_resolution:
                xy = full_to_session_xy(live, self.anchor, xy)
            res = click(context, obj, live, self.anchor, xy, self.positive, preview=self.preview)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        what = f"spawned view {res.id}" if self.positive else "negative prompt recorded"
        self.report({"INFO"}, f"Anchor {self.anchor}: {what}")
        return {"FINISHED"}


class DIVAS_OT_session_add_anchor(_SessionOperator, bpy.types.Operator):
    """Add a camera as one more anchor (manual anchor selection): a training camera, or one
    you aligned to the viewport, when the offered anchors do not show the whole target"""

    bl_idname = "divas.session_add_anchor"
    bl_label = "Add Camera as Anchor"
    bl_options = {"REGISTER"}

    camera: StringProperty(
        name="Camera",
        default="",
        description="Camera object (default: the active object when it is "
        "a camera, else the scene camera)",
    )

    def execute(self, context):
        obj, live = _live(context)
        try:
            if self.camera:
                cam = bpy.data.objects.get(self.camera)
                if cam is None:
                    raise ValueError(f"no object named {self.camera!r}")
            else:
                act = context.active_object
                cam = act if act is not None and act.type == "CAMERA" else context.scene.camera
            i = add_anchor(context, obj, live, cam)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, f"{cam.name} added as anchor {i}: click the target on it")
        return {"FINISHED"}


class DIVAS_OT_session_accept(_SessionOperator, bpy.types.Operator):
    """Accept a centroid view: fuse its mask into the 3D selection and recolour the splats"""

    bl_idname = "divas.session_accept"
    bl_label = "Accept View"
    bl_options = {"REGISTER"}

    view: StringProperty(
        name="View",
        default="",
        description="View id (default: the scene camera's view, else the next open one)",
    )
    points: StringProperty(
        name="Prompt Points",
        default="",
        description="JSON [[x, y, positive], ...] replacing the points "
        "added on the view (its default prompt stays)",
    )
    full_resolution: BoolProperty(name="Full-Resolution Pixels", default=False)

    def execute(self, context):
        obj, live = _live(context)
        try:
            pts = labs = None
            if self.points:
                pts, labs = _parse_points(self.points)
                if self.full_resolution and pts:
                    a = live.session.view(self.view).anchor if self.view else None
                    if a is None:
                        raise ValueError("full_resolution points need the view id")
                    pts = [full_to_session_xy(live, a, p) for p in pts]
            res = accept(context, obj, live, self.view or None, pts, labs)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        v = res.view
        if v.status == "rejected":
            self.report({"WARNING"}, f"View {v.id} rejected: {v.reason}")
        elif v.status == "pending":
            self.report({"INFO"}, f"View {v.id} pending ({res.pending} masks queued)")
        else:
            self.report(
                {"INFO"},
                f"View {v.id} fused: {int(live.session.selection.sum()):,} "
                f"selected ({res.timings.get('update_s', 0.0):.2f} s)",
            )
        return {"FINISHED"}


class DIVAS_OT_session_sync(_SessionOperator, bpy.types.Operator):
    """Fuse every pending NeRF mask now"""

    bl_idname = "divas.session_sync"
    bl_label = "Sync Pending Views"
    bl_options = {"REGISTER"}

    def execute(self, context):
        obj, live = _live(context)
        try:
            res = sync(context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, f"{len(res.fused)} views fused, {len(res.rejected)} rejected")
        return {"FINISHED"}


class DIVAS_OT_session_undo(_SessionOperator, bpy.types.Operator):
    """Undo the last accepted view (exact)"""

    bl_idname = "divas.session_undo"
    bl_label = "Undo View"
    bl_options = {"REGISTER"}

    def execute(self, context):
        obj, live = _live(context)
        try:
            v = undo(context, obj, live)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        if v is None:
            self.report({"WARNING"}, "Nothing to undo")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Undid view {v.id}")
        return {"FINISHED"}


class DIVAS_OT_session_reset(_SessionOperator, bpy.types.Operator):
    """Drop the current object's views and selection"""

    bl_idname = "divas.session_reset"
    bl_label = "Reset"
    bl_options = {"REGISTER"}

    all_objects: BoolProperty(
        name="All Objects", default=False, description="Also drop every finished object's label"
    )

    def execute(self, context):
        obj, live = _live(context)
        try:
            reset(context, obj, live, all_objects=self.all_objects)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, "DivAS session reset")
        return {"FINISHED"}


class DIVAS_OT_session_finish_object(_SessionOperator, bpy.types.Operator):
    """Commit the selection as the next label ('divas_label') and start a new object"""

    bl_idname = "divas.session_finish_object"
    bl_label = "Finish Object"
    bl_options = {"REGISTER"}

    name: StringProperty(name="Name", default="", description="Object name (default object_<k>)")

    def execute(self, context):
        obj, live = _live(context)
        try:
            rec = finish_object(context, obj, live, self.name or None)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report(
            {"INFO"},
            f"Finished {rec.name} (label {rec.label}, {int(rec.selection.sum()):,} primitives)",
        )
        return {"FINISHED"}


class DIVAS_OT_resume_session(bpy.types.Operator):
    """Reload the autosaved DivAS session of the active object (replayed, no segmenter runs)"""

    bl_idname = "divas.resume_session"
    bl_label = "Resume DivAS Session"
    bl_options = {"REGISTER"}

    filepath: StringProperty(
        name="Session File",
        subtype="FILE_PATH",
        description="Saved session .json (default: the autosave)",
    )
    segmenter: EnumProperty(name="Segmenter", items=SEGMENTER_ITEMS, default="PREFERENCES")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="PREFERENCES")
    cameras: StringProperty(name="Training Cameras", subtype="FILE_PATH")
    gt_labels: StringProperty(name="Ground Truth", subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        if source.source_of(context.active_object) is None:
            cls.poll_message_set("Select the DivAS-imported point cloud the session was made on")
            return False
        return True

    def execute(self, context):
        obj = context.active_object
        path = bpy.path.abspath(self.filepath) if self.filepath else str(autosave_path(obj))
        try:
            settings = start_settings(
                context,
                obj,
                segmenter=self.segmenter,
                device=self.device,
                cameras=self.cameras,
                gt_labels=self.gt_labels,
                autosave=path,
            )
            live = resume(context, obj, path, settings)
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        c = live.counts()
        ok = "" if live.session.replay_matches else " (replay differs from the saved labels!)"
        self.report(
            {"INFO" if ok == "" else "WARNING"},
            f"Resumed {c['accepted']} accepted views, {c['selected']:,} selected{ok}",
        )
        return {"FINISHED"}


CLASSES = (
    DIVAS_OT_session_click,
    DIVAS_OT_session_add_anchor,
    DIVAS_OT_session_accept,
    DIVAS_OT_session_sync,
    DIVAS_OT_session_undo,
    DIVAS_OT_session_reset,
    DIVAS_OT_session_finish_object,
    DIVAS_OT_resume_session,
)

"""The N-panel tab "DivAS": import, session settings, the live session (counts, the last
update's timings, undo / redo, its buttons), a saved session to resume, the manual
selection and edit tools, the active object's selection, extract/export."""

from __future__ import annotations

import bpy

from divas_engine.kinds import SceneKind

from .. import session_registry, source
from ..blend_space import BLEND_FLAG
from ..camera_objects import RESOLUTION_PROP
from ..preferences import SAM_SEGMENTERS, active_model, active_model_ready, get_preferences
from ..properties import scene_settings
from ..reporting import advice_message, view_rejection_message
from ..selection import selected_count
from ..session_actions import saved_session_path

#: (timing key, label) shown for the last update, in pipeline order.
TIMING_LABELS = (
    ("centroid_s", "Centroid"),
    ("render_s", "Render"),
    ("preview_s", "Preview"),
    ("segmenter_s", "Segmenter"),
    ("segmenter_wait_s", "Segmenter wait"),
    ("kernel_s", "Fusion"),
    ("mapping_s", "Mapping"),
    ("overlay_s", "Overlay"),
    ("update_s", "Total"),
)


def backbone_of(ref: source.SourceRef) -> str:
    return "NeRF (density grid)" if ref.kind == "grid" else "2DGS / 3DGS (splats)"


def _draw_import(layout) -> None:
    col = layout.column(align=True)
    col.label(text="Import")
    col.operator("divas.import_splats", text="Gaussian Splats", icon="POINTCLOUD_DATA")
    col.operator("divas.import_density_grid", text="NeRF", icon="VOLUME_DATA")
    col.operator("divas.import_cameras", text="Training Cameras", icon="CAMERA_DATA")


def _draw_settings(layout, context, ref) -> None:
    box = layout.box()
    box.label(text="Settings")
    box.use_property_split = True
    prefs = get_preferences(context)
    if prefs is None:
        box.label(text="Preferences unavailable (add-on not enabled)", icon="INFO")
    else:
        box.prop(prefs, "device")
        box.prop(prefs, "segmenter")
        if prefs.segmenter in SAM_SEGMENTERS:
            # one rule for what a Start would use: a checkpoint alone is enough for SAM
            # (ONNX), it is converted once
            ready = active_model_ready(prefs)
            box.label(text=f"Model: {active_model(prefs)}", icon="INFO" if ready else "ERROR")
    props = scene_settings(context.scene)
    if props is None:
        return
    if ref is not None:
        box.label(text=f"Backbone: {backbone_of(ref)}")
    box.prop(props, "preset")
    box.prop(props, "render_scale")
    if ref is not None and ref.format in ("ingp", "msgpack"):
        box.prop(props, "nerf_views")
    col = box.column(align=True)
    col.active = ref is None or ref.kind != "grid"  # NeRF: the preset's constants
    col.prop(props, "see_through_gap")
    col.prop(props, "surfel_coverage")
    col.prop(props, "gamma")
    if ref is not None and ref.kind == "grid":
        box.label(text="NeRF uses the preset's fusion constants", icon="INFO")
    box.prop(props, "mask_channel")
    box.prop(props, "seed")
    box.prop(props, "autosave")


def _wrap(text: str, width: int = 48) -> list[str]:
    """``text`` in lines of at most ``width`` characters (panel labels do not wrap)."""
    import textwrap

    return textwrap.wrap(text, width) or [""]


def _draw_history(layout, live) -> None:
    h = live.session.history
    row = layout.row(align=True)
    undo = row.row(align=True)
    undo.enabled = h.can_undo
    undo.operator("ed.undo", text=f"Undo {h.undo_name}" if h.can_undo else "Undo", icon="LOOP_BACK")
    redo = row.row(align=True)
    redo.enabled = h.can_redo
    redo.operator(
        "ed.redo", text=f"Redo {h.redo_name}" if h.can_redo else "Redo", icon="LOOP_FORWARDS"
    )


def _draw_session(layout, live) -> None:
    box = layout.box()
    box.label(text="Session", icon="RESTRICT_SELECT_OFF")
    c = live.counts()
    col = box.column(align=True)
    col.label(
        text=f"{c['anchors']} anchors · {c['centroid_views']} views "
        f"({c['accepted']} added, {c['rejected']} not added, {c['pending']} waiting)"
    )
    col.label(
        text=f"{c['selected']:,} selected · {c['labelled']:,} labelled · "
        f"object {len(live.session.objects)}"
    )
    if c["active_voxels"] is None:  # the engine still builds it in the background
        col.label(text="building the voxel grid …")
    else:
        col.label(
            text=f"{c['active_voxels']:,} active voxels · {c['segmented_voxels']:,} segmented"
        )
    rejected = [v for v in live.session.views if v.status == "rejected"]
    if rejected:
        sub = box.column(align=True)
        sub.alert = True
        sub.label(text=f"{len(rejected)} view(s) not added. Last one:", icon="ERROR")
        last_rejected = rejected[-1]
        r = last_rejected
        msg = view_rejection_message(live.session, r)
        for line in _wrap(msg):
            sub.label(text=line)
    hinted = [v for v in live.session.views if v.status in ("open", "fused") and v.advice]
    if hinted:  # the segmenter was unsure about a preview or a fused view: what to click
        sub = box.column(align=True)
        sub.label(text=f"Unsure about view {hinted[-1].id}:", icon="QUESTION")
        for line in _wrap(advice_message(hinted[-1].advice)):
            sub.label(text=line)
    last = live.last_update
    if last:
        sub = box.column(align=True)
        sub.label(text=f"Last: {last.get('what', '')}")
        if "views_changed" in last:  # a click as a correction (views segmented again)
            sub.label(text=f"    Views changed: {last['views_changed']}")
        for key, label in TIMING_LABELS:
            if key in last:
                sub.label(text=f"    {label}: {1000.0 * float(last[key]):.0f} ms")
    col = box.column(align=True)
    col.operator("divas.segment_modal", icon="RESTRICT_SELECT_OFF")
    col.label(text="Click the object through an anchor camera or in any 3D view", icon="INFO")
    _draw_history(col, live)
    row = col.row(align=True)
    row.operator("divas.session_accept", text="Accept", icon="CHECKMARK")
    row.operator("divas.session_undo", text="Take Back View", icon="LOOP_BACK")
    col.operator("divas.session_add_anchor", icon="OUTLINER_OB_CAMERA")
    row = col.row(align=True)
    row.operator("divas.session_reset", text="Reset", icon="X")
    row.operator("divas.session_finish_object", text="Finish Object", icon="FORWARD")
    layout.operator("divas.export_objects", icon="EXPORT")
    if live.kind == SceneKind.NERF and c["pending"]:
        col.operator("divas.session_sync", icon="FILE_REFRESH")


def _draw_tools(layout) -> None:
    box = layout.box()
    box.label(text="Select Splats", icon="RESTRICT_SELECT_OFF")
    row = box.row(align=True)
    for shape, icon in (("BOX", "SELECT_SET"), ("LASSO", "MOD_CURVE"), ("CIRCLE", "MESH_CIRCLE")):
        row.operator("divas.select_gesture", text=shape.title(), icon=icon).shape = shape
    row = box.row(align=True)
    row.operator("divas.select_sphere", text="Sphere at Cursor", icon="SPHERE")
    for action, text in (("SELECT", "All"), ("DESELECT", "None"), ("INVERT", "Invert")):
        row.operator("divas.select_all", text=text).action = action
    row = box.row(align=True)
    row.operator("divas.select_grow", text="Grow", icon="ADD").shrink = False
    row.operator("divas.select_grow", text="Shrink", icon="REMOVE").shrink = True
    row = box.row(align=True)
    row.operator("divas.select_by_attribute", text="By Opacity").attribute = "OPACITY"
    row.operator("divas.select_by_attribute", text="By Size").attribute = "SIZE"
    col = box.column(align=True)
    col.label(text="Edit Splats")
    row = col.row(align=True)
    row.operator("divas.delete_selected", text="Delete", icon="TRASH")
    row.operator("divas.hide_selected", text="Hide", icon="HIDE_ON")
    row.operator("divas.reveal_hidden", text="Reveal", icon="HIDE_OFF")
    col.operator("divas.separate_selected", text="Separate into New Object", icon="DUPLICATE")


class DIVAS_PT_main(bpy.types.Panel):
    bl_idname = "DIVAS_PT_main"
    bl_label = "DivAS"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "DivAS"

    def draw(self, context):
        layout = self.layout
        _draw_import(layout)
        obj = context.active_object
        ref = source.source_of(obj)
        owner, live = session_registry.find(context)
        _draw_settings(layout, context, ref if ref is not None else source.source_of(owner))

        if obj is not None and obj.type == "CAMERA":
            row = layout.row()
            row.operator("divas.activate_camera", icon="VIEW_CAMERA")
            if RESOLUTION_PROP in obj:
                w, h = obj[RESOLUTION_PROP]
                row.label(text=f"{w} x {h}")

        if ref is not None:
            row = layout.row(align=True)
            row.scale_y = 1.3
            row.operator(
                "divas.start_session",
                text="Restart DivAS" if live is not None and owner == obj else "Start DivAS",
                icon="PLAY",
            )
            row.operator("divas.resume_session", text="", icon="RECOVER_LAST")
            if live is None and saved_session_path(obj, search=False) is not None:
                box = layout.box()
                box.label(text="This object has a saved DivAS session", icon="FILE_TICK")
                box.operator("divas.resume_session", text="Resume Session", icon="RECOVER_LAST")
        if live is not None:
            _draw_session(layout, live)

        if ref is None:
            return
        box = layout.box()
        box.label(text=obj.name, icon="OUTLINER_OB_POINTCLOUD")
        box.label(text=f"{ref.path.name} ({ref.format})")
        n = len(obj.data.points)
        count = selected_count(obj)
        box.label(text=f"{n:,} points" + ("" if count is None else f", {count:,} selected"))
        box.prop(context.scene, BLEND_FLAG)
        col = box.column(align=True)
        col.operator("divas.extract_selection", icon="DUPLICATE")
        if ref.kind == "grid":
            col.operator("divas.segmented_volume", icon="VOLUME_DATA")
        col.operator("divas.export_selection", icon="EXPORT")
        _draw_tools(layout)

"""Start DivAS: a live session on the active imported object, its anchors as cameras
(one undo step: undoing it closes the session)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import bpy
from bpy.props import EnumProperty, StringProperty

from .. import source
from ..preferences import SEGMENTERS, get_settings
from ..properties import scene_settings, session_config
from ..reporting import report_exception
from ..session_actions import StartSettings, autosave_path, start

_FROM_PREFS = ("PREFERENCES", "From Preferences", "Use the add-on preferences")
SEGMENTER_ITEMS = (
    _FROM_PREFS,
    *SEGMENTERS,
    (
        "oracle",
        "Oracle (evaluation)",
        "Ground-truth oracle with SAM-like errors; needs Ground Truth",
    ),
)
DEVICE_ITEMS = (
    _FROM_PREFS,
    ("auto", "Auto", "CUDA when present, else CPU"),
    ("cpu", "CPU", ""),
    ("cuda", "CUDA", ""),
)


def _path(p: str) -> Path | None:
    return Path(bpy.path.abspath(p)) if p else None


def start_settings(
    context,
    obj,
    *,
    segmenter: str = "PREFERENCES",
    device: str = "PREFERENCES",
    cameras: str = "",
    prompts: str = "",
    gt_labels: str = "",
    autosave: str = "",
) -> StartSettings:
    """Preferences + the scene's settings + operator overrides → :class:`StartSettings`.
    Anchors render at the preferences' anchor resolution, except those of a prompts file
    (they keep the file's cameras × render scale, as ``divas segment`` renders them)."""
    prefs = get_settings(context)
    props = scene_settings(context.scene)
    save = None
    if autosave:
        save = str(_path(autosave))
    elif props is None or props.autosave:
        save = str(autosave_path(obj))
    config = session_config(props, autosave=save)
    config = replace(config, anchor_long_side=0 if prompts else int(prefs.anchor_resolution))
    return StartSettings(
        config=config,
        device=prefs.device if device == "PREFERENCES" else device,
        segmenter=prefs.segmenter if segmenter == "PREFERENCES" else segmenter,
        sam_encoder=_path(prefs.sam_encoder_path),
        sam_decoder=_path(prefs.sam_decoder_path),
        sam_checkpoint=_path(prefs.sam_checkpoint_path),
        sam_model_type=prefs.sam_model_type,
        cameras_path=_path(cameras),
        prompts_path=_path(prompts),
        gt_labels=_path(gt_labels),
    )


class DIVAS_OT_start_session(bpy.types.Operator):
    """Build a DivAS session on the active imported object: occupancy grid, anchor views as
    cameras (collection 'DivAS Views'), each showing its render once first looked through"""

    bl_idname = "divas.start_session"
    bl_label = "Start DivAS"
    bl_options = {"REGISTER", "UNDO"}

    segmenter: EnumProperty(name="Segmenter", items=SEGMENTER_ITEMS, default="PREFERENCES")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="PREFERENCES")
    cameras: StringProperty(
        name="Training Cameras",
        subtype="FILE_PATH",
        description="cameras.json / COLMAP / transforms.json (default: "
        "cameras.json beside the scene, else the imported "
        "'DivAS Cameras')",
    )
    prompts: StringProperty(
        name="Anchors From Prompts File",
        subtype="FILE_PATH",
        description="Use the anchors of this prompts file (version 1) instead of the planned ones",
    )
    gt_labels: StringProperty(
        name="Ground Truth",
        subtype="FILE_PATH",
        description="Ground-truth labels .npy (the oracle's target)",
    )
    autosave: StringProperty(
        name="Autosave To",
        subtype="FILE_PATH",
        description="Session file written after every accept (default: a recovery file "
        "in the add-on's user folder when Autosave is on; the session is also saved "
        "beside the .blend whenever the .blend is saved)",
    )

    @classmethod
    def poll(cls, context):
        if source.source_of(context.active_object) is None:
            cls.poll_message_set(
                "Select splats imported with DivAS first (File › Import › Gaussian Splats, "
                "or NeRF Density Grid)"
            )
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        obj = context.active_object
        try:
            settings = start_settings(
                context,
                obj,
                segmenter=self.segmenter,
                device=self.device,
                cameras=self.cameras,
                prompts=self.prompts,
                gt_labels=self.gt_labels,
                autosave=self.autosave,
            )
            live = start(context, obj, settings)
        except Exception as e:  # noqa: BLE001 - reported, never a traceback in the UI
            return report_exception(self, e)
        s = live.session
        self.report(
            {"INFO"},
            f"DivAS is ready on {obj.name} ({len(s.scene):,} splats/voxels, "
            f"{live.open_s:.1f} s): click the object in one of the {len(s.anchors)} anchor "
            "views, or anywhere in a 3D view, with Click to Segment",
        )
        return {"FINISHED"}

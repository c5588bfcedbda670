"""Add-on preferences: compute device, 2D segmenter and the SAM model files.

Stored by Blender under the add-on's package name (``__package__``: ``bl_ext.<repo>.divas``
when installed as an extension). :func:`get_settings` turns them into a frozen
:class:`DivasSettings` the rest of the add-on reads, with the defaults when the
preferences are not registered (e.g. the add-on registered by hand in a test).
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
from bpy.props import EnumProperty, StringProperty
from bpy.types import AddonPreferences

__all__ = [
    "ADDON_ID",
    "DIVAS_AddonPreferences",
    "DivasSettings",
    "get_preferences",
    "get_settings",
    "DEVICES",
    "SEGMENTERS",
    "SAM_MODEL_TYPES",
]

ADDON_ID = __package__

DEVICES = (
    ("cpu", "CPU", "Run the kernels on the CPU (always available)"),
    ("cuda", "CUDA", "Run the kernels on the first CUDA GPU (needs an NVIDIA driver)"),
)
SEGMENTERS = (
    ("graph3d", "3D graph", "Weight-free 3D cut over the scene's own splats (no model files)"),
    ("classic", "Classic", "Weight-free GrabCut on colour + depth (no model files)"),
    ("sam_onnx", "SAM (ONNX)", "SAM / MobileSAM encoder + decoder .onnx files via onnxruntime"),
    (
        "sam_torch",
        "SAM (PyTorch)",
        "A segment-anything checkpoint (needs torch in Blender's Python)",
    ),
)
SAM_MODEL_TYPES = (
    ("vit_h", "ViT-H", "sam_vit_h_4b8939.pth"),
    ("vit_l", "ViT-L", "sam_vit_l_0b3195.pth"),
    ("vit_b", "ViT-B", "sam_vit_b_01ec64.pth"),
)


@dataclass(frozen=True)
class DivasSettings:
    device: str = "cpu"
    segmenter: str = "graph3d"
    sam_encoder_path: str = ""
    sam_decoder_path: str = ""
    sam_checkpoint_path: str = ""
    sam_model_type: str = "vit_h"


class DIVAS_AddonPreferences(AddonPreferences):
    bl_idname = ADDON_ID

    device: EnumProperty(name="Device", items=DEVICES, default="cpu")
    segmenter: EnumProperty(name="Segmenter", items=SEGMENTERS, default="graph3d")
    sam_encoder_path: StringProperty(name="SAM Encoder (.onnx)", subtype="FILE_PATH")
    sam_decoder_path: StringProperty(name="SAM Decoder (.onnx)", subtype="FILE_PATH")
    sam_checkpoint_path: StringProperty(name="SAM Checkpoint (.pth)", subtype="FILE_PATH")
    sam_model_type: EnumProperty(name="Model Type", items=SAM_MODEL_TYPES, default="vit_h")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "device")
        layout.prop(self, "segmenter")
        box = layout.box()
        box.label(text="SAM via ONNX Runtime")
        box.prop(self, "sam_encoder_path")
        box.prop(self, "sam_decoder_path")
        box = layout.box()
        box.label(text="SAM via PyTorch")
        box.prop(self, "sam_checkpoint_path")
        box.prop(self, "sam_model_type")


def get_preferences(context=None) -> DIVAS_AddonPreferences | None:
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return None if addon is None else addon.preferences


def get_settings(context=None) -> DivasSettings:
    prefs = get_preferences(context)
    if prefs is None:
        return DivasSettings()
    return DivasSettings(
        prefs.device,
        prefs.segmenter,
        bpy.path.abspath(prefs.sam_encoder_path),
        bpy.path.abspath(prefs.sam_decoder_path),
        bpy.path.abspath(prefs.sam_checkpoint_path),
        prefs.sam_model_type,
    )

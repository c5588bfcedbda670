"""Add-on preferences: compute device, 2D segmenter, the SAM model files, how sharp the
anchor images are, whether saved sessions resume when a .blend opens, and what is drawn
over the viewport.

SAM (ONNX) takes an encoder/decoder pair, or an official checkpoint (``.pth``) that the
engine converts once into a pair (:func:`divas_engine.segment.sam_export.cached_conversion`,
needs torch in Blender's Python) cached in the extension's user folder; a set pair wins.

Stored by Blender under the add-on's package name (``__package__``: ``bl_ext.<repo>.divas``
when installed as an extension). :func:`get_settings` turns them into a frozen
:class:`DivasSettings` the rest of the add-on reads, with the defaults when the
preferences are not registered (e.g. the add-on registered by hand in a test).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy.types import AddonPreferences

from divas_engine.segment.factory import DEFAULT_SEGMENTER, SegmenterKind

__all__ = [
    "ADDON_ID",
    "DIVAS_AddonPreferences",
    "DivasSettings",
    "get_preferences",
    "get_settings",
    "DEVICES",
    "SEGMENTERS",
    "SAM_SEGMENTERS",
    "SAM_MODEL_TYPES",
    "ANCHOR_RESOLUTION",
]

ADDON_ID = __package__

DEVICES = (
    ("cpu", "CPU", "Run the kernels on the CPU (always available)"),
    ("cuda", "CUDA", "Run the kernels on the first CUDA GPU (needs an NVIDIA driver)"),
)
#: The segmenters offered, named as the engine and the CLI name them
#: (:class:`~divas_engine.segment.SegmenterKind`). Blender keeps an enum in a .blend or in
#: the saved preferences as its item's position, so the order stays as it is: preferences
#: saved when SAM was spelled ``sam_onnx`` read back as ``sam-onnx``.
SEGMENTERS = (
    (
        SegmenterKind.GRAPH3D.value,
        "3D graph",
        "Weight-free 3D cut over the scene's own splats (no model files)",
    ),
    (
        SegmenterKind.CLASSIC.value,
        "Classic",
        "Weight-free GrabCut on colour + depth (no model files)",
    ),
    (
        SegmenterKind.SAM_ONNX.value,
        "SAM (ONNX)",
        "SAM / MobileSAM encoder + decoder .onnx files via onnxruntime",
    ),
    (
        SegmenterKind.SAM_TORCH.value,
        "SAM (PyTorch)",
        "A segment-anything checkpoint (needs torch in Blender's Python)",
    ),
)
#: the segmenters that need model files
SAM_SEGMENTERS = (SegmenterKind.SAM_ONNX.value, SegmenterKind.SAM_TORCH.value)
SAM_MODEL_TYPES = (
    ("vit_h", "ViT-H", "sam_vit_h_4b8939.pth"),
    ("vit_l", "ViT-L", "sam_vit_l_0b3195.pth"),
    ("vit_b", "ViT-B", "sam_vit_b_01ec64.pth"),
    ("mobile_sam", "MobileSAM", "mobile_sam.pt"),
)


#: default long side of an anchor image, pixels (the issue asks for ≥ 640).
ANCHOR_RESOLUTION = 640


@dataclass(frozen=True)
class DivasSettings:
    device: str = "cpu"
    segmenter: str = DEFAULT_SEGMENTER.value
    sam_encoder_path: str = ""
    sam_decoder_path: str = ""
    sam_checkpoint_path: str = ""
    sam_model_type: str = "vit_h"
    anchor_resolution: int = ANCHOR_RESOLUTION


class DIVAS_AddonPreferences(AddonPreferences):
    bl_idname = ADDON_ID

    device: EnumProperty(name="Device", items=DEVICES, default="cpu")
    segmenter: EnumProperty(name="Segmenter", items=SEGMENTERS, default=DEFAULT_SEGMENTER.value)
    sam_encoder_path: StringProperty(name="SAM Encoder (.onnx)", subtype="FILE_PATH")
    sam_decoder_path: StringProperty(name="SAM Decoder (.onnx)", subtype="FILE_PATH")
    sam_checkpoint_path: StringProperty(name="SAM Checkpoint (.pth)", subtype="FILE_PATH")
    sam_model_type: EnumProperty(name="Model Type", items=SAM_MODEL_TYPES, default="vit_h")
    anchor_resolution: IntProperty(
        name="Anchor Resolution",
        default=ANCHOR_RESOLUTION,
        min=0,
        soft_min=320,
        soft_max=1600,
        subtype="PIXEL",
        description="Long side of the anchor images you click on (their close-up views "
        "get the same size: larger is sharper but slower). 0: the camera's size × "
        "Render Scale",
    )
    resume_on_open: BoolProperty(
        name="Resume Sessions on Open",
        default=True,
        description="When a .blend with DivAS sessions opens, resume them by themselves "
        "(else: one click on Resume in the DivAS panel)",
    )
    show_render: BoolProperty(
        name="Show Engine Render",
        default=False,
        description="Looking through a DivAS camera, draw the image the segmenter sees "
        "over the scene (else the scene's own splats show under the mask)",
    )
    show_selection: BoolProperty(
        name="Show Selection Tint",
        default=True,
        description="Draw the selected splats in orange over every 3D view",
    )
    tint_point_size: FloatProperty(
        name="Tint Point Size",
        default=3.0,
        min=1.0,
        max=12.0,
        subtype="PIXEL",
        description="Size of the dots that mark selected splats",
    )

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "device")
        layout.prop(self, "segmenter")
        layout.prop(self, "anchor_resolution")
        layout.prop(self, "resume_on_open")
        box = layout.box()
        box.label(text="Viewport Feedback")
        box.prop(self, "show_render")
        box.prop(self, "show_selection")
        box.prop(self, "tint_point_size")
        box = layout.box()
        box.label(text="SAM via ONNX Runtime")
        box.prop(self, "sam_encoder_path")
        box.prop(self, "sam_decoder_path")
        box = layout.box()
        box.label(text="SAM Checkpoint (PyTorch, or converted once for ONNX)")
        box.prop(self, "sam_checkpoint_path")
        box.prop(self, "sam_model_type")
        layout.label(text=f"Active model: {active_model(self)}", icon="INFO")


def sam_cache_dir() -> Path:
    """Where converted checkpoints live: the extension's user folder (Blender's datafiles
    when the add-on is not installed as an extension)."""
    try:
        return Path(bpy.utils.extension_path_user(ADDON_ID, path="sam_onnx", create=True))
    except ValueError:  # not an extension (registered by hand, tests)
        return Path(bpy.utils.user_resource("DATAFILES", path="divas/sam_onnx", create=True))


def active_model(prefs) -> str:
    """One line naming the model a session started now would use."""
    from divas_engine.segment.sam_export import find_cached_conversion, torch_available

    enc, dec = prefs.sam_encoder_path, prefs.sam_decoder_path
    ckpt = bpy.path.abspath(prefs.sam_checkpoint_path) if prefs.sam_checkpoint_path else ""
    if prefs.segmenter not in SAM_SEGMENTERS:
        names = {key: name for key, name, _ in SEGMENTERS}
        return f"{names.get(prefs.segmenter, prefs.segmenter)} (no model files)"
    if prefs.segmenter == SegmenterKind.SAM_TORCH:
        return f"{Path(ckpt).name} ({prefs.sam_model_type}) via PyTorch" if ckpt else "none"
    if enc and dec:
        return f"ONNX pair {Path(enc).name} + {Path(dec).name}"
    if not ckpt:
        return "none: set an ONNX pair or a checkpoint"
    done = find_cached_conversion(ckpt, prefs.sam_model_type, sam_cache_dir())
    if done is not None:
        return f"{Path(ckpt).name} ({prefs.sam_model_type}), converted to ONNX"
    if not torch_available():
        return f"{Path(ckpt).name}: converting needs torch in Blender's Python; set an ONNX pair"
    return f"{Path(ckpt).name} ({prefs.sam_model_type}), converted to ONNX at the next Start"


def active_model_ready(prefs) -> bool:
    """Whether a session started now has the model files its segmenter needs (what the
    panel warns about): SAM (PyTorch) needs a checkpoint; SAM (ONNX) an ONNX pair, or a
    checkpoint already converted or convertible here (torch installed)."""
    from divas_engine.segment.sam_export import find_cached_conversion, torch_available

    if prefs.segmenter == SegmenterKind.SAM_TORCH:
        return bool(prefs.sam_checkpoint_path)
    if prefs.segmenter != SegmenterKind.SAM_ONNX or (
        prefs.sam_encoder_path and prefs.sam_decoder_path
    ):
        return True
    if not prefs.sam_checkpoint_path:
        return False
    ckpt = bpy.path.abspath(prefs.sam_checkpoint_path)
    return torch_available() or (
        find_cached_conversion(ckpt, prefs.sam_model_type, sam_cache_dir()) is not None
    )


def get_preferences(context=None) -> DIVAS_AddonPreferences | None:
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return None if addon is None else addon.preferences


def get_settings(context=None) -> DivasSettings:
    prefs = get_preferences(context)
    if prefs is None:
        return DivasSettings()
    settings = DivasSettings(
        prefs.device,
        prefs.segmenter,
        bpy.path.abspath(prefs.sam_encoder_path),
        bpy.path.abspath(prefs.sam_decoder_path),
        bpy.path.abspath(prefs.sam_checkpoint_path),
        prefs.sam_model_type,
        int(prefs.anchor_resolution),
    )
    return with_converted_checkpoint(settings)


def with_converted_checkpoint(settings: DivasSettings) -> DivasSettings:
    """SAM (ONNX) with a checkpoint and no pair: the engine's cached conversion of it (the
    first time this converts, minutes on a CPU; raises a clear error without torch)."""
    s = settings
    if s.segmenter != SegmenterKind.SAM_ONNX or (s.sam_encoder_path and s.sam_decoder_path):
        return s
    if not s.sam_checkpoint_path:
        return s
    from divas_engine.errors import DivasInputError
    from divas_engine.segment.sam_export import cached_conversion

    try:
        pair = cached_conversion(s.sam_checkpoint_path, s.sam_model_type, sam_cache_dir())
    except ImportError as e:
        raise DivasInputError(s.sam_checkpoint_path, f"cannot convert to ONNX: {e}") from None
    return replace(s, sam_encoder_path=str(pair.encoder), sam_decoder_path=str(pair.decoder))

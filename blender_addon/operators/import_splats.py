"""File › Import › Gaussian Splats: 2DGS/3DGS .ply, compressed .ply, .splat, .spz, SOG."""

from __future__ import annotations

import time
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, StringProperty
from bpy_extras.io_utils import ImportHelper, orientation_helper

from .. import first_look
from ..blend_space import BLEND_FLAG
from ..importers import SplatImportSettings, import_splats
from ..reporting import USER_ERRORS, report_failure

_DISPLAY_MODES = (
    ("AUTO", "Auto", "Splats up to 1,000,000 splats, points above"),
    ("SPLATS", "Splats", "Oriented Gaussian quads (Cycles, EEVEE, Solid colours)"),
    ("POINTS", "Points", "One point per splat: fast for huge scenes"),
)
_BLEND_SPACES = (
    (
        "AUTO",
        "Auto",
        "Like the capture when the scene has nothing else to render, else the scene's "
        "setting is kept",
    ),
    (
        "DISPLAY",
        "Like the Capture",
        "Blend in display (sRGB) space as the 3DGS/2DGS trainers do (a compositor "
        "decode node; other objects' mid-tones look darker)",
    ),
    ("LINEAR", "Linear", "Blender's linear blending (no compositor node)"),
)


@orientation_helper(axis_forward="Z", axis_up="-Y")
class DIVAS_OT_import_splats(bpy.types.Operator, ImportHelper):
    """Import a Gaussian-splat scene as a point cloud shown as oriented Gaussian splats"""

    bl_idname = "divas.import_splats"
    bl_label = "Import Gaussian Splats"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply;*.splat;*.spz;*.sog;*.json", options={"HIDDEN"})
    up_from_scene: BoolProperty(
        name="Up From Scene",
        default=True,
        description="Find the up axis from the scene's ground plane; Forward/Up are the "
        "file's convention used when there is none (COLMAP-trained 3DGS: Z forward, -Y up)",
    )
    display: BoolProperty(
        name="Display",
        default=True,
        description="Add the DivAS display (Geometry Nodes splats or points)",
    )
    display_mode: EnumProperty(name="Show As", items=_DISPLAY_MODES, default="AUTO")
    view_dependent: BoolProperty(
        name="View-Dependent Colour",
        default=True,
        description="Keep the spherical-harmonic coefficients (8-bit) so colours change "
        "with the view",
    )
    blend_space: EnumProperty(
        name="Blend",
        items=_BLEND_SPACES,
        default="AUTO",
        description="Where overlapping splats are blended: display space reproduces the "
        "capture's colours; linear is Blender's own (Scene › Blend Like the Capture)",
    )
    material_preview: BoolProperty(
        name="Show in Material Preview",
        default=True,
        description="Switch the 3D views in Solid or Wireframe shading to Material Preview, "
        "which blends the splats as the capture does (Solid draws them as hard shards); "
        "undone with the import",
    )
    setup_scene: BoolProperty(
        name="Set Up Scene",
        default=True,
        description="Standard view transform (captured colours), Cycles transparent "
        "bounces, EEVEE samples, Solid mode colour from the splats",
    )

    def execute(self, context):
        settings = SplatImportSettings(
            Path(self.filepath),
            display=self.display,
            forward=self.axis_forward,
            up=self.axis_up,
            up_from_scene=self.up_from_scene,
            points={"AUTO": None, "SPLATS": False, "POINTS": True}[self.display_mode],
            view_dependent=self.view_dependent,
            setup_scene=self.setup_scene,
            blend_display={"AUTO": None, "DISPLAY": True, "LINEAR": False}[self.blend_space],
        )
        t0 = time.perf_counter()
        try:
            obj = import_splats(context, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        if self.display and self.material_preview:
            first_look.show_in_material_preview(obj, context.window_manager)
        n = len(obj.data.points)
        self.report(
            {"INFO"},
            f"Imported {n:,} splats from {settings.filepath.name} "
            f"in {time.perf_counter() - t0:.1f} s (up: {obj.get('divas_up_reason', '')}; "
            f"blend: {'like the capture' if blending_display(context.scene) else 'linear'})",
        )
        return {"FINISHED"}


def blending_display(scene) -> bool:
    return bool(getattr(scene, BLEND_FLAG, False))


def menu_func(self, context):
    self.layout.operator(
        DIVAS_OT_import_splats.bl_idname, text="Gaussian Splats (.ply, .splat, .spz, .sog)"
    )

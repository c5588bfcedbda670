"""Export Selection: the selected splats (or voxels) in the input file's own format."""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, StringProperty

from .. import source
from ..reporting import USER_ERRORS, report_failure
from ..selection import ExportSettings, ExportTransform, export_selection, has_selection

_TRANSFORMS = (
    (ExportTransform.NONE.value, "None", "Rows as the file holds them (its own frame)"),
    (
        ExportTransform.OBJECT.value,
        "Object",
        "Apply the object's transform since import: moves, turns and scaling baked in, "
        "the file's own axis convention kept (positions, rotations, scales and SH rotated)",
    ),
    (
        ExportTransform.WORLD.value,
        "World",
        "Apply the whole object transform: Blender's world frame (Z up)",
    ),
)


class DIVAS_OT_export_selection(bpy.types.Operator):
    """Write the points marked by 'divas_selected' as a subset of the original file (a NeRF
    grid: the masked grid in its own format, plus the masked density as .vdb)"""

    bl_idname = "divas.export_selection"
    bl_label = "Export Selection"
    bl_options = {"REGISTER"}

    filepath: StringProperty(name="File Path", subtype="FILE_PATH")
    filter_glob: StringProperty(
        default="*.ply;*.splat;*.spz;*.sog;*.npz;*.ingp;*.msgpack;*.pth;*.vdb", options={"HIDDEN"}
    )
    write_labels: BoolProperty(
        name="Write Labels",
        default=False,
        description="Also write <name>_labels.npy: one bool per input-file row",
    )
    apply_transform: EnumProperty(
        name="Apply Transform",
        items=_TRANSFORMS,
        default=ExportTransform.NONE.value,
        description="What of the object's transform to bake into the exported splats",
    )

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if source.source_of(obj) is None:
            cls.poll_message_set("The active object is not a DivAS-imported point cloud")
            return False
        if not has_selection(obj):
            cls.poll_message_set("The object has no selection yet ('divas_selected')")
            return False
        return True

    def invoke(self, context, event):
        ref = source.source_of(context.active_object)
        if not self.filepath:
            stem = ref.path.name.split(".")[0]
            suffix = (
                ".compressed.ply"
                if ref.format == "compressed_ply"
                else source.FORMAT_SUFFIX.get(ref.format, ".ply")
            )
            self.filepath = str(ref.path.with_name(f"{stem}_selection{suffix}"))
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        if not self.filepath:
            self.report({"ERROR"}, "No output file given")
            return {"CANCELLED"}
        settings = ExportSettings(
            Path(bpy.path.abspath(self.filepath)),
            self.write_labels,
            ExportTransform(self.apply_transform),
        )
        try:
            result = export_selection(context.active_object, settings)
        except USER_ERRORS as e:
            return report_failure(self, e, settings.filepath)
        self.report(
            {"INFO"},
            f"Exported {result.count:,} primitives to {result.path.name} ({result.format})",
        )
        return {"FINISHED"}


def menu_func(self, context):
    self.layout.operator(DIVAS_OT_export_selection.bl_idname, text="DivAS Selection (input format)")

"""Export Objects: every finished DivAS object as its own file, plus the label set.

Thin wrapper over :meth:`divas_engine.session.Session.export_objects`: one file per object in
the input's own format, and ``labelled.ply`` (the original rows with an extra ``divas_label``
column) or ``labels.npy`` for density grids.
"""

from __future__ import annotations

from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..reporting import report_exception
from .session_base import SessionOperator, live_session


class DIVAS_OT_export_objects(SessionOperator, bpy.types.Operator):
    """Write each finished object to its own file and the labelled scene (divas_label)"""

    bl_idname = "divas.export_objects"
    bl_label = "Export Objects"
    bl_options = {"REGISTER"}

    directory: StringProperty(name="Folder", subtype="DIR_PATH")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        if not self.directory:
            self.report({"ERROR"}, "No output folder given")
            return {"CANCELLED"}
        _obj, live = live_session(context)
        try:
            files = live.session.export_objects(Path(bpy.path.abspath(self.directory)))
        except Exception as e:  # noqa: BLE001 - one readable report line, details to the console
            return report_exception(self, e)
        n = len(files["objects"])
        self.report({"INFO"}, f"Exported {n} object(s) and {Path(files['labelled']).name}")
        return {"FINISHED"}

"""What the manual selection and edit operators share: a poll asking for DivAS splats
(the active imported object, or the object of the running session), the select modes,
and one place that turns a tool into one undo step with a plain-language report.
"""

from __future__ import annotations

from bpy.props import EnumProperty

from .. import draw, point_edits, session_registry, source
from ..reporting import report_exception

__all__ = ["MODE_ITEMS", "PointEditOperator", "mode_property"]

MODE_ITEMS = (
    ("SET", "Set", "Select only these splats"),
    ("ADD", "Extend", "Add them to the selection"),
    ("SUB", "Subtract", "Remove them from the selection"),
    ("AND", "Intersect", "Keep only selected splats among them"),
    ("XOR", "Difference", "Flip their selection"),
)


def mode_property(default: str = "SET"):
    return EnumProperty(name="Mode", items=MODE_ITEMS, default=default, options={"SKIP_SAVE"})


class PointEditOperator:
    """Shared poll and step runner of the manual tools."""

    @classmethod
    def poll(cls, context):
        if source.source_of(context.active_object) is None and (
            session_registry.find(context)[1] is None
        ):
            cls.poll_message_set("Select splats imported with DivAS first")
            return False
        return context.mode == "OBJECT"

    def run(self, context, what: str, fn, *args, done: str = ""):
        """Run ``fn(target, *args)`` as one step; report ``done`` (formatted with the
        result as ``{n}``) or the error."""
        try:
            t = point_edits.edit_target(context)
            n = point_edits.as_step(t, what, fn, t, *args)
        except Exception as e:  # noqa: BLE001 - one readable report line
            return report_exception(self, e)
        draw.touch()  # points deleted, hidden or reselected: redraw the feedback
        if done:
            self.report({"INFO"}, done.format(n=n if not isinstance(n, int) else f"{n:,}"))
        return {"FINISHED"}

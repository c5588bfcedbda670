"""Click Anchor: a positive click spawns a centroid view, a negative one takes the spot
out of the selection at once (one undo step). With ``view`` set, the click is on that
centroid view instead: a correction of the selection (accepted or not). Every click is
a 3D constraint (:mod:`divas_engine.session.corrections`); the report says how many
views it changed.

Coordinates are rendered-image pixels of the anchor (the session's), or full-camera
pixels with ``full_resolution`` (the prompts file's). RNA floats are single precision,
so ``xy`` also takes decimal text, for clicks that must be bit-identical to
``divas segment`` (the headless script passes them so).
"""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from ..reporting import report_exception
from ..session_actions import (
    click,
    correct_view,
    correction_summary,
    full_to_session_xy,
    run_step,
)
from .session_base import SessionOperator, live_session


def _parse_xy(text: str) -> tuple[float, float]:
    parts = text.replace(",", " ").split()
    if len(parts) != 2:
        raise ValueError(f"XY needs two numbers 'x y' (got {text!r}): type e.g. '120.5 80'")
    return float(parts[0]), float(parts[1])


def click_message(anchor: int, positive: bool, correction=None) -> str:
    """What a click did and what to do next (``correction``: what it changed, the
    engine's :class:`~divas_engine.session.CorrectionResult`)."""
    if positive:
        return (
            f"Opened a close-up view of the object from anchor {anchor}: if the blue mask "
            "misses parts, click them; press Enter to add the view (Ctrl+Z takes the click back)"
        )
    done = "" if correction is None else f" ({correction_summary(correction)})"
    return (
        f"Took that spot on anchor {anchor} out of the object{done}: every view that "
        "sees it leaves it out (Ctrl+Z takes the click back)"
    )


def view_click_message(view_id: str, positive: bool, correction) -> str:
    """What a correction on a centroid view did."""
    what = "into" if positive else "out of"
    return (
        f"Put that spot on view {view_id} {what} the object "
        f"({correction_summary(correction)}; Ctrl+Z takes the click back)"
    )


class DIVAS_OT_session_click(SessionOperator, bpy.types.Operator):
    """Click on an anchor (positive spawns a centroid view, negative takes the spot out),
    or on a centroid view (a correction of the selection)"""

    bl_idname = "divas.session_click"
    bl_label = "Click Anchor"
    bl_options = {"REGISTER", "UNDO"}

    anchor: IntProperty(options={"SKIP_SAVE"}, name="Anchor", default=0, min=0)
    view: StringProperty(
        options={"SKIP_SAVE"},
        name="View",
        default="",
        description="A centroid view's id: click on that view instead of the anchor",
    )
    x: FloatProperty(options={"SKIP_SAVE"}, name="X", default=0.0)
    y: FloatProperty(options={"SKIP_SAVE"}, name="Y", default=0.0)
    xy: StringProperty(
        options={"SKIP_SAVE"},
        name="XY (exact)",
        default="",
        description="'x y' as decimal text (double precision); overrides X/Y",
    )
    positive: BoolProperty(options={"SKIP_SAVE"}, name="Positive", default=True)
    full_resolution: BoolProperty(
        options={"SKIP_SAVE"},
        name="Full-Resolution Pixels",
        default=False,
        description="X/Y are pixels of the full camera (the prompts "
        "file's), not of the rendered image",
    )
    preview: BoolProperty(
        options={"SKIP_SAVE"},
        name="Preview",
        default=True,
        description="Segment the default prompt at once (the mask preview)",
    )

    def execute(self, context):
        obj, live = live_session(context)
        sign = "Click" if self.positive else "Negative click"
        if self.view:
            return self._on_view(context, obj, live, f"{sign} on view {self.view}")
        what = f"{sign} on anchor {self.anchor}"
        try:
            xy = _parse_xy(self.xy) if self.xy else (self.x, self.y)
            if self.full_resolution:
                xy = full_to_session_xy(live, self.anchor, xy)
            last = live.session.last_correction
            run_step(
                obj,
                live,
                what,
                click,
                context,
                obj,
                live,
                self.anchor,
                xy,
                self.positive,
                preview=self.preview,
            )
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        corr = live.session.last_correction
        corr = corr if corr is not last else None
        self.report({"INFO"}, click_message(self.anchor, self.positive, corr))
        return {"FINISHED"}

    def _on_view(self, context, obj, live, what: str):
        try:
            xy = _parse_xy(self.xy) if self.xy else (self.x, self.y)
            res = run_step(obj, live, what, correct_view, context, obj, live, self.view, xy,
                           self.positive)  # fmt: skip
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report({"INFO"}, view_click_message(self.view, self.positive, res))
        return {"FINISHED"}

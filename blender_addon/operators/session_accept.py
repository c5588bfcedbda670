"""Accept View: fuse a centroid view's mask into the 3D selection (one undo step).

``points`` replace the points added on the view, as JSON ``[[x, y, positive], ...]`` in
rendered-image pixels, or full-camera pixels with ``full_resolution`` (the prompts
file's); JSON keeps them double precision (RNA floats are single).
"""

from __future__ import annotations

import json

import bpy
from bpy.props import BoolProperty, StringProperty

from divas_engine.kinds import ViewStatus
from divas_engine.session.widening import is_wider

from ..reporting import advice_message, report_exception, view_rejection_message
from ..session_actions import accept, full_to_session_xy, run_step
from .session_base import SessionOperator, live_session


def _parse_points(text: str):
    try:
        doc = json.loads(text)
        pts = [(float(p[0]), float(p[1])) for p in doc]
        labs = [int(bool(p[2])) if len(p) > 2 else 1 for p in doc]
    except (ValueError, TypeError, IndexError, KeyError) as e:
        raise ValueError(
            f"Prompt Points must be JSON like [[x, y, true], [x, y, false]] (got {text!r}: "
            f"{e}): fix the text and run Accept again"
        ) from None
    return pts, labs


def accept_message(live, res) -> tuple[set[str], str]:
    """The report (level, text) of an accept: what happened, what to do next."""
    v = res.view
    if v.status == ViewStatus.REJECTED:
        msg = view_rejection_message(live.session, v)
        return {"WARNING"}, "View not added. " + msg
    if v.status == ViewStatus.PENDING:
        return {"INFO"}, (
            f"View accepted; the segmenter is working on it in the background "
            f"({res.pending} waiting). The selection updates when this anchor's views are "
            "done (or press Sync)"
        )
    n = int(live.session.selection.sum())
    wide = sum(is_wider(x) for x in res.fused)
    if wide:  # the object ran out of the close-up: the session framed it wider
        n_views = "one wider view" if wide == 1 else f"{wide} wider views"
        n = f"{n:,} selected, with {n_views} of the object"
    else:
        n = f"{n:,} selected"
    if v.advice:  # fused, but the segmenter was unsure: what to click next
        return {"WARNING"}, (
            f"View added: {n} ({res.timings.get('update_s', 0.0):.2f} s), "
            f"but the segmenter was unsure. {advice_message(v.advice)}"
        )
    return {"INFO"}, (
        f"View added: {n} ({res.timings.get('update_s', 0.0):.2f} s). Click "
        "another anchor to add more, or Finish Object when it is complete"
    )


class DIVAS_OT_session_accept(SessionOperator, bpy.types.Operator):
    """Accept a centroid view: fuse its mask into the 3D selection and recolour the splats"""

    bl_idname = "divas.session_accept"
    bl_label = "Accept View"
    bl_options = {"REGISTER", "UNDO"}

    view: StringProperty(
        options={"SKIP_SAVE"},
        name="View",
        default="",
        description="View id (default: the scene camera's view, else the next open one)",
    )
    points: StringProperty(
        options={"SKIP_SAVE"},
        name="Prompt Points",
        default="",
        description="JSON [[x, y, positive], ...] replacing the points "
        "added on the view (its default prompt stays)",
    )
    full_resolution: BoolProperty(
        options={"SKIP_SAVE"}, name="Full-Resolution Pixels", default=False
    )

    def execute(self, context):
        obj, live = live_session(context)
        try:
            pts = labs = None
            if self.points:
                pts, labs = _parse_points(self.points)
                if self.full_resolution and pts:
                    a = live.session.view(self.view).anchor if self.view else None
                    if a is None:
                        raise ValueError(
                            "Full-resolution points need the view they belong to: "
                            "fill in View and run Accept again"
                        )
                    pts = [full_to_session_xy(live, a, p) for p in pts]
            res = run_step(
                obj, live, "Accept view", accept, context, obj, live, self.view or None, pts, labs
            )
        except Exception as e:  # noqa: BLE001
            return report_exception(self, e)
        self.report(*accept_message(live, res))
        return {"FINISHED"}

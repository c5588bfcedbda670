"""What a session reports: counts of views and primitives, and the full run report
(timings per stage, per-update timings, views with their rejection reasons, memory)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..kinds import ViewStatus
from .timing import memory_report
from .widening import is_wider

if TYPE_CHECKING:
    from .session import Session

__all__ = ["session_counts", "session_report"]


def session_counts(session: Session, *, wait: bool = True) -> dict[str, Any]:
    """:meth:`Session.counts <divas_engine.session.Session.counts>`."""
    views = [v for o in session.objects for v in o.views]
    voxels = wait or session.warmed_up
    st = [v.status for v in views]
    return {
        "primitives": int(len(session.scene)),
        "anchors": len(session.anchors),
        "centroid_views": len(views),
        "wider_views": sum(is_wider(v.id) for v in views),
        "accepted": st.count(ViewStatus.FUSED),
        "rejected": st.count(ViewStatus.REJECTED),
        "pending": st.count(ViewStatus.PENDING),
        "open": st.count(ViewStatus.OPEN),
        "objects": len(session.object_selections()),
        "selected": int(session.selection.sum()),
        "labelled": int((session.label_set() > 0).sum()),
        "active_voxels": int(len(session.grid)) if voxels else None,
        "segmented_voxels": None
        if not voxels
        else int(session.fusion.result().segmented.sum())
        if session.state.live_views()
        else 0,
    }


def session_report(session: Session) -> dict[str, Any]:
    """:meth:`Session.report <divas_engine.session.Session.report>`."""
    views = []
    for o in session.objects:
        for v in o.views:
            views.append(
                {
                    "id": v.id,
                    "object": o.name,
                    "anchor": v.anchor,
                    "click": v.click,
                    "status": v.status,
                    "reason": v.reason,
                    "advice": v.advice,
                    "score": None if not np.isfinite(v.score) else float(v.score),
                    "strategy": v.centroid.strategy,
                    "d_cam": float(v.centroid.d_cam),
                    "prompts": None if v.points is None else int(len(v.points)),
                }
            )
    grid_report = session.grid.report
    return {
        "kind": session.kind,
        "seed": session.config.seed,
        "device": str(session.device),
        "forward_facing": session.forward_facing,
        "segmenter": getattr(session.segmenter, "name", type(session.segmenter).__name__),
        "config": session.config.to_dict(),
        "grid": grid_report.as_dict() if hasattr(grid_report, "as_dict") else None,
        "timings": session.timings.summary(),
        "updates": session.updates,
        "counts": session.counts(),
        "views": views,
        "objects": [
            {"name": o.name, "label": o.label, "count": int(s.sum())}
            for o, s in session.object_selections()
        ],
        "memory": memory_report(),
    }

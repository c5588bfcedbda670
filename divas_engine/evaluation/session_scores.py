"""The ``evaluation`` block of a ``divas segment`` report (``--gt-labels``), for every
caller that runs a session against ground truth: the CLI and the headless Blender script.

* ``surfels`` / ``voxels``: per-primitive precision / recall / IoU of the selection
  (:func:`~divas_engine.evaluation.metrics.surfel_scores`);
* ``render`` (surfel scenes): image IoU, alpha fidelity, opacity-weighted IoU and the
  extracted object's PSNR at camera-free test views around the ground truth
  (:func:`~divas_engine.evaluation.fidelity.rendered_report`); on 3DGS scenes also of the
  selection without the completion (``without_completion``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..kinds import SceneKind
from .metrics import surfel_scores

__all__ = ["session_evaluation"]


def session_evaluation(session, selection: np.ndarray, gt: np.ndarray, device) -> dict[str, Any]:
    """The report's ``evaluation`` dict of ``selection`` (the session's) against ``gt``."""
    surfels = session.kind == SceneKind.GS2D
    out: dict[str, Any] = {("surfels" if surfels else "voxels"): surfel_scores(selection, gt)}
    if surfels:
        out["render"] = _rendered_scores(session, selection, gt, device)
    return out


def _rendered_scores(session, sel: np.ndarray, gt: np.ndarray, device) -> dict[str, Any]:
    from ..session import anchor_plan
    from .fidelity import rendered_report

    sels = {"selection": sel}
    if getattr(session.backend, "last_completion", None) is not None:
        sels["without_completion"] = session.last_mapping.selected
    up = anchor_plan(session.scene, session.cameras, session.config).up
    return rendered_report(
        session.scene,
        sels,
        gt,
        up,
        scale=session.config.render_scale,
        device=device,
        renderer=session.renderer,
    )

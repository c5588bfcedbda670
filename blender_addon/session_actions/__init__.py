"""The DivAS session steps on Blender data: the work behind the session operators and
the click-to-segment modal (which share every function here).

Each step makes one engine call on the object's live :class:`~divas_engine.session.Session`
(:mod:`..session_registry`) and then updates what Blender shows:

* :mod:`.start` — start a session on an imported object, or resume its saved one;
* :mod:`.loop_steps` — add an anchor, click, add a prompt, correct an accepted view, accept,
  sync, undo, reset, finish the object;
* :mod:`.history` — every step one Blender undo step, the session kept in step with it;
* :mod:`.files` — where a session is saved so it follows the .blend;
* :mod:`.view_cameras` — a camera per anchor and centroid view in "DivAS Views", with the
  view's render (packed) as its background image;
* :mod:`.points` — ``divas_selected`` / ``divas_label`` on the object's points after every
  change of the selection.

Pixel coordinates are in rendered-image pixels (the camera × render scale) unless a function
says otherwise.
"""

from __future__ import annotations

from ..reporting import SESSION_ERRORS, report_exception
from .files import ensure_key, recovery_path, saved_session_path, sidecar_path
from .history import commit, rollback, run_step, sync_after_undo, sync_blender
from .loop_steps import (
    accept,
    add_anchor,
    add_prompt,
    click,
    correct_view,
    correction_summary,
    finish_object,
    full_to_session_xy,
    refresh_preview,
    reset,
    sync,
    undo,
    viewport_camera,
    viewport_click,
)
from .points import LABEL_ATTRIBUTE, write_selection
from .start import StartSettings, autosave_path, resume, start
from .view_cameras import VIEWS_COLLECTION, activate_camera, camera_target, scene_camera_of

__all__ = [
    "StartSettings",
    "VIEWS_COLLECTION",
    "LABEL_ATTRIBUTE",
    "SESSION_ERRORS",
    "autosave_path",
    "start",
    "resume",
    "add_anchor",
    "click",
    "correct_view",
    "correction_summary",
    "add_prompt",
    "refresh_preview",
    "accept",
    "sync",
    "undo",
    "reset",
    "finish_object",
    "write_selection",
    "activate_camera",
    "camera_target",
    "scene_camera_of",
    "report_exception",
    "full_to_session_xy",
    "viewport_camera",
    "viewport_click",
    "commit",
    "rollback",
    "run_step",
    "sync_after_undo",
    "sync_blender",
    "ensure_key",
    "recovery_path",
    "saved_session_path",
    "sidecar_path",
]

"""Session steps as Blender undo steps.

Blender's undo restores the whole file — the points' attributes, the cameras, every property —
but knows nothing of the engine session living in Python. So every session step is one Blender
undo step *and* one step of the session's own history
(:class:`divas_engine.session.history.SessionHistory`), tied by an id:

* after a step, :func:`commit` records the session state and writes the step's id into the
  object (``divas_history_step``); Blender then pushes its undo step (``bl_options`` ``UNDO``;
  the modal calls ``ed.undo_push``), so the id is part of that step's file state;
* after an undo or redo (``undo_post`` / ``redo_post``), :func:`sync_after_undo` reads the
  restored id and moves the session to that step
  (:meth:`~divas_engine.session.history.SessionHistory.goto`: exact, nothing rendered again);
  other steps leave the id alone.

So the one undo an artist knows works for everything. When Blender goes back to before the
session started (the id is gone), the session is closed. A step that fails halfway is rolled
back (:func:`rollback`).
"""

from __future__ import annotations

from .. import memory, session_registry
from ..session_registry import STEP_PROP, LiveSession
from .points import write_selection
from .view_cameras import prune_anchor_cameras, prune_view_cameras, sync_camera_tables

__all__ = ["commit", "rollback", "run_step", "sync_after_undo", "sync_blender"]


def commit(obj, live: LiveSession, what: str) -> str:
    """Record the state after a step; returns the step id (also written on ``obj``)."""
    step = live.session.history.record(what, live.host_state())
    obj[STEP_PROP] = step.id
    live.changed()
    return step.id


def sync_blender(obj, live: LiveSession) -> None:
    """Make what Blender holds match the session: no camera of a view or anchor it no
    longer has, the points' selection and labels."""
    prune_view_cameras(live)
    prune_anchor_cameras(live)
    write_selection(obj, live, full=True)  # after a failed step: write everything
    live.changed()


def rollback(obj, live: LiveSession) -> None:
    """Back to the last recorded step after a step failed halfway."""
    step = live.session.history.restore_current()
    live.restore_host_state(step.host)
    sync_blender(obj, live)


def run_step(obj, live: LiveSession, what: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` as one session step: committed when it returns, rolled
    back (and the error re-raised) when it raises."""
    try:
        out = fn(*args, **kwargs)
    except BaseException:
        rollback(obj, live)
        raise
    commit(obj, live, what)
    memory.release_freed()  # the step's freed transients back to the system
    return out


def sync_after_undo() -> list[str]:
    """Move every live session to the step the (just restored) file holds; returns a
    line per session that changed, for the console."""
    lines = []
    for live in session_registry.all_sessions():
        obj = session_registry.object_of(live)
        step = None if obj is None else obj.get(STEP_PROP)
        if obj is None or step is None or step not in live.session.history:
            # the file is back to before this session (or its object) existed
            session_registry.discard(live)
            lines.append(f"DivAS: session of {live.object_name!r} closed by undo")
            continue
        sync_camera_tables(obj, live)
        if step != live.session.history.current.id:
            s = live.session.history.goto(step)
            live.restore_host_state(s.host)
            lines.append(f"DivAS: {live.object_name!r} back at {s.what!r}")
        # the restored file holds it already; written in full (what was last written
        # is not what Blender restored), cheap and exact
        write_selection(obj, live, full=True)
        live.record({"what": f"undo/redo → {live.session.history.current.what}"})
    return lines

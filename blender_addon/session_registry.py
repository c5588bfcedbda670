"""The live DivAS sessions, one per imported object, kept outside Blender's data.

Blender properties cannot hold Python objects, so each running
:class:`~divas_engine.session.Session` lives in a module-level table. An object is
matched to its session by its *session key* (``divas_session_key``, a random id stored
on the object when the session starts: it survives renames, undo, saving and reopening
the .blend), then by ``session_uid``, then by name. The table is emptied (sessions
closed) when a file is loaded (:func:`on_load_pre`) and when the add-on is
unregistered; the saved session comes back with "Resume DivAS Session"
(:mod:`.session_actions.files`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bpy
from bpy.app.handlers import persistent

from divas_engine.session import Session

from .modal_logic import OWNER_PROP

#: the object's session key (stable id) and the session-history step its Blender state is at.
KEY_PROP, STEP_PROP = "divas_session_key", "divas_history_step"

__all__ = [
    "KEY_PROP",
    "STEP_PROP",
    "LiveSession",
    "object_of",
    "put",
    "get",
    "drop",
    "clear",
    "find",
    "owner_object",
    "all_sessions",
    "discard",
    "on_load_pre",
]


@dataclass(eq=False)
class LiveSession:
    """A running session and what the add-on made for it.

    Attributes:
        session: the engine session.
        object_name: the point-cloud object it segments.
        anchor_cameras: camera object name per anchor index.
        view_cameras: camera object name per centroid view id.
        extra_prompts: prompt points added on each centroid view, ``(x, y, label)`` in
            rendered-image pixels (the view's default prompt is added by the engine).
        autosave: where the engine saves the session after every accept (None: off).
        segmenter: the segmenter's name; open_s: seconds to start (load → anchors).
        last_update: the last update's timings (seconds by stage) and what it was.
        key: the object's session key (:data:`KEY_PROP`).
        coverage: per view id, the selection array an overlay was made for and the
            engine's selection overlay on that view (Sec. 3.7), or the callable that
            renders it on first read (:meth:`coverage_of`; drawn while it is current).
        written: what :func:`~.session_actions.points.write_selection` last wrote to
            the points (to write only what changed), None when unknown.
        version: bumped whenever what is drawn over the viewport changes.
    """

    session: Session
    object_name: str
    anchor_cameras: list[str] = field(default_factory=list)
    view_cameras: dict[str, str] = field(default_factory=dict)
    extra_prompts: dict[str, list[tuple[float, float, int]]] = field(default_factory=dict)
    autosave: Path | None = None
    segmenter: str = "graph3d"
    open_s: float = 0.0
    last_update: dict[str, Any] = field(default_factory=dict)
    key: str = ""
    coverage: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    version: int = 0
    written: Any = None
    _counts: dict[str, Any] | None = None

    def set_coverage(self, view_id: str, overlay: Any) -> None:
        """Keep ``overlay`` (an engine ``Overlay`` or a callable returning one) of the
        current selection on view ``view_id``."""
        self.coverage[view_id] = (self.session.selection, overlay)

    def coverage_of(self, view_id: str):
        """The ``[H,W]`` selection coverage on view ``view_id`` while its selection is
        current (rendered now if it was kept as a callable; then cached), else None."""
        cov = self.coverage.get(view_id)
        if cov is None or cov[0] is not self.session.selection:
            return None
        sel, ov = cov
        if callable(ov):
            ov = ov()
            if ov is None:
                self.coverage.pop(view_id, None)
                return None
            self.coverage[view_id] = (sel, ov)
            from . import memory

            memory.release_freed()  # the render's freed transients
        return ov.coverage

    def host_state(self) -> dict[str, Any]:
        """What the add-on keeps per history step (the engine keeps the rest)."""
        return {"extra_prompts": {k: list(v) for k, v in self.extra_prompts.items()}}

    def restore_host_state(self, state: dict[str, Any] | None) -> None:
        extra = (state or {}).get("extra_prompts", {})
        self.extra_prompts = {k: list(v) for k, v in extra.items()}

    @property
    def kind(self) -> str:
        return self.session.kind

    def record(self, update: dict[str, Any]) -> None:
        """Remember the last update (what, seconds by stage) and refresh the counts."""
        self.last_update = dict(update)
        self.changed()

    def changed(self) -> None:
        """The session changed: recount when the counts are next read, redraw. (The
        panel reads them in the redraw after every step; counting here would count an
        accept, which records and commits, twice, and the engine's count of the
        labelled points copies the ``[N]`` labels each time.)"""
        self._counts = None
        self.version += 1

    def counts(self) -> dict[str, Any]:
        """The session's counts as of the last update, counted on the first read after
        it (never waiting for the engine's background warm-up: its voxel counts come
        when it is done); cheap afterwards: the panel redraws often."""
        c = self._counts
        if c is None or (c.get("active_voxels") is None and self.session.warmed_up):
            self._counts = self.session.counts(wait=False)
        return self._counts


_sessions: dict[int, LiveSession] = {}


def _key(obj) -> int:
    uid = getattr(obj, "session_uid", None)  # every supported Blender has it; be safe
    return int(uid) if uid is not None else int(obj.as_pointer())


def put(obj, live: LiveSession) -> None:
    """Register ``live`` for ``obj`` (closing a previous session of that object)."""
    drop(obj)
    live.key = live.key or str(obj.get(KEY_PROP, ""))
    _sessions[_key(obj)] = live


def get(obj) -> LiveSession | None:
    if obj is None:
        return None
    key = obj.get(KEY_PROP) if hasattr(obj, "get") else None
    live = next((s for s in _sessions.values() if key and s.key == key), None)
    if live is None:
        live = _sessions.get(_key(obj))
    if live is None:
        live = next((s for s in _sessions.values() if s.object_name == obj.name), None)
    if live is not None:
        live.object_name = obj.name
    return live


def object_of(live: LiveSession):
    """The object ``live`` segments (by key, then by name), or None when it is gone."""
    if live.key:
        obj = next((o for o in bpy.data.objects if o.get(KEY_PROP) == live.key), None)
        if obj is not None:
            live.object_name = obj.name
            return obj
    return bpy.data.objects.get(live.object_name)


def discard(live: LiveSession) -> None:
    """Close and forget ``live`` (its object may be gone)."""
    for k, v in list(_sessions.items()):
        if v is live:
            del _sessions[k]
    live.session.close()


def drop(obj) -> None:
    """Close and forget the session of ``obj`` (if any)."""
    live = get(obj)
    if live is None:
        return
    for k, v in list(_sessions.items()):
        if v is live:
            del _sessions[k]
    live.session.close()


def clear() -> None:
    """Close and forget every session."""
    for live in list(_sessions.values()):
        live.session.close()
    _sessions.clear()


def all_sessions() -> list[LiveSession]:
    return list(_sessions.values())


def owner_object(context):
    """The object whose session the context is about: the active object when it has a
    session, else the owner of the scene camera (a DivAS view: its parent, or the object
    named in ``divas_owner``), else the only session's."""
    obj = context.active_object
    if get(obj) is not None:
        return obj
    cam = context.scene.camera if context.scene is not None else None
    if cam is not None and cam.get(OWNER_PROP):
        for owner in (cam.parent, bpy.data.objects.get(cam[OWNER_PROP])):
            if owner is not None and get(owner) is not None:
                return owner
    if len(_sessions) == 1:
        owner = object_of(next(iter(_sessions.values())))
        if owner is not None:
            return owner
    return None


def find(context) -> tuple[Any, LiveSession] | tuple[None, None]:
    """``(object, live session)`` for the context (see :func:`owner_object`)."""
    obj = owner_object(context)
    return (obj, get(obj)) if obj is not None else (None, None)


@persistent
def on_load_pre(*_args) -> None:
    """A file is being loaded: the objects the sessions point at are going away."""
    clear()

"""Undo and redo of any session step (not in the paper, which undoes the last view only).

A :class:`SessionHistory` is a linear list of :class:`HistoryStep` s, one per user-level
step (a click, a prompt point, an accept, a reject, a finished object, a manual edit …),
each holding a :class:`SessionSnapshot` of the session's *logical* state right after
that step: anchors, objects with their clicks, views and view fields (status, prompts,
preview, fused mask and fusion slot), the label set, the semantic and final selections,
the manual edit layers and the pending NeRF views. Renders are not part of it: views
keep their cached buffers, so going back to a step re-renders nothing.

:meth:`SessionHistory.goto` restores any step and *reconciles* the fusion state with it:
views fused now but not in the target are removed (``remove_view``, exact), views fused
in the target but not now are fused again in their own slots (``add_view(view, slot)``);
the fusion is fixed-point, so the accumulators equal the target's bit for bit whatever
the path (:mod:`divas_engine.fusion.state`). Pending NeRF views are forgotten or
re-submitted the same way. The restored selection is the snapshot's, so the mapping does
not run again.

A host keeps its own state per step in ``host`` (e.g. the Blender add-on's added prompt
points) and gets it back from :meth:`goto`. Recording a step after an undo drops the
redo branch (as every editor does). Snapshots share arrays with the session: the
session replaces its selection, label and edit arrays rather than writing into them.
"""

from __future__ import annotations

import itertools
import uuid
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..kinds import ViewStatus
from .edits import EditLayer
from .records import AnchorClick, AnchorView, ObjectRecord, SessionView

if TYPE_CHECKING:
    from .session import Session

__all__ = ["SessionHistory", "HistoryStep", "SessionSnapshot", "HISTORY_LIMIT"]

#: steps kept (Blender keeps 32 undo steps by default); the oldest are dropped.
HISTORY_LIMIT = 64

_VIEW_FIELDS = (
    "status",
    "reason",
    "advice",
    "score",
    "points",
    "labels",
    "preview",
    "mask",
    "fusion_id",
    "fusion_view",
)


@dataclass(frozen=True, eq=False)
class _ObjectState:
    index: int
    label: int
    name: str
    finished: bool
    selection: np.ndarray | None
    views: tuple[SessionView, ...]
    clicks: dict[int, tuple[AnchorClick, ...]]
    accept_order: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class SessionSnapshot:
    """The logical state of a session after one step (module docstring)."""

    anchors: tuple[AnchorView, ...]
    objects: tuple[_ObjectState, ...]
    view_table: dict[str, SessionView]
    view_fields: tuple[tuple[SessionView, tuple], ...]
    labels: np.ndarray
    semantic: np.ndarray
    selection: np.ndarray
    edits: EditLayer
    pending: tuple[SessionView, ...]


@dataclass(frozen=True, eq=False)
class HistoryStep:
    """One step: ``id`` (unique across histories: ``<history uid>:<n>``), what it did,
    the state after it and the host's state."""

    id: str
    what: str
    snapshot: SessionSnapshot
    host: Any = None


def _all_views(session: Session) -> list[SessionView]:
    seen: dict[int, SessionView] = {}
    for o in session.objects:
        for v in o.views:
            seen.setdefault(id(v), v)
    for v in session._views.values():
        seen.setdefault(id(v), v)
    return list(seen.values())


def take_snapshot(session: Session, previous: SessionSnapshot | None = None) -> SessionSnapshot:
    """The session's logical state now (arrays shared with ``previous`` when equal)."""
    labels = session.labels
    if previous is not None and np.array_equal(previous.labels, labels):
        labels = previous.labels
    else:
        labels = labels.copy()  # finish/reset replace it, older code wrote into it
    objects = tuple(
        _ObjectState(
            o.index,
            o.label,
            o.name,
            o.finished,
            o.selection,
            tuple(o.views),
            {a: tuple(cs) for a, cs in o.clicks.items()},
            tuple(o.accept_order),
        )
        for o in session.objects
    )
    fields = tuple((v, tuple(getattr(v, f) for f in _VIEW_FIELDS)) for v in _all_views(session))
    return SessionSnapshot(
        tuple(session.anchors),
        objects,
        dict(session._views),
        fields,
        labels,
        session._semantic,
        session._selection,
        session.edits,
        tuple(session._pending),
    )


def _fused_slots(views) -> dict[int, SessionView]:
    return {
        int(v.fusion_id): v
        for v in views
        if v.status == ViewStatus.FUSED and v.fusion_id is not None
    }


def restore_snapshot(session: Session, snap: SessionSnapshot) -> None:
    """Put ``session`` in the state ``snap`` holds (module docstring)."""
    before_fused = _fused_slots(session.current.views)
    before_pending = list(session._pending)
    session.anchors = list(snap.anchors)
    objs = []
    for o in snap.objects:
        rec = ObjectRecord(o.index, o.label, o.name, list(o.views))
        rec.clicks = {a: list(cs) for a, cs in o.clicks.items()}
        rec.accept_order = list(o.accept_order)
        rec.finished, rec.selection = o.finished, o.selection
        objs.append(rec)
    session.objects = objs
    session._views = dict(snap.view_table)
    for v, values in snap.view_fields:
        for f, val in zip(_VIEW_FIELDS, values):
            setattr(v, f, val)
    # the fusion holds the current object's fused views: reconcile it slot by slot
    target = _fused_slots(session.current.views)
    fusion = session.fusion
    for slot, v in before_fused.items():
        if target.get(slot) is not v and slot in fusion.view_ids:
            fusion.remove_view(slot)
    for slot, v in target.items():
        if before_fused.get(slot) is not v and slot not in fusion.view_ids:
            fusion.add_view(v.fusion_view, slot)
    if sorted(fusion.view_ids) != sorted(target):  # never expected; rebuild to be exact
        fusion.reset()
        for slot, v in target.items():
            fusion.add_view(v.fusion_view, slot)
    # pending NeRF views: forget the extra ones, re-submit the missing ones
    keep = set(map(id, snap.pending))
    for v in before_pending:
        if id(v) not in keep and session._worker is not None:
            session._worker.forget(v.id)
    session._pending = [v for v in before_pending if id(v) in keep]
    had = set(map(id, session._pending))
    for v in snap.pending:
        if id(v) not in had:
            session._accept_async(v, v.points, v.labels)
    session._pending = list(snap.pending)
    session.labels = snap.labels.copy()
    session._semantic, session._selection = snap.semantic, snap.selection
    session.edits = snap.edits


class SessionHistory:
    """Linear undo / redo history of a :class:`~divas_engine.session.Session` (module
    docstring). Made by :attr:`Session.history` with the current state as step 0."""

    def __init__(self, session: Session, limit: int = HISTORY_LIMIT) -> None:
        self.session = session
        self.uid = uuid.uuid4().hex[:12]
        self.limit = max(2, int(limit))
        self._counter = itertools.count()
        self.steps: list[HistoryStep] = []
        self.index = -1
        self.record("start")

    # ------------------------------------------------------------------ queries
    @property
    def current(self) -> HistoryStep:
        return self.steps[self.index]

    def __contains__(self, step_id: object) -> bool:
        return any(s.id == step_id for s in self.steps)

    @property
    def can_undo(self) -> bool:
        return self.index > 0

    @property
    def can_redo(self) -> bool:
        return self.index < len(self.steps) - 1

    @property
    def undo_name(self) -> str | None:
        """What undo would take back (None: nothing)."""
        return self.current.what if self.can_undo else None

    @property
    def redo_name(self) -> str | None:
        return self.steps[self.index + 1].what if self.can_redo else None

    # ------------------------------------------------------------------ steps
    def record(self, what: str, host: Any = None) -> HistoryStep:
        """Record the session's state after a step; drops the redo branch."""
        prev = self.steps[self.index].snapshot if self.steps else None
        step = HistoryStep(
            f"{self.uid}:{next(self._counter)}",
            str(what),
            take_snapshot(self.session, prev),
            host,
        )
        del self.steps[self.index + 1 :]
        self.steps.append(step)
        if len(self.steps) > self.limit:
            del self.steps[: len(self.steps) - self.limit]
        self.index = len(self.steps) - 1
        return step

    def goto(self, step_id: str) -> HistoryStep:
        """Restore step ``step_id`` (undo or redo any number of steps at once)."""
        k = next((i for i, s in enumerate(self.steps) if s.id == step_id), None)
        if k is None:
            raise KeyError(f"step {step_id!r} is not in this session's history")
        s = self.steps[k]
        if k != self.index:
            restore_snapshot(self.session, s.snapshot)
            self.index = k
            self.session._autosave()
        return s

    def restore_current(self) -> HistoryStep:
        """Put the session back in the current step's state (after a step that failed
        halfway, so a partial change never lingers)."""
        restore_snapshot(self.session, self.current.snapshot)
        return self.current

    def undo(self) -> HistoryStep | None:
        """Go one step back; returns the step now current (None: nothing to undo)."""
        return self.goto(self.steps[self.index - 1].id) if self.can_undo else None

    def redo(self) -> HistoryStep | None:
        return self.goto(self.steps[self.index + 1].id) if self.can_redo else None

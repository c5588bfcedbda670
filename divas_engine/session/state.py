"""The logical state of a session, in one object: what undo restores, what a save writes
and what a load rebuilds.

:class:`SessionState` holds the anchors, the objects with their clicks and centroid
views, the view table, the committed labels, the semantic and final selections of the
current object, the manual edit layers and the views still pending (NeRF). The
:class:`~divas_engine.session.Session` owns one and is the only writer of its fields;
:mod:`.history` keeps :class:`StateSnapshot` s of it and :mod:`.persistence` writes and
rebuilds it. Renders are not part of it: views keep their buffers across snapshots, so
going back to a step re-renders nothing. The fusion state that matches it belongs to
the session's backend; the session reconciles it on a restore.

The clicks are kept per object in 3D (:meth:`SessionState.object_clicks`) and, as
corrections, with the surface patch each one forces in or out of the selection
(:meth:`SessionState.composed`, :mod:`.corrections`): a click is a constraint on every
view of its object, whichever anchor, view or camera it was made on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kinds import ClickOrigin, ViewStatus
from ..segment.context import ObjectClicks
from .corrections import constrain
from .edits import EditLayer, compose
from .records import AnchorClick, AnchorView, Correction, ObjectRecord, SessionView

__all__ = ["SessionState", "StateSnapshot"]

#: the statuses of a spawned view whose click holds (:func:`~.corrections.constrain`)
_CLICK_HOLDS = (ViewStatus.FUSED, ViewStatus.REJECTED)
#: the view fields a step can change (a snapshot keeps their values)
_VIEW_FIELDS = (
    "status",
    "reason",
    "rejection",
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
    corrections: tuple[Correction, ...]
    accept_order: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class StateSnapshot:
    """A :class:`SessionState` frozen after one step (its arrays shared, not copied: the
    session replaces its selection, label and edit arrays rather than writing into them)."""

    anchors: tuple[AnchorView, ...]
    objects: tuple[_ObjectState, ...]
    view_table: dict[str, SessionView]
    view_fields: tuple[tuple[SessionView, tuple], ...]
    labels: np.ndarray
    semantic: np.ndarray
    selection: np.ndarray
    edits: EditLayer
    pending: tuple[SessionView, ...]


@dataclass(eq=False)
class SessionState:
    """The logical state of a session (module docstring).

    Attributes:
        anchors: the :class:`AnchorView` s offered, in order.
        objects: the :class:`ObjectRecord` s, the last one current.
        views: every centroid view still addressable, by id.
        labels: the committed integer labels (selection shape).
        semantic: the current object's fused-and-mapped selection ``S``; selection: ``S``
            with the manual edits (:func:`~.edits.compose`).
        edits: the manual :class:`~.edits.EditLayer`.
        pending: accepted views whose masks are still being segmented (NeRF).
    """

    anchors: list[AnchorView]
    objects: list[ObjectRecord]
    labels: np.ndarray
    semantic: np.ndarray
    selection: np.ndarray
    edits: EditLayer = field(default_factory=EditLayer)
    views: dict[str, SessionView] = field(default_factory=dict)
    pending: list[SessionView] = field(default_factory=list)

    @classmethod
    def empty(cls, anchors: list[AnchorView], shape: tuple[int, ...]) -> SessionState:
        """A fresh state: the anchors, one empty object, nothing selected or labelled."""
        return cls(
            list(anchors),
            [ObjectRecord(0, 1, "object_1")],
            np.zeros(shape, np.int32),
            np.zeros(shape, bool),
            np.zeros(shape, bool),
        )

    # ------------------------------------------------------------------ queries
    @property
    def current(self) -> ObjectRecord:
        return self.objects[-1]

    def view(self, view_id: str) -> SessionView:
        try:
            return self.views[view_id]
        except KeyError:
            raise KeyError(f"no view {view_id!r} in this session") from None

    def live_views(self) -> list[SessionView]:
        """The current object's fused views (what the fusion holds)."""
        return [v for v in self.current.views if v.status == ViewStatus.FUSED]

    def next_view(self) -> SessionView | None:
        """The first open (not yet accepted) centroid view of the current object."""
        return next((v for v in self.current.views if v.status == ViewStatus.OPEN), None)

    def fused_slots(self) -> dict[int, SessionView]:
        """The current object's fused views by fusion slot."""
        return {
            int(v.fusion_id): v
            for v in self.current.views
            if v.status == ViewStatus.FUSED and v.fusion_id is not None
        }

    def object_clicks(
        self, obj: ObjectRecord, new_positive: np.ndarray | None = None
    ) -> ObjectClicks:
        """The 3D clicks of ``obj`` on every anchor, then its corrections made elsewhere
        (views, cameras, points), with ``new_positive`` a positive click not recorded
        yet (the click being made)."""
        clicks = [c for cs in obj.clicks.values() for c in cs if c.point is not None]
        clicks += [c for c in obj.corrections if c.source.origin != ClickOrigin.ANCHOR]
        pts = [np.asarray(c.point, np.float64) for c in clicks]
        pos = [bool(c.positive) for c in clicks]
        if new_positive is not None:
            pts.append(np.asarray(new_positive, np.float64))
            pos.append(True)
        if not pts:
            return ObjectClicks.empty()
        return ObjectClicks(np.stack(pts), np.array(pos))

    def label_set(self, overwrite: bool, include_current: bool = True) -> np.ndarray:
        """Committed labels, plus the current object's selection as the next label
        (over earlier labels only when ``overwrite``)."""
        out = self.labels.copy()
        sel = self.selection
        if include_current and sel.any():
            take = sel if overwrite else sel & (out == 0)
            out[take] = self.current.label
        return out

    def object_selections(self) -> list[tuple[ObjectRecord, np.ndarray]]:
        """Finished objects and the current one when its selection is non-empty."""
        out = [(o, o.selection) for o in self.objects[:-1] if o.selection is not None]
        if self.selection.any():
            out.append((self.current, self.selection))
        return out

    # ------------------------------------------------------------------ changes
    def add_view(self, view: SessionView) -> None:
        """A new centroid view of the current object."""
        self.current.views.append(view)
        self.views[view.id] = view

    def composed(self) -> np.ndarray:
        """The selection of the current object: ``S`` with its clicks' patches forced in
        or out (:func:`~.corrections.constrain`), then the manual edits
        (:func:`~.edits.compose`)."""
        cur = self.current
        # a click holds once its view is accepted: fused, or refused (its mask failed)
        accepted = {v.id for v in cur.views if v.status in _CLICK_HOLDS}
        return compose(constrain(self.semantic, cur.corrections, accepted), self.edits, cur.index)

    def set_semantic(self, semantic: np.ndarray) -> None:
        """The fused selection ``S``; the selection is :meth:`composed` from it."""
        self.semantic = semantic
        self.selection = self.composed()

    def new_object(self) -> ObjectRecord:
        """Start the next object (empty, labelled one past the last)."""
        k = len(self.objects)
        obj = ObjectRecord(k, k + 1, f"object_{k + 1}")
        self.objects.append(obj)
        return obj

    # ------------------------------------------------------------------ snapshots
    def _all_views(self) -> list[SessionView]:
        seen: dict[int, SessionView] = {}
        for o in self.objects:
            for v in o.views:
                seen.setdefault(id(v), v)
        for v in self.views.values():
            seen.setdefault(id(v), v)
        return list(seen.values())

    def snapshot(self, previous: StateSnapshot | None = None) -> StateSnapshot:
        """This state now, frozen (the label array shared with ``previous`` when equal)."""
        labels = self.labels
        if previous is not None and np.array_equal(previous.labels, labels):
            labels = previous.labels
        else:
            labels = labels.copy()
        objects = tuple(
            _ObjectState(
                o.index,
                o.label,
                o.name,
                o.finished,
                o.selection,
                tuple(o.views),
                {a: tuple(cs) for a, cs in o.clicks.items()},
                tuple(o.corrections),
                tuple(o.accept_order),
            )
            for o in self.objects
        )
        fields = tuple((v, tuple(getattr(v, f) for f in _VIEW_FIELDS)) for v in self._all_views())
        return StateSnapshot(
            tuple(self.anchors),
            objects,
            dict(self.views),
            fields,
            labels,
            self.semantic,
            self.selection,
            self.edits,
            tuple(self.pending),
        )

    def restore(self, snap: StateSnapshot) -> None:
        """Put the data of ``snap`` back (the views' fields too); the pending list is
        the snapshot's. The caller reconciles what follows the state (the fusion, the
        segmentation worker)."""
        self.anchors = list(snap.anchors)
        objs = []
        for o in snap.objects:
            rec = ObjectRecord(o.index, o.label, o.name, list(o.views))
            rec.clicks = {a: list(cs) for a, cs in o.clicks.items()}
            rec.corrections = list(o.corrections)
            rec.accept_order = list(o.accept_order)
            rec.finished, rec.selection = o.finished, o.selection
            objs.append(rec)
        self.objects = objs
        self.views = dict(snap.view_table)
        for v, values in snap.view_fields:
            for f, val in zip(_VIEW_FIELDS, values):
                setattr(v, f, val)
        self.pending = list(snap.pending)
        self.labels = snap.labels.copy()
        self.semantic, self.selection = snap.semantic, snap.selection
        self.edits = snap.edits

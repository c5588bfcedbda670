"""Undo and redo of any session step (not in the paper, which undoes the last view only).

A :class:`SessionHistory` is a linear list of :class:`HistoryStep` s, one per user-level
step (a click, a prompt point, an accept, a reject, a finished object, a manual edit …),
each holding a :class:`~.state.StateSnapshot` of the session's state
(:class:`~.state.SessionState`) right after that step. Renders are not part of it: views
keep their buffers, so going back to a step re-renders nothing.

:meth:`SessionHistory.goto` restores any step through :meth:`Session.restore`, which
*reconciles* the fusion with it slot by slot (exact: the fusion is fixed-point, so the
accumulators equal the target's bit for bit whatever the path) and forgets or submits
again the pending NeRF views. The restored selection is the snapshot's, so the mapping
does not run again.

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

from .state import StateSnapshot

if TYPE_CHECKING:
    from .session import Session

__all__ = ["SessionHistory", "HistoryStep", "HISTORY_LIMIT"]

#: steps kept (Blender keeps 32 undo steps by default); the oldest are dropped.
HISTORY_LIMIT = 64


@dataclass(frozen=True, eq=False)
class HistoryStep:
    """One step: ``id`` (unique across histories: ``<history uid>:<n>``), what it did,
    the session's state after it and the host's state."""

    id: str
    what: str
    snapshot: StateSnapshot
    host: Any = None


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
            self.session.state.snapshot(prev),
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
            self.session.restore(s.snapshot)
            self.index = k
        return s

    def restore_current(self) -> HistoryStep:
        """Put the session back in the current step's state (after a step that failed
        halfway, so a partial change never lingers)."""
        self.session.restore(self.current.snapshot, autosave=False)
        return self.current

    def undo(self) -> HistoryStep | None:
        """Go one step back; returns the step now current (None: nothing to undo)."""
        return self.goto(self.steps[self.index - 1].id) if self.can_undo else None

    def redo(self) -> HistoryStep | None:
        return self.goto(self.steps[self.index + 1].id) if self.can_redo else None

"""Manual edits of a session's selection, composed with the semantic one (not in the paper).

The paper's selection is *semantic*: the fused masks mapped to primitives (Sec. 3.5–3.6).
Artists also clean it up by hand (box, lasso, brush, grow/shrink, by opacity …) and
delete or hide splats. The selection a session shows, labels and exports is

    F = ((S ∖ R_o) ∪ A_o) ∖ D

* ``S`` — the semantic selection of the current object ``o`` (fusion + mapping);
* ``A_o`` / ``R_o`` — primitives the user added / removed by hand on object ``o``;
* ``D`` — deleted primitives: never selected, labelled or exported again.

Hidden primitives ``H`` are kept too (a host does not draw them and its tools skip
them); hiding deselects them by hand (into ``R_o``, as Blender's hide does), so ``H``
never enters ``F`` and a replay does not depend on when something was hidden.

So a view fused *after* a manual edit still grows or shrinks ``S`` while the edit stays:
a splat removed by hand stays removed, one added stays added. A manual edit that turns
``F`` into ``F'`` updates the layers by its delta only:
``A' = (A ∪ (F' ∖ F)) ∖ (F ∖ F')`` and ``R' = (R ∪ (F ∖ F')) ∖ (F' ∖ F)``.

An :class:`EditLayer` is immutable: every edit returns a new one (its arrays are never
written in place), so the session history (:mod:`.history`) keeps references, not
copies. Masks have the session's selection shape (``[N]`` surfels, ``[D,H,W]`` voxels).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DivasInputError

if TYPE_CHECKING:
    from .core import SessionCore

__all__ = [
    "ObjectEdits",
    "EditLayer",
    "compose",
    "edit_arrays",
    "restore_session_edits",
    "restore_object_edits",
    "SelectionEditing",
]


@dataclass(frozen=True, eq=False)
class ObjectEdits:
    """``A_o`` (added) and ``R_o`` (removed) of one object; None: empty."""

    added: np.ndarray | None = None
    removed: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class EditLayer:
    """The manual layers of a session (module docstring); immutable."""

    objects: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    deleted: np.ndarray | None = None
    hidden: np.ndarray | None = None

    def of(self, obj_index: int) -> ObjectEdits:
        return self.objects.get(int(obj_index), ObjectEdits())

    def with_object(self, obj_index: int, edits: ObjectEdits | None) -> EditLayer:
        objs = dict(self.objects)
        if edits is None or (edits.added is None and edits.removed is None):
            objs.pop(int(obj_index), None)
        else:
            objs[int(obj_index)] = edits
        return replace(self, objects=MappingProxyType(objs))


def _any(mask: np.ndarray | None) -> np.ndarray | None:
    return None if mask is None or not mask.any() else mask


def compose(semantic: np.ndarray, edits: EditLayer, obj_index: int) -> np.ndarray:
    """``F = ((S ∖ R_o) ∪ A_o) ∖ D``."""
    o = edits.of(obj_index)
    out = semantic
    if o.removed is not None:
        out = out & ~o.removed
    if o.added is not None:
        out = out | o.added
    if edits.deleted is not None:
        out = out & ~edits.deleted
    return np.asarray(out, dtype=bool) if out is not semantic else semantic.copy()


def _delta(edits: ObjectEdits, old: np.ndarray, new: np.ndarray) -> ObjectEdits:
    on, off = new & ~old, old & ~new
    added = on if edits.added is None else (edits.added | on)
    removed = off if edits.removed is None else (edits.removed | off)
    return ObjectEdits(_any(added & ~off), _any(removed & ~on))


# ----------------------------------------------------------------------------- persistence
def edit_arrays(edits: EditLayer) -> dict[str, np.ndarray]:
    """The arrays a saved session keeps for ``edits`` (absent layers are not written)."""
    out: dict[str, np.ndarray] = {}
    if edits.deleted is not None:
        out["edits_deleted"] = edits.deleted
    if edits.hidden is not None:
        out["edits_hidden"] = edits.hidden
    for k, o in edits.objects.items():
        if o.added is not None:
            out[f"edits_added_{k}"] = o.added
        if o.removed is not None:
            out[f"edits_removed_{k}"] = o.removed
    return out


def _mask(arrays: dict[str, np.ndarray], key: str, shape) -> np.ndarray | None:
    a = arrays.get(key)
    if a is None:
        return None
    if a.shape != tuple(shape):
        raise DivasInputError(None, f"saved session array {key!r} has shape {a.shape}, not {shape}")
    return _any(np.asarray(a, dtype=bool))


def restore_session_edits(session: SessionCore, arrays: dict[str, np.ndarray]) -> None:
    """Deleted and hidden primitives of a saved session (before its objects replay)."""
    shape = session.backend.selection_shape
    session.edits = replace(
        session.edits,
        deleted=_mask(arrays, "edits_deleted", shape),
        hidden=_mask(arrays, "edits_hidden", shape),
    )


def restore_object_edits(session: SessionCore, obj_index: int, arrays) -> None:
    """Object ``obj_index``'s manual layers of a saved session."""
    shape = session.backend.selection_shape
    o = ObjectEdits(
        _mask(arrays, f"edits_added_{obj_index}", shape),
        _mask(arrays, f"edits_removed_{obj_index}", shape),
    )
    session.edits = session.edits.with_object(obj_index, o)


# ----------------------------------------------------------------------------- session API
class SelectionEditing:
    """The manual-edit steps of :class:`~divas_engine.session.Session` (a mixin over
    :class:`~.core.SessionCore`, which holds ``edits``, ``_semantic`` and ``_selection``)."""

    def _check_mask(self: SessionCore, mask, what: str) -> np.ndarray:
        m = np.asarray(mask)
        shape = self.backend.selection_shape
        if m.shape != shape:
            raise DivasInputError(None, f"{what}: a mask of shape {shape} is needed, got {m.shape}")
        return m.astype(bool, copy=False)

    def apply_selection(self: SessionCore, new, within=None, *, autosave: bool = True):
        """Make the current selection ``new`` by hand (a manual edit, composed with the
        semantic selection as in the module docstring); ``within``: only these primitives
        change (e.g. the ones a host shows). Deleted ones stay unselected. ``autosave``:
        False while a brush stroke is still going (the host saves at its end). Returns
        the new selection."""
        new = self._check_mask(new, "apply_selection")
        old = self._selection
        if within is not None:
            new = np.where(self._check_mask(within, "apply_selection within"), new, old)
        if self.edits.deleted is not None:
            new = new & ~self.edits.deleted
        k = self.current.index
        self.edits = self.edits.with_object(k, _delta(self.edits.of(k), old, new))
        self._selection = compose(self._semantic, self.edits, k)
        if autosave:
            self._autosave()
        return self._selection

    def delete_primitives(self: SessionCore, mask) -> int:
        """Delete primitives: out of every selection and label from now on, and out of
        every export (the scene file is never changed). Returns how many were new."""
        m = self._check_mask(mask, "delete_primitives")
        old = self.edits.deleted
        new = m.copy() if old is None else (old | m)
        count = int(new.sum()) - (0 if old is None else int(old.sum()))
        self.edits = replace(self.edits, deleted=_any(new))
        if count:
            if self.labels[m].any():
                self.labels = np.where(m, 0, self.labels).astype(self.labels.dtype)
            for o in self.objects[:-1]:
                if o.selection is not None and o.selection[m].any():
                    o.selection = o.selection & ~m
            self._selection = compose(self._semantic, self.edits, self.current.index)
        self._autosave()
        return count

    def hide_primitives(self: SessionCore, mask) -> None:
        """Hide primitives until :meth:`reveal_primitives`; hidden ones are deselected
        by hand (a manual removal that stays, module docstring)."""
        m = self._check_mask(mask, "hide_primitives")
        old = self.edits.hidden
        self.edits = replace(self.edits, hidden=_any(m.copy() if old is None else (old | m)))
        self.apply_selection(self._selection & ~m)  # autosaves

    def reveal_primitives(self: SessionCore) -> np.ndarray:
        """Show every hidden primitive again (still deselected); returns the mask of
        the revealed ones."""
        old = self.edits.hidden
        self.edits = replace(self.edits, hidden=None)
        self._autosave()
        return np.zeros(self.backend.selection_shape, bool) if old is None else old

    @property
    def semantic_selection(self: SessionCore) -> np.ndarray:
        """The fused-and-mapped selection of the current object, before manual edits."""
        return self._semantic

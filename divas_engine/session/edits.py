"""Manual edits of a session's selection, composed with the semantic one (not in the paper).

The paper's selection is *semantic* (fused masks mapped to primitives, Sec. 3.5–3.6); artists
also edit it by hand and delete or hide splats. The selection a session shows, labels and
exports is

    F = ((S ∖ R_o) ∪ A_o) ∖ D

with ``S`` the semantic selection of the current object ``o`` (its clicks' surface patches
forced in or out, :mod:`.corrections`; a click takes its patch out of the manual layer that
would undo it, :func:`yield_to_click`), ``A_o`` / ``R_o`` the primitives added / removed by hand
and ``D`` the deleted ones. Hiding deselects by hand (into ``R_o``), so hidden primitives never
enter ``F``. A view fused after an edit still changes ``S`` while the edit stays. An edit
turning ``F`` into ``F'`` updates the layers by its delta only:
``A' = (A ∪ (F' ∖ F)) ∖ (F ∖ F')`` and ``R' = (R ∪ (F ∖ F')) ∖ (F' ∖ F)``.

An :class:`EditLayer` is immutable (every edit returns a new one), so the history keeps
references, not copies. The edit steps change a :class:`~.state.SessionState`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from ..errors import DivasInputError

if TYPE_CHECKING:
    from .state import SessionState

__all__ = [
    "ObjectEdits",
    "EditLayer",
    "compose",
    "edit_arrays",
    "saved_edits",
    "check_mask",
    "apply_selection",
    "delete_primitives",
    "hide_primitives",
    "reveal_primitives",
    "yield_to_click",
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


def saved_edits(
    arrays: dict[str, np.ndarray], shape: tuple[int, ...], objects: Sequence[int]
) -> EditLayer:
    """The manual layers of a saved session: deleted and hidden primitives, and those of
    each object index in ``objects``."""
    layer = EditLayer(deleted=_mask(arrays, "edits_deleted", shape))
    layer = replace(layer, hidden=_mask(arrays, "edits_hidden", shape))
    for k in objects:
        o = ObjectEdits(
            _mask(arrays, f"edits_added_{k}", shape), _mask(arrays, f"edits_removed_{k}", shape)
        )
        layer = layer.with_object(k, o)
    return layer


# ----------------------------------------------------------------------------- edit steps
def check_mask(mask, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``mask`` as bool of the selection ``shape`` (:class:`DivasInputError` otherwise)."""
    m = np.asarray(mask)
    if m.shape != shape:
        raise DivasInputError(None, f"{what}: a mask of shape {shape} is needed, got {m.shape}")
    return m.astype(bool, copy=False)


def apply_selection(state: SessionState, new: np.ndarray, within: np.ndarray | None) -> np.ndarray:
    """Make the current selection ``new`` by hand (checked masks; ``within``: only these
    primitives change); deleted ones stay unselected. Returns the new selection."""
    old = state.selection
    if within is not None:
        new = np.where(within, new, old)
    if state.edits.deleted is not None:
        new = new & ~state.edits.deleted
    k = state.current.index
    state.edits = state.edits.with_object(k, _delta(state.edits.of(k), old, new))
    state.selection = state.composed()
    return state.selection


def delete_primitives(state: SessionState, m: np.ndarray) -> int:
    """Delete primitives (a checked mask): out of every selection and label from now on,
    and out of every export. Returns how many were new."""
    old = state.edits.deleted
    new = m.copy() if old is None else (old | m)
    count = int(new.sum()) - (0 if old is None else int(old.sum()))
    state.edits = replace(state.edits, deleted=_any(new))
    if count:
        if state.labels[m].any():
            state.labels = np.where(m, 0, state.labels).astype(state.labels.dtype)
        for o in state.objects[:-1]:
            if o.selection is not None and o.selection[m].any():
                o.selection = o.selection & ~m
        state.selection = state.composed()
    return count


def hide_primitives(state: SessionState, m: np.ndarray) -> None:
    """Hide primitives (a checked mask); hidden ones are deselected by hand (a manual
    removal that stays, module docstring)."""
    old = state.edits.hidden
    state.edits = replace(state.edits, hidden=_any(m.copy() if old is None else (old | m)))
    apply_selection(state, state.selection & ~m, None)


def reveal_primitives(state: SessionState) -> np.ndarray | None:
    """Show every hidden primitive again (still deselected); the mask of the revealed
    ones (None: none)."""
    old = state.edits.hidden
    state.edits = replace(state.edits, hidden=None)
    return old


def yield_to_click(state: SessionState, patch: np.ndarray, positive: bool) -> None:
    """A click on the current object forces ``patch`` (a mask) in or out: it leaves the
    manual layer that would undo that (``A_o`` for a negative click, ``R_o`` for a
    positive one)."""
    k = state.current.index
    o = state.edits.of(k)
    if positive and o.removed is not None and o.removed[patch].any():
        o = ObjectEdits(o.added, _any(o.removed & ~patch))
    elif not positive and o.added is not None and o.added[patch].any():
        o = ObjectEdits(_any(o.added & ~patch), o.removed)
    else:
        return
    state.edits = state.edits.with_object(k, o)

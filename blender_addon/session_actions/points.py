"""The session's selection on the object's points: ``divas_selected`` (bool, the current
object's selection) and ``divas_label`` (int, every object's label), written through
:mod:`..bridge` after every change of the selection, so the display material recolours
the splats live.

Only what changed is written: the point → primitive map and the values last written are kept
on the live session (:class:`Written`), so an accept writes just the points that changed — one
element at a time while they are few, one bulk ``foreach_set`` when that is cheaper
(:data:`PARTIAL_MAX`) — and leaves an unchanged attribute alone. When only the current
selection changed, no ``[N]`` array is made: the comparison goes into a kept buffer and the
labels are worked out at the changed points only (the engine's ``label_set`` rule). A fresh
``[N]`` array per accept would take pages from the kernel, and on a VM with free page
reporting touching them again is a host fault. The result equals a full write (tested);
anything that may have changed the points or the committed labels behind the session's back
(Blender's undo, a rebuilt point cloud, finishing an object, a reset, erasing, a history jump)
makes the next write a full one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from divas_engine.errors import DivasInputError
from divas_engine.point_attributes import INDEX, SELECTED, point_values
from divas_engine.scene import DensityGrid

from .. import bridge
from ..session_registry import LiveSession

__all__ = ["LABEL_ATTRIBUTE", "PARTIAL_MAX", "Written", "WriteBack", "write_selection"]

#: per-point int32: the label of every finished object plus the current selection.
LABEL_ATTRIBUTE = "divas_label"
#: up to this many changed points are written one element at a time; above it one bulk
#: write of the whole attribute is cheaper (an element write costs microseconds, a bulk
#: write of a million points milliseconds).
PARTIAL_MAX = 1000


@dataclass(eq=False)
class Written:
    """What was last written to a point cloud: its identity, each point's primitive
    (``pos``: index into the session's per-primitive arrays; None when point ``i`` is
    primitive ``i``, a fresh import: no ``[N]`` int64 map held, 23 MB at 3M points)
    and the values written."""

    geometry: int
    count: int
    pos: np.ndarray | None
    selected: np.ndarray
    labels: np.ndarray
    #: the label rule's inputs when ``labels`` was made (module docstring): the
    #: session's committed-labels array (the object itself: the engine replaces it
    #: whenever it changes), the current object's label and the overwrite switch
    committed: np.ndarray | None = None
    label: int = 0
    overwrite: bool = False
    #: kept ``[N]`` bool buffer for the comparison (no fresh pages per accept)
    scratch: np.ndarray | None = None


@dataclass(frozen=True)
class WriteBack:
    """What one :func:`write_selection` wrote: ``full`` (every point, both attributes) or
    the changed point indices of each attribute (empty: left alone)."""

    full: bool
    selected: np.ndarray
    labels: np.ndarray


def _primitive_of_points(live: LiveSession, geom) -> np.ndarray | None:
    """Each point's index into the session's per-primitive arrays (flat for grids);
    None when every primitive is there, in order (point ``i`` is primitive ``i``)."""
    s = live.session
    index = bridge.read_attribute(geom, INDEX)
    src = getattr(s.scene, "source", None)
    if not isinstance(s.scene, DensityGrid) and src is not None and src.kept_rows is not None:
        kept = src.kept_rows
        if len(index) == len(kept) and np.array_equal(index, kept):
            return None  # every primitive, in order (a fresh import)
    try:
        if isinstance(s.scene, DensityGrid):
            return point_values(s.scene, index, np.arange(s.scene.density.size))
        return point_values(s.scene, index, np.arange(len(s.scene)))
    except ValueError:
        raise DivasInputError(
            None,
            f"{geom.name!r} no longer matches the session's scene file (re-imported or "
            "edited outside DivAS?): press Start DivAS on it again",
        ) from None


def _write_changed(geom, name: str, values: np.ndarray, changed: np.ndarray) -> None:
    attr = geom.attributes.get(name)
    data = attr.data
    for i, v in zip(changed.tolist(), values[changed].tolist()):
        data[i].value = v


def _valid(w: Written | None, geom) -> bool:
    if w is None or w.geometry != geom.as_pointer() or w.count != bridge.point_count(geom):
        return False
    for name, dtype in ((SELECTED, "BOOLEAN"), (LABEL_ATTRIBUTE, "INT")):
        a = geom.attributes.get(name)
        if a is None or a.data_type != dtype or a.domain != "POINT":
            return False
    return True


def _label_inputs(s) -> tuple[np.ndarray, int, bool]:
    return s.labels, int(s.current.label), bool(s.config.overwrite_labels)


def _same_labels(w: Written, s) -> bool:
    """Only the current selection can have changed the labels since ``w`` was written."""
    committed, label, overwrite = _label_inputs(s)
    return w.committed is committed and w.label == label and w.overwrite == overwrite


def _write(geom, name: str, values: np.ndarray, changed: np.ndarray) -> None:
    if 0 < len(changed) <= PARTIAL_MAX:
        _write_changed(geom, name, values, changed)
    elif len(changed):
        bridge.write_attribute(geom, name, values)


def _write_full(geom, live: LiveSession, pos: np.ndarray | None) -> WriteBack:
    s = live.session
    selected = np.asarray(s.selection).reshape(-1)
    labels = np.asarray(s.label_set()).reshape(-1)
    if pos is not None:
        selected, labels = selected[pos], labels[pos]
    selected, labels = selected.astype(bool), labels.astype(np.int32)  # our own copies
    bridge.write_attribute(geom, SELECTED, selected)
    bridge.write_attribute(geom, LABEL_ATTRIBUTE, labels)
    geom.update_tag()
    committed, label, overwrite = _label_inputs(s)
    live.written = Written(
        geom.as_pointer(), len(selected), pos, selected, labels, committed, label, overwrite
    )
    everything = np.arange(len(selected))
    return WriteBack(True, everything, everything)


def _write_selection_changes(geom, live: LiveSession, w: Written) -> WriteBack:
    """The current selection changed, nothing else (:func:`_same_labels`): compare into
    the kept buffer, work the labels out at the changed points, update in place."""
    s = live.session
    selected = np.asarray(s.selection).reshape(-1)
    if w.pos is not None:
        selected = selected[w.pos]
    if w.scratch is None:
        w.scratch = np.empty(w.count, bool)
    changed = np.flatnonzero(np.not_equal(selected, w.selected, out=w.scratch))
    if len(changed) == 0:
        return WriteBack(False, changed, changed)
    now = selected[changed]
    prim = changed if w.pos is None else w.pos[changed]
    committed = np.asarray(w.committed).reshape(-1)[prim]
    take = now if w.overwrite else now & (committed == 0)  # Session.label_set's rule
    labels = np.where(take, w.label, committed).astype(np.int32)
    relabelled = np.flatnonzero(labels != w.labels[changed])
    w.selected[changed] = now
    w.labels[changed[relabelled]] = labels[relabelled]
    _write(geom, SELECTED, w.selected, changed)
    _write(geom, LABEL_ATTRIBUTE, w.labels, changed[relabelled])
    geom.update_tag()
    return WriteBack(False, changed, changed[relabelled])


def write_selection(obj, live: LiveSession, *, full: bool = False) -> WriteBack:
    """``divas_selected`` and ``divas_label`` of ``obj``'s points from the session: only
    the changed points (module docstring), or every point with ``full`` or when what
    was last written is unknown."""
    s = live.session
    geom = obj.data
    w = live.written
    if full or not _valid(w, geom):
        return _write_full(geom, live, _primitive_of_points(live, geom))
    if _same_labels(w, s):
        return _write_selection_changes(geom, live, w)
    selected = np.asarray(s.selection).reshape(-1)
    labels = np.asarray(s.label_set()).reshape(-1)
    if w.pos is not None:
        selected, labels = selected[w.pos], labels[w.pos]
    selected, labels = selected.astype(bool), labels.astype(np.int32)  # our own copies
    out = []
    for name, new, old in ((SELECTED, selected, w.selected), (LABEL_ATTRIBUTE, labels, w.labels)):
        changed = np.flatnonzero(new != old)
        _write(geom, name, new, changed)
        out.append(changed)
    if any(len(c) for c in out):
        geom.update_tag()
    w.selected, w.labels = selected, labels
    w.committed, w.label, w.overwrite = _label_inputs(s)
    return WriteBack(False, out[0], out[1])

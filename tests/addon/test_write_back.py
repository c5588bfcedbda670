"""An accept or an undo writes the points' selection and labels
back without an array of every point — the comparison in a kept buffer, the labels worked
out at the changed points, the kept arrays updated in place — and the attributes then
equal the engine's selection and ``label_set`` (the full reference) at every step: click,
accept, undo, a second object over the first (labels kept, or overwritten), finish,
reset. The panel's counts are counted once, when read, not twice inside an accept.
"""

from __future__ import annotations

from dataclasses import replace

import bpy
import numpy as np
import pytest

from blender_addon import bridge
from blender_addon.session_actions import LABEL_ATTRIBUTE, loop_steps, points
from divas_engine.point_attributes import INDEX, SELECTED, point_values
from divas_engine.session import Session

from .test_persistence import _click
from .test_session_memory import _start


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_write_back")
    sc = generate_scene("ribs", out, size=12_000, seed=4, grid_resolution=24)
    return out, sc


def _assert_matches_engine(obj, live) -> None:
    """The attributes equal a full write: the engine's selection and label set, each
    point through its ``divas_index`` (independent of what the write-back kept)."""
    s = live.session
    index = bridge.read_attribute(obj.data, INDEX)
    np.testing.assert_array_equal(
        bridge.read_attribute(obj.data, SELECTED), point_values(s.scene, index, s.selection)
    )
    np.testing.assert_array_equal(
        bridge.read_attribute(obj.data, LABEL_ATTRIBUTE),
        point_values(s.scene, index, s.label_set()),
    )


class _Spy:
    """Calls of ``Session.label_set`` and ``Session.counts`` (who makes ``[N]`` arrays)."""

    def __init__(self, monkeypatch):
        self.label_set = self.counts = 0
        plain_ls, plain_counts = Session.label_set, Session.counts

        def label_set(s, *a, **k):
            self.label_set += 1
            return plain_ls(s, *a, **k)

        def counts(s, *a, **k):
            self.counts += 1
            return plain_counts(s, *a, **k)

        monkeypatch.setattr(Session, "label_set", label_set)
        monkeypatch.setattr(Session, "counts", counts)


@pytest.mark.parametrize("overwrite", [False, True])
@pytest.mark.parametrize("partial_max", [10**9, 0])
def test_accept_and_undo_write_back_in_place(scene_dir, monkeypatch, overwrite, partial_max):
    """``partial_max``: changed points written one by one, or the kept array in bulk;
    ``overwrite``: a later object takes labelled points (or leaves them)."""
    monkeypatch.setattr(points, "PARTIAL_MAX", partial_max)
    _, sc = scene_dir
    obj, live = _start(scene_dir)
    s = live.session
    s.config = replace(s.config, overwrite_labels=overwrite)
    # a changed rule input is noticed (a write with the label set), then kept
    assert points.write_selection(obj, live).full is False
    assert live.written.overwrite == overwrite
    _assert_matches_engine(obj, live)
    spy = _Spy(monkeypatch)
    calls = []
    plain = loop_steps.write_selection

    def recording(o, lv, **kw):
        before = spy.label_set
        wb = plain(o, lv, **kw)
        calls.append((wb, spy.label_set - before))
        return wb

    monkeypatch.setattr(loop_steps, "write_selection", recording)

    def accept_in_place():
        w = live.written
        kept = (w.selected, w.labels)
        assert bpy.ops.divas.session_accept() == {"FINISHED"}
        wb, label_sets = calls[-1]
        assert not wb.full and len(wb.selected) > 0
        assert label_sets == 0  # no [N] label set made by the write-back
        assert live.written.selected is kept[0] and live.written.labels is kept[1]
        _assert_matches_engine(obj, live)
        return wb

    _click(live, 0, sc)
    wb = accept_in_place()
    assert len(wb.labels) == len(wb.selected)  # nothing labelled yet: all relabelled
    assert bpy.ops.divas.session_undo() == {"FINISHED"}
    wb, label_sets = calls[-1]
    assert not wb.full and label_sets == 0 and len(wb.selected) > 0
    _assert_matches_engine(obj, live)
    assert not bridge.read_attribute(obj.data, SELECTED).any()
    accept_in_place()
    first = bridge.read_attribute(obj.data, SELECTED).copy()
    # finishing the object commits the labels (a new committed-labels array): full
    assert bpy.ops.divas.session_finish_object(name="first") == {"FINISHED"}
    _assert_matches_engine(obj, live)
    assert calls[-1][1] == 1
    # a second object over the first: its labels are kept, or overwritten
    _click(live, 0, sc)
    wb = accept_in_place()
    second = bridge.read_attribute(obj.data, SELECTED)
    both = first & second
    assert both.any()
    labels = bridge.read_attribute(obj.data, LABEL_ATTRIBUTE)
    first_label, second_label = s.objects[0].label, s.current.label
    assert (labels[both] == (second_label if overwrite else first_label)).all()
    assert len(wb.labels) == (len(wb.selected) if overwrite else (second & ~first).sum())
    assert bpy.ops.divas.session_undo() == {"FINISHED"}
    _assert_matches_engine(obj, live)
    assert bpy.ops.divas.session_reset() == {"FINISHED"}
    _assert_matches_engine(obj, live)


def test_an_accept_counts_once_when_the_panel_reads(scene_dir, monkeypatch):
    _, sc = scene_dir
    obj, live = _start(scene_dir)
    _click(live, 0, sc)
    live.counts()
    spy = _Spy(monkeypatch)
    assert bpy.ops.divas.session_accept() == {"FINISHED"}
    assert spy.counts == 0  # the step itself does not count
    c = live.counts()
    assert spy.counts == 1
    assert c == live.session.counts(wait=False)
    assert c["selected"] == int(live.session.selection.sum()) > 0
    live.counts()
    assert spy.counts == 2  # (the line above) — the cached counts were read for free

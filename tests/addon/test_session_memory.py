"""What the add-on keeps and how freed
memory leaves the process, with the written selection unchanged.

* the write-back keeps no point → primitive map when point ``i`` is primitive ``i`` (a
  fresh import: 23 MB at 3M points), and writes what a full write from the session
  writes — with the map (a reordered point cloud) too;
* glibc's fixed mmap threshold (:func:`blender_addon.memory.limit_heap`, set when a
  session of 2M+ primitives starts) gives a freed array's pages back at once, where the
  adaptive threshold leaves them on the heap (checked in a fresh process, both ways, so
  the test can fail); a small scene keeps the adaptive threshold.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import bpy
import numpy as np
import pytest

from blender_addon import bridge, memory, session_registry
from blender_addon.session_actions import LABEL_ATTRIBUTE, points
from divas_engine.point_attributes import INDEX, SELECTED


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    from divas_engine.synthetic import generate_scene

    out = tmp_path_factory.mktemp("ribs_memory")
    sc = generate_scene("ribs", out, size=8_000, seed=2, grid_resolution=16)
    return out, sc


def _start(scene_dir):
    out, _ = scene_dir
    assert bpy.ops.divas.import_splats(filepath=str(out / "scene.ply")) == {"FINISHED"}
    obj = bpy.context.active_object
    bpy.context.scene.divas.render_scale = 0.5
    bpy.context.scene.divas.autosave = False
    ok = bpy.ops.divas.start_session(
        device="cpu", segmenter="oracle", gt_labels=str(out / "labels.npy")
    )
    assert ok == {"FINISHED"}
    return obj, session_registry.get(obj)


def _attrs(obj):
    g = obj.data
    return bridge.read_attribute(g, SELECTED), bridge.read_attribute(g, LABEL_ATTRIBUTE)


def _some_selection(live):
    s = live.session
    n = len(s.scene)
    sel = np.zeros(n, bool)
    sel[np.random.default_rng(0).choice(n, n // 5, replace=False)] = True
    s.state.set_semantic(sel)  # as an accept would (no render needed for the write-back)
    return sel


def test_fresh_import_keeps_no_point_map_and_writes_the_same(scene_dir):
    obj, live = _start(scene_dir)
    assert live.written is not None and live.written.pos is None
    sel = _some_selection(live)
    wb = points.write_selection(obj, live)
    assert not wb.full and len(wb.selected) == int(sel.sum())
    got_sel, got_lab = _attrs(obj)
    np.testing.assert_array_equal(got_sel, sel)
    np.testing.assert_array_equal(got_lab, live.session.label_set().astype(np.int32))
    assert got_lab.any()


def test_reordered_points_keep_their_map_and_write_the_same(scene_dir):
    obj, live = _start(scene_dir)
    g = obj.data
    index = bridge.read_attribute(g, INDEX)
    perm = np.random.default_rng(1).permutation(len(index))
    bridge.write_attribute(g, INDEX, index[perm])  # point i now shows file row perm[i]
    sel = _some_selection(live)
    wb = points.write_selection(obj, live, full=True)
    assert wb.full and live.written.pos is not None
    got_sel, got_lab = _attrs(obj)
    np.testing.assert_array_equal(got_sel, sel[perm])  # every row kept: row == primitive
    np.testing.assert_array_equal(got_lab, live.session.label_set()[perm])
    # the next change is written through the map as well
    sel2 = sel.copy()
    sel2[perm[:7]] = ~sel2[perm[:7]]
    live.session.state.set_semantic(sel2)
    wb = points.write_selection(obj, live)
    assert not wb.full and sorted(wb.selected.tolist()) == list(range(7))
    np.testing.assert_array_equal(_attrs(obj)[0], sel2[perm])


_PROBE = textwrap.dedent(
    """
    import importlib.util, sys
    import numpy as np
    spec = importlib.util.spec_from_file_location("m", sys.argv[1])
    m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)
    def rss():
        return int(open("/proc/self/statm").read().split()[1]) * 4096
    big = np.ones(16 << 20, np.uint8); del big  # raises the adaptive threshold to 16 MB
    if sys.argv[2] == "limit":
        assert m.limit_heap()
    arrs = [np.ones(m.MMAP_THRESHOLD + (2 << 20), np.uint8) for _ in range(30)]  # touched
    before = rss()
    del arrs[::2]  # every other one: holes in the middle of the heap
    print((before - rss()) >> 20, (15 * (m.MMAP_THRESHOLD + (2 << 20))) >> 20)
    """
)


@pytest.mark.skipif(memory._glibc() is None, reason="glibc only")
def test_fixed_mmap_threshold_gives_freed_pages_back():
    path = Path(memory.__file__)
    drop = {}
    for mode in ("limit", "adaptive"):
        out = subprocess.run(
            [sys.executable, "-c", _PROBE, str(path), mode],
            capture_output=True,
            text=True,
            check=True,
        )
        drop[mode], freed = (int(x) for x in out.stdout.split()[-2:])
    assert drop["limit"] >= 0.9 * freed, (drop, freed)  # the 15 freed arrays leave at once
    assert drop["adaptive"] <= 10, drop  # they stay resident on the heap without it
    assert memory.release_freed() and memory.last_seconds >= 0.0


def test_start_fixes_the_threshold_only_for_large_scenes(scene_dir, monkeypatch):
    calls, asked = [], []
    monkeypatch.setattr(memory, "_limited", False)
    monkeypatch.setattr(memory, "limit_heap", lambda: calls.append(1) or True)
    plain = memory.limit_heap_for
    monkeypatch.setattr(memory, "limit_heap_for", lambda n: asked.append(n) or plain(n))
    _start(scene_dir)
    assert asked == [8_000] and calls == []  # 8k splats: glibc's adaptive threshold kept
    assert memory.limit_heap_for(memory.LIMIT_FROM) and calls == [1]


def test_the_mask_renders_reuse_their_buffers_only_with_the_fixed_threshold(scene_dir, monkeypatch):
    """With the fixed mmap threshold (a large scene) the session's renderer keeps
    its sparse value renders' working arrays between calls; with glibc's adaptive one
    (what a small scene keeps) it does not (freed arrays are reused there anyway)."""
    monkeypatch.setattr(memory, "_limited", False)
    _, live = _start(scene_dir)
    assert live.session.renderer.scratch_sparse is False
    monkeypatch.setattr(memory, "limit_heap_for", lambda n: True)
    _, live = _start(scene_dir)
    assert live.session.renderer.scratch_sparse is True

"""graph3d's cut started from a click's 3D point before its centroid view renders (issue
20): the prompt takes the very cut the background thread made, its seeds are the ones
the prompt computes key for key, and the masks, scores and selections equal those of a
session without the prefetch bit for bit — after a negative click, after an undone
click, and when the background cut fails. The cut cache's own rules are tested on a
counting stand-in."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from divas_engine.segment.graph3d import Graph3DSegmenter
from divas_engine.segment.graph3d.cut_cache import CutCache
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene


@pytest.fixture(scope="module")
def plant():
    return generate_scene("plant", None, size=20_000, seed=0)


def _open(sc, prefetch: bool) -> tuple[Session, Graph3DSegmenter]:
    seg = Graph3DSegmenter()
    assert not seg.prefetch_cuts  # off in the engine (the add-on switches it on)
    seg.prefetch_cuts = prefetch
    s = Session.open(sc.scene, sc.cameras, SessionConfig(render_scale=0.5), seg, "cpu")
    assert s.wait_warm_up(120)
    return s, seg


def _on_object(s: Session, sc, k: int) -> tuple[int, tuple[float, float]]:
    """``(anchor, pixel)`` of the scene's ``k``-th ground-truth click point that shows in an
    anchor (the benchmark's way of clicking the object)."""
    found = []
    for a in s.anchors:
        for c in sc.metadata["clicks"]:
            uv, z = a.camera.project(np.array([c["xyz"]]))
            x, y = float(uv[0, 0]), float(uv[0, 1])
            if z[0] > 0 and 0 <= x < a.camera.width and 0 <= y < a.camera.height:
                found.append((a.index, (x, y)))
    return found[k]


def _loop(sc, prefetch: bool, *, negative: bool = False, undo_first: bool = False):
    """Optional negative click, a positive click (undone first when ``undo_first``), a
    positive click, the default prompt: ``(preview, cut used, prefetched cut, seeds key
    the prompt computed, segmenter)``."""
    s, seg = _open(sc, prefetch)
    if negative:
        s.click(*_on_object(s, sc, 1), positive=False)
    if undo_first:
        s.history.record("start")
        s.click(*_on_object(s, sc, 2))
        s.history.record("click")
        seg.cuts.wait(120)
        s.history.undo()
    v = s.click(*_on_object(s, sc, 0))
    assert seg.cuts.wait(120)
    view = s.view_context(v)
    clicks = view.clicks
    key = seg.seeds_of(clicks).key()
    prefetched = seg.cuts.peek(key)
    seeds, _ = seg.seeds(view, *s.default_prompts(v))
    prev = s.prompt(v)
    out = (prev, seg.last_cut, prefetched, seeds.key() == key, seg, clicks)
    s.close()
    return out


def _same(a, b) -> None:
    pa, ca = a[0], a[1]
    pb, cb = b[0], b[1]
    assert np.array_equal(pa.masks, pb.masks) and np.array_equal(pa.scores, pb.scores)
    assert np.array_equal(pa.mask, pb.mask)
    assert np.array_equal(ca.selected, cb.selected) and np.array_equal(ca.scores, cb.scores)
    assert np.array_equal(ca.cut.potential, cb.cut.potential)


@pytest.mark.parametrize("negative", [False, True])
def test_the_prompt_takes_the_prefetched_cut_and_its_masks_are_unchanged(plant, negative):
    on = _loop(plant, True, negative=negative)
    off = _loop(plant, False, negative=negative)
    prev, used, prefetched, same_key, seg, clicks = on
    assert same_key  # the prefetch's seeds are the prompt's, key for key
    assert prefetched is not None and used is prefetched  # the background cut itself
    assert seg.cuts.prefetch_hits == 1
    assert off[2] is None and off[4].cuts.prefetch_hits == 0  # off: nothing ahead
    assert bool(np.any(~clicks.positive)) == negative and prev.mask.any()
    _same(on, off)


def test_an_undone_click_leaves_its_cut_unused(plant):
    on = _loop(plant, True, undo_first=True)
    off = _loop(plant, False)
    assert len(on[5].points) == 1  # the undone click is not among the object's clicks
    # the undone click's cut went only to its own masks rendered ahead (prefetch_view)
    assert on[1] is on[2] and on[4].cuts.prefetch_hits == 1 + int(on[4].prefetch_masks)
    _same(on, off)


def test_a_failed_background_cut_is_computed_again_by_the_prompt(plant, monkeypatch):
    s, seg = _open(plant, True)
    seg.prefetch_masks = False  # (else the background mask render computes it again)
    real = seg._cut
    calls: list[str] = []

    def flaky(seeds):
        calls.append(threading.current_thread().name)
        if len(calls) == 1:
            raise RuntimeError("background failure")
        return real(seeds)

    monkeypatch.setattr(seg, "_cut", flaky)
    v = s.click(*_on_object(s, plant, 0))
    assert seg.cuts.wait(120)
    prev = s.prompt(v)
    s.close()
    assert calls[0] == "divas-graph3d-prefetch" and len(calls) == 2
    assert calls[1] == threading.current_thread().name and seg.cuts.prefetch_hits == 0
    _same((prev, seg.last_cut), _loop(plant, False)[:2])


def test_closing_the_session_waits_for_the_cut_a_click_started(plant, monkeypatch):
    """No prefetch thread outlives its session (in Blender: past a file close or exit)."""
    s, seg = _open(plant, True)
    real = seg._cut

    def slow(seeds):
        time.sleep(1.0)
        return real(seeds)

    monkeypatch.setattr(seg, "_cut", slow)
    s.click(*_on_object(s, plant, 0))
    s.close()
    alive = [t for t in threading.enumerate() if t.name == "divas-graph3d-prefetch"]
    assert not alive and len(seg.cuts) == 1


# ---------------------------------------------------------------------- the cache's rules
class _Counting:
    def __init__(self, value, gate: threading.Event | None = None, fail: bool = False):
        self.value, self.gate, self.fail, self.calls = value, gate, fail, 0

    def __call__(self):
        self.calls += 1
        if self.gate is not None:
            assert self.gate.wait(30)
        if self.fail:
            raise ValueError("no cut")
        return self.value


def test_a_prompt_waits_for_the_cut_in_flight_and_never_computes_it_twice():
    cache: CutCache = CutCache(2)
    gate = threading.Event()
    bg, fg = _Counting("bg", gate), _Counting("fg")
    assert cache.start(b"k", bg) and not cache.start(b"k", bg)  # one thread per key
    got: list = []
    t = threading.Thread(target=lambda: got.append(cache.get(b"k", fg)))
    t.start()
    t.join(0.2)
    assert t.is_alive() and not got  # waiting for the background cut
    gate.set()
    t.join(30)
    assert got == ["bg"] and fg.calls == 0 and bg.calls == 1 and cache.prefetch_hits == 1
    assert cache.get(b"k", fg) == "bg" and fg.calls == 0
    assert not cache.start(b"k", bg)  # kept: nothing started


def test_a_background_cut_two_waiters_take_counts_once():
    """The prompt and the masks rendered ahead may both wait for one cut in flight."""
    cache: CutCache = CutCache(2)
    gate = threading.Event()
    assert cache.start(b"k", _Counting("bg", gate))
    got: list = []
    waiters = [threading.Thread(target=lambda: got.append(cache.get(b"k", _Counting("fg"))))]
    waiters.append(threading.Thread(target=lambda: got.append(cache.get(b"k", _Counting("fg")))))
    for t in waiters:
        t.start()
    time.sleep(0.2)
    gate.set()
    for t in waiters:
        t.join(30)
    assert got == ["bg", "bg"] and cache.prefetch_hits == 1


def test_a_failed_or_superseded_background_cut_is_not_kept():
    cache: CutCache = CutCache(2)
    assert cache.start(b"bad", _Counting("x", fail=True)) and cache.wait(30)
    assert cache.peek(b"bad") is None and cache.in_flight(b"bad") is None
    fg = _Counting("fg")
    assert cache.get(b"bad", fg) == "fg" and fg.calls == 1  # computed by the caller
    gate = threading.Event()
    assert cache.start(b"old", _Counting("old", gate))
    cache.clear()  # a new scene bound meanwhile
    gate.set()
    assert cache.wait(30) and cache.peek(b"old") is None and len(cache) == 0
    for k in (b"a", b"b", b"c"):  # least recently used dropped
        cache.get(k, _Counting(k))
    assert cache.peek(b"a") is None and cache.peek(b"c") == b"c"

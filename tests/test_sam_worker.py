"""SAM scheduling (paper Sec. 3.4 "Execution scheduling"): async worker for NeRF, sync for 2DGS."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from divas_engine.segment import SamWorker, SegmentationJobError, Segmenter, ViewContext
from divas_engine.segment.worker import SYNC_PENDING


class FakeSegmenter(Segmenter):
    """Mask value = first pixel's red channel; optional delay per view; 'bad' views fail."""

    name = "fake"

    def __init__(self, delays=None):
        super().__init__(cache_size=16)
        self.delays = delays or {}
        self.encodes, self.predicts, self.threads = 0, 0, set()

    def _encode(self, rgb, depth, view_id):
        self.encodes += 1
        self.threads.add(threading.get_ident())
        time.sleep(self.delays.get(view_id, 0.0))
        if view_id == "bad":
            raise ValueError("broken view")
        return (float(rgb[0, 0, 0]), rgb.shape[:2])

    def _predict(self, state, points, labels):
        self.predicts += 1
        v, (h, w) = state
        m = np.full((3, h, w), v, np.float32)
        m[2] = float(len(points))
        return m, np.array([0.1, 0.9, 0.2], np.float32)


def _rgb(v):
    return np.full((4, 5, 3), v, np.float32)


P1, L1 = np.array([[1.0, 1.0]]), np.array([1])


def test_async_results_in_submission_order_and_in_background():
    seg = FakeSegmenter(delays={"a": 0.15, "b": 0.05, "c": 0.0})
    with SamWorker(seg) as w:
        t = time.perf_counter()
        for i, v in enumerate("abc"):
            w.submit(ViewContext(v, _rgb(0.1 * (i + 1))), P1, L1)
        assert time.perf_counter() - t < 0.1  # submit does not wait for SAM
        assert w.pending() == 3
        res = w.sync()
    assert list(res) == ["a", "b", "c"]
    for i, v in enumerate("abc"):
        assert res[v].masks[1, 0, 0] == pytest.approx(0.1 * (i + 1))
        np.testing.assert_allclose(res[v].scores, [0.1, 0.9, 0.2])
    assert threading.get_ident() not in seg.threads and len(seg.threads) == 1
    assert w.pending() == 0


def test_should_sync_rule():
    with SamWorker(FakeSegmenter()) as w:
        assert not w.should_sync(end_of_group=True)  # nothing pending
        w.submit(ViewContext(0, _rgb(0.1)), P1, L1)
        assert not w.should_sync(end_of_group=False)
        assert w.should_sync(end_of_group=True)  # (i) last view of the anchor group
        w.submit(ViewContext(1, _rgb(0.2)), P1, L1)
        assert not w.should_sync()
        w.submit(ViewContext(2, _rgb(0.3)), P1, L1)
        assert SYNC_PENDING == 3 and w.should_sync()  # (ii) three pending masks
        assert len(w.sync()) == 3 and not w.should_sync(True)


def test_result_cache_and_embedding_reuse():
    seg = FakeSegmenter()
    with SamWorker(seg) as w:
        w.submit(ViewContext("v", _rgb(0.5)), P1, L1)
        first = w.sync()["v"]
        w.submit(ViewContext("v", _rgb(0.5)), P1.copy(), L1.copy())  # same prompts: cached result
        again = w.sync()["v"]
        assert again is first and w.runs == 1 and w.result("v") is first
        w.submit(ViewContext("v", _rgb(0.5)), np.array([[1.0, 1.0], [2.0, 2.0]]), np.array([1, 0]))
        new = w.sync()["v"]
        assert w.runs == 2 and new.masks[2, 0, 0] == 2.0
        assert seg.encodes == 1 and seg.predicts == 2  # the view's embedding was reused
        w.forget("v")
        assert w.result("v") is None


def test_resubmitting_a_pending_view_replaces_it():
    seg = FakeSegmenter(delays={"slow": 0.1})
    with SamWorker(seg) as w:
        w.submit(ViewContext("slow", _rgb(0.1)), P1, L1)
        w.submit(ViewContext("x", _rgb(0.2)), P1, L1)
        w.submit(ViewContext("x", _rgb(0.2)), np.array([[1.0, 1.0], [3.0, 3.0]]), np.array([1, 1]))
        w.submit(ViewContext("y", _rgb(0.3)), P1, L1)
        w.submit(ViewContext("x", _rgb(0.2)), np.array([[1.0, 1.0], [3.0, 3.0]]), np.array([1, 1]))
        assert w.pending() == 3
        res = w.sync()
    assert list(res) == ["slow", "y", "x"] and res["x"].masks[2, 0, 0] == 2.0


def test_errors_reraised_at_sync_with_view_id():
    with SamWorker(FakeSegmenter()) as w:
        w.submit(ViewContext("ok1", _rgb(0.1)), P1, L1)
        w.submit(ViewContext("bad", _rgb(0.2)), P1, L1)  # fails in the thread, not here
        w.submit(ViewContext("ok2", _rgb(0.3)), P1, L1)
        with pytest.raises(SegmentationJobError, match="'bad'.*broken view") as info:
            w.sync()
        err = info.value
        assert err.view_id == "bad" and isinstance(err.cause, ValueError)
        assert isinstance(err.__cause__, ValueError)
        assert list(err.results) == ["ok1", "ok2"] and w.result("ok2") is not None
        assert w.pending() == 0
        w.submit(ViewContext("ok3", _rgb(0.4)), P1, L1)
        assert list(w.sync()) == ["ok3"]


def test_synchronous_mode_same_api():
    seg = FakeSegmenter()
    w = SamWorker(seg, asynchronous=False)
    w.submit(ViewContext("a", _rgb(0.1)), P1, L1)
    assert seg.threads == {threading.get_ident()}  # ran inside submit
    assert w.should_sync(end_of_group=False)  # 2DGS: every view is fused at once
    w.submit(ViewContext("bad", _rgb(0.2)), P1, L1)  # error kept for sync(), like async
    with pytest.raises(SegmentationJobError) as info:
        w.sync()
    assert list(info.value.results) == ["a"]
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.submit(ViewContext("b", _rgb(0.1)), P1, L1)


def test_close_cancels_queued_jobs():
    seg = FakeSegmenter(delays={0: 0.2})
    w = SamWorker(seg)
    for i in range(4):
        w.submit(ViewContext(i, _rgb(0.1)), P1, L1)
    time.sleep(0.05)
    w.close()
    w.close()  # idempotent
    assert seg.encodes == 1 and w.pending() == 0
    with pytest.raises(RuntimeError):
        w.submit(ViewContext(9, _rgb(0.1)), P1, L1)


def test_inputs_are_copied_for_the_background_thread():
    seg = FakeSegmenter(delays={"a": 0.05})
    with SamWorker(seg) as w:
        buf = _rgb(0.25)
        w.submit(ViewContext("a", buf), P1, L1)
        buf[:] = 0.75  # the caller reuses its render buffer
        assert w.sync()["a"].masks[1, 0, 0] == pytest.approx(0.25)

"""One BLAS thread while a session is open (:mod:`divas_engine.blas_threads`): the
count is set by the first open session and restored by the last close, and the engine's
results — the centroid view, its buffers, graph3d's cut and masks — are the same bits with
one BLAS thread and with two (the check can fail: a threaded ``ddot`` rounds by thread
count, and is shown to here)."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import ThreadpoolController

from divas_engine import blas_threads
from divas_engine.blas_threads import BlasThreads
from divas_engine.segment.graph3d import Graph3DSegmenter
from divas_engine.session import Session, SessionConfig
from divas_engine.synthetic import generate_scene


class _FakeLimiter:
    def __init__(self, libs: list[list[int]], n: int) -> None:
        self.libs, self.saved = libs, [x[0] for x in libs]
        for x in libs:
            x[0] = n

    def restore_original_limits(self) -> None:
        for x, n in zip(self.libs, self.saved, strict=True):
            x[0] = n


def test_first_open_sets_one_thread_and_last_close_restores(monkeypatch):
    libs = [[2], [4]]
    made = []
    monkeypatch.setattr(
        blas_threads, "limit_blas", lambda n: made.append(n) or _FakeLimiter(libs, n)
    )
    monkeypatch.setattr(BlasThreads, "_users", 0)
    monkeypatch.setattr(BlasThreads, "_limiter", None)
    BlasThreads.acquire()
    assert libs == [[1], [1]]
    BlasThreads.acquire()  # a second session: nothing changes
    BlasThreads.release()
    assert libs == [[1], [1]]
    BlasThreads.release()  # the last one: each library's own count back
    assert libs == [[2], [4]]
    BlasThreads.release()  # an extra release changes nothing
    assert libs == [[2], [4]] and made == [1]
    monkeypatch.setattr(blas_threads, "SESSION_BLAS_THREADS", None)
    BlasThreads.acquire()
    BlasThreads.release()
    assert libs == [[2], [4]] and made == [1]  # None: left alone


class _NumpyBlas:
    """The thread count of NumPy's BLAS, read and set through threadpoolctl — picked by
    its file: another OpenBLAS may share its prefix (OpenCV's wheel bundles a one-thread
    ``libopenblas``; which of the two came first in a prefix selection depended on the
    import order, and the test read OpenCV's count)."""

    def __init__(self, info: dict) -> None:
        self.filepath = info["filepath"]

    def _pool(self):
        return ThreadpoolController().select(filepath=self.filepath)

    def get(self) -> int:
        return int(self._pool().info()[0]["num_threads"])

    def set(self, n: int) -> None:
        self._pool().limit(limits=int(n))


def _numpy_blas() -> _NumpyBlas:
    libs = [i for i in ThreadpoolController().info() if i["user_api"] == "blas"]
    mine = [i for i in libs if "numpy" in i["filepath"]] or libs
    if not mine:
        pytest.skip("no BLAS threadpoolctl can set is loaded in this process")
    return _NumpyBlas(mine[0])


@pytest.fixture(scope="module")
def plant():
    return generate_scene("plant", None, size=20_000, seed=0)


def _click_and_prompt(sc):
    seg = Graph3DSegmenter()
    s = Session.open(sc.scene, sc.cameras, SessionConfig(render_scale=0.5), seg, "cpu")
    assert s.wait_warm_up(120)
    threads = _numpy_blas().get()
    a = s.anchors[0]
    ys, xs = np.nonzero((a.buffers.alpha > 0.9) & (a.buffers.D_med > 0))
    k = len(xs) // 2
    v = s.click(a.index, (xs[k] + 0.5, ys[k] + 0.5))
    prev = s.prompt(v)
    b = v.buffers
    out = (v.camera.w2c, b.rgb, b.D_med, b.D_min, b.D_max, b.N_samp, prev.masks, prev.scores)
    out += (seg.last_cut.selected, seg.last_cut.cut.potential)
    s.close()
    return threads, out


def test_session_results_are_the_same_with_one_and_two_blas_threads(plant, monkeypatch):
    lib = _numpy_blas()
    before = lib.get()
    # sessions other tests left open hold the count: this test's own from zero
    monkeypatch.setattr(BlasThreads, "_users", 0)
    monkeypatch.setattr(BlasThreads, "_limiter", None)
    lib.set(2)
    try:
        x = np.random.default_rng(0).normal(size=400_003)
        y = x @ x
        lib.set(1)
        if x @ x == y:  # the threaded ddot rounds by thread count here (the check can fail)
            pytest.skip("this BLAS gives a threaded ddot the same bits")
        lib.set(2)
        monkeypatch.setattr(blas_threads, "SESSION_BLAS_THREADS", None)
        n2, two = _click_and_prompt(plant)
        monkeypatch.setattr(blas_threads, "SESSION_BLAS_THREADS", 1)
        n1, one = _click_and_prompt(plant)
        assert (n2, n1) == (2, 1)  # the sessions ran with two and with one thread
        assert lib.get() == 2  # restored at close
        for a, b in zip(two, one, strict=True):
            assert np.array_equal(a, b)
    finally:
        lib.set(before)


def test_the_walk_solver_on_a_large_graph_is_the_same_with_one_and_two_threads():
    """graph3d's solve (two-level PCG) of a 40k-voxel lattice Laplacian — above the size
    where OpenBLAS threads a ``ddot`` — gives the same bits with one and two threads (its
    inner products are NumPy's sums; a BLAS ``u @ v`` there fails this)."""
    from scipy import sparse

    from divas_engine.segment.graph3d.config import Graph3DConfig
    from divas_engine.segment.graph3d.walk_solver import solve_walk

    lib = _numpy_blas()
    before = lib.get()
    g = 34
    cells = np.stack(np.meshgrid(*[np.arange(g)] * 3, indexing="ij"), -1).reshape(-1, 3)
    n = len(cells)
    idx = np.arange(n).reshape(g, g, g)
    rng = np.random.default_rng(4)
    pairs = [
        np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1),
        np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
        np.stack([idx[:, :, :-1].ravel(), idx[:, :, 1:].ravel()], 1),
    ]
    e = np.concatenate(pairs)
    w = rng.uniform(0.01, 1.0, len(e))
    wm = sparse.csr_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])))
    deg = np.asarray(wm.sum(axis=1)).ravel()
    a = (sparse.diags(deg * 1.001) - wm).tocsr()
    b = rng.uniform(0.0, 1.0, n)
    cfg = Graph3DConfig()
    try:
        out = []
        for threads in (2, 1):
            lib.set(threads)
            out.append(solve_walk(a, b, a.diagonal(), np.zeros(n), cells, cfg))
        assert np.array_equal(out[0], out[1])
    finally:
        lib.set(before)

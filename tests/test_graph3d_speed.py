"""The 3D graph segmenter's fast paths (the cost per prompt) give the reference
results: the walk's conjugate gradients are SciPy's bit for bit, and the masks rendered
in the selection's window with only the surfels in front of it are the dense full-image
render's."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse.linalg import LinearOperator, cg, spsolve

from divas_engine.camera import Camera
from divas_engine.render.config import RenderConfig
from divas_engine.render.nerf_renderer import NerfRenderer
from divas_engine.render.surfel_renderer import SurfelRenderer
from divas_engine.segment import Graph3DSegmenter, SceneBinding
from divas_engine.segment.graph3d import Seeds
from divas_engine.segment.graph3d import segmenter as sm
from divas_engine.segment.graph3d.config import Graph3DConfig, WalkSolver
from divas_engine.segment.graph3d.cut import _laplacian
from divas_engine.segment.graph3d.primitives import ScenePrimitives
from divas_engine.segment.graph3d.render_box import WHOLE, screen_box
from divas_engine.segment.graph3d.voxel_graph import build_voxel_graph
from divas_engine.segment.graph3d.walk_solver import _pcg, solve_walk
from tests.graph3d_cases import grid_ball_and_box, touching_boxes

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def boxes():
    return touching_boxes()


def _camera() -> Camera:
    return Camera.look_at(
        np.array([0.5, -1.2, 0.7]),
        np.array([0.0, 0.0, 0.1]),
        np.array([0.0, 0.0, 1.0]),
        width=200,
        height=150,
        fx=260.0,
    )


def _walk_system(case, click):
    """The walk's system on a real voxel graph (seed at ``click``, the rim a sink)."""
    cfg = Graph3DConfig()
    prims = ScenePrimitives.from_scene(case.scene, cfg.min_opacity)
    g = build_voxel_graph(prims, np.asarray(click), 0.3, cfg)
    wmat, deg = _laplacian(g)
    pos = np.zeros(len(g), bool)
    pos[g.node_of_points(np.asarray(click)[None])] = True
    fi = np.flatnonzero(~(pos | g.rim) & (deg > 0))
    b = cfg.leak * deg[fi] + np.asarray(wmat[fi][:, np.flatnonzero(g.rim)].sum(axis=1)).ravel()
    diag = deg[fi] * (1.0 + cfg.leak)
    a = (sparse.diags(diag) - wmat[fi][:, fi]).tocsr()
    return a, b, diag, np.clip(b / diag, 0.0, 1.0), g.cell[fi], cfg


@pytest.mark.parametrize("maxiter", [400, 7])
def test_walk_cg_follows_scipys_cg(boxes, maxiter):
    """The default walk solver takes SciPy's Jacobi-preconditioned ``cg`` steps: capped
    early, the same iterate to rounding; run to the tolerance, a solution as good (its
    inner products are pairwise sums, not BLAS ``ddot``, so the bits differ)."""
    a, b, diag, x0, _, cfg = _walk_system(boxes, [0.12, -0.12, 0.1])
    pre = LinearOperator(a.shape, matvec=lambda r: r / diag, dtype=np.float64)
    ref, info = cg(a, b, x0=x0, rtol=cfg.cg_tol, maxiter=maxiter, M=pre)
    assert (info == 0) == (maxiter == 400) and len(b) > 1000
    got = _pcg(a, b, diag, x0, cfg.cg_tol, maxiter)
    if maxiter == 7:
        assert np.allclose(got, ref, rtol=0, atol=1e-9)
    else:
        tol = cfg.cg_tol * np.linalg.norm(b)
        assert np.linalg.norm(b - a @ got) < tol and np.linalg.norm(b - a @ ref) < tol


_WALK_IN_A_PROCESS = """
import sys, numpy as np
from scipy import sparse
from divas_engine.segment.graph3d.walk_solver import _pcg
d = np.load(sys.argv[1])
a = sparse.csr_matrix((d["data"], d["indices"], d["indptr"]), shape=tuple(d["shape"]))
np.save(sys.argv[2], _pcg(a, d["b"], d["diag"], d["x0"], 1e-5, 400))
"""


def test_walk_cg_gives_the_same_bits_whatever_the_blas_threads(tmp_path):
    """A 60k-unknown walk system with a 1e-5 leak (badly conditioned, as on near-islands):
    the potentials are bit-identical with one BLAS thread and with two — BLAS ``ddot``
    splits long dots across threads, which made the default cut depend on the core count."""
    import subprocess
    import sys

    rng = np.random.default_rng(3)
    n = 60_000
    i = rng.integers(0, n, 4 * n)
    j = np.minimum(i + rng.integers(1, 40, 4 * n), n - 1)
    w = 10.0 ** rng.uniform(-4, 0, 4 * n)
    wm = sparse.coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    wm = wm + wm.T
    deg = np.asarray(wm.sum(axis=1)).ravel() + 1e-3
    diag = deg * (1 + 1e-5)
    a = (sparse.diags(diag) - wm).tocsr()
    b = 1e-5 * deg
    b[rng.integers(0, n, 50)] += deg[:50]
    sysfile = tmp_path / "walk.npz"
    np.savez(
        sysfile,
        data=a.data,
        indices=a.indices,
        indptr=a.indptr,
        shape=a.shape,
        b=b,
        diag=diag,
        x0=np.clip(b / diag, 0, 1),
    )
    out = []
    for threads in ("1", "2"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS=threads, OMP_NUM_THREADS=threads)
        res = tmp_path / f"u{threads}.npy"
        subprocess.run(
            [sys.executable, "-c", _WALK_IN_A_PROCESS, str(sysfile), str(res)],
            env=env,
            check=True,
            cwd=REPO,
        )
        out.append(np.load(res))
    assert np.array_equal(out[0], out[1])
    assert np.abs(out[0]).max() > 0


def test_two_level_walk_solver_reaches_the_solution(boxes):
    """The two-level preconditioned CG meets the tolerance within a cap of 40 steps (the
    Jacobi CG does not) and lands on the direct solve's potentials."""
    a, b, diag, x0, cells, cfg = _walk_system(boxes, [0.12, -0.12, 0.1])
    exact = spsolve(a.tocsc(), b)
    capped = replace(cfg, cg_maxiter=40)
    two = solve_walk(a, b, diag, x0, cells, replace(capped, walk_solver=WalkSolver.TWO_LEVEL))
    jac = solve_walk(a, b, diag, x0, cells, replace(capped, walk_solver=WalkSolver.JACOBI_CG))
    tol = cfg.cg_tol * np.linalg.norm(b)
    assert np.linalg.norm(a @ two - b) < tol < np.linalg.norm(a @ jac - b)
    assert np.abs(two - exact).max() < 1e-3 * np.abs(exact).max()


@pytest.mark.parametrize("alpha_min", [1.0 / 255.0, 1e-20])
def test_fast_masks_are_the_dense_full_render(boxes, alpha_min, monkeypatch):
    """The three masks of a cut, rendered in the selection's window with only the
    surfels that blend before it, equal the dense render of the whole view; with
    footprints wider than the window's bound assumes (α_min 1e-20: 9.6 σ, more than its
    4 σ and margin) the window's border shows coverage and the whole view is rendered
    instead — still equal."""
    seen = []
    border = sm._border_shows
    monkeypatch.setattr(sm, "_border_shows", lambda c, b: seen.append(border(c, b)) or seen[-1])
    wide = alpha_min < 1e-3
    cam = _camera()
    r = SurfelRenderer(boxes.scene, device="cpu", config=RenderConfig(alpha_min=alpha_min))
    bind = SceneBinding(boxes.scene, r.render_values)
    seg = Graph3DSegmenter(binding=bind)
    rc = seg.cut(Seeds(np.array([[0.12, -0.12, 0.1]]), np.zeros((0, 3))))
    assert rc.selected.any()
    seg.fast_masks = False
    ref = seg.render_masks(cam, rc.selected)
    seg.fast_masks = True
    assert np.array_equal(seg.render_masks(cam, rc.selected), ref)  # window, dense
    seg.bind_scene(SceneBinding(boxes.scene, r.render_values, render_sparse=r.render_values_sparse))
    assert np.array_equal(seg.render_masks(cam, rc.selected), ref)  # window, sparse
    prims = seg.primitives()
    cols = rc.selected.any(axis=0)
    box = screen_box(cam, prims.points[cols], prims.reach_of(cols), 4.0)
    assert box not in (None, WHOLE)
    x0, y0, x1, y1 = box
    assert (x1 - x0) * (y1 - y0) < 0.6 * cam.width * cam.height  # a real window
    assert (ref.max(axis=0) > 0.5).any()
    assert seen == [wide, wide]  # the border check: the fallback exactly when needed


def test_screen_box_of_nothing_and_of_a_ball_at_the_camera():
    cam = _camera()
    p = np.array([[0.0, 0.0, 0.1]])
    assert screen_box(cam, p[:0], np.zeros(0), 4.0) is None
    eye = cam.c2w[:3, 3]
    assert screen_box(cam, eye[None], np.array([0.1]), 4.0) == WHOLE
    behind = eye - 2.0 * cam.c2w[:3, 2]
    assert screen_box(cam, behind[None], np.array([0.1]), 4.0) is None


def test_fast_masks_of_a_density_grid_are_the_dense_render():
    """A NeRF grid: the masks rendered in the selection's window (ray-marched, no sparse
    path) equal the whole view's render up to the crop's float32 ray rounding, and the
    window is smaller than the view."""
    case = grid_ball_and_box()
    cam = Camera.look_at(
        np.array([0.0, -1.4, 0.8]),
        np.array([0.0, 0.0, 0.2]),
        np.array([0.0, 0.0, 1.0]),
        width=160,
        height=120,
        fx=200.0,
    )
    r = NerfRenderer(case.grid, device="cpu")
    seg = Graph3DSegmenter(binding=SceneBinding(case.grid, r.render_values))
    rc = seg.cut(Seeds(np.array([[0.0, 0.0, 0.36]]), np.zeros((0, 3))))
    prims = seg.primitives()
    cols = rc.selected.any(axis=0)
    x0, y0, x1, y1 = screen_box(cam, prims.points[cols], prims.reach_of(cols), 4.0)
    assert (x1 - x0) * (y1 - y0) < 0.5 * cam.width * cam.height
    seg.fast_masks = False
    ref = seg.render_masks(cam, rc.selected)
    seg.fast_masks = True
    fast = seg.render_masks(cam, rc.selected)
    assert (ref.max(axis=0) > 0.5).any() and np.abs(fast - ref).max() < 1e-4

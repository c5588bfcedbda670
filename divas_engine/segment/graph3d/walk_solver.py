"""The random walk's linear system (:mod:`.cut` step 1) and its two solvers.

``A u = b`` with ``A = (1 + λ) D_U − W_UU`` (SPD) over the free voxels U.

* :attr:`WalkSolver.TWO_LEVEL` (default): conjugate gradients with a two-level additive
  preconditioner over aggregates of ``_AGGREGATE³`` cells (sparse LU of the coarse
  system): tens of steps, and the tolerance is met on near-islands too.
* :attr:`WalkSolver.JACOBI_CG`: the same CG with the Jacobi preconditioner; on a
  near-island it stops at the step cap with the potentials still near its starting
  guess there (such a pocket then keeps ``x`` ≈ 1 and is swept in with the object).

Both: SciPy ``cg``'s steps in its order but every inner product NumPy's pairwise sum
(:func:`_dot`), so the rounding does not depend on the machine's core count.

Conditioning, stopping rule and the coarse level in full: docs/design-notes.md.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import splu

from .config import Graph3DConfig, WalkSolver

__all__ = ["WalkSolver", "solve_walk"]

_AGGREGATE = 2  # voxel cells per aggregate side (two-level preconditioner)


def solve_walk(
    a: sparse.csr_matrix,
    b: np.ndarray,
    diag: np.ndarray,
    x0: np.ndarray,
    cells: np.ndarray,
    config: Graph3DConfig,
) -> np.ndarray:
    """``u`` of ``a u = b`` from ``x0``; ``diag = diag a``; ``cells [n,3]`` the free
    voxels' integer cells (the two-level aggregates)."""
    pre = None
    if WalkSolver(config.walk_solver) == WalkSolver.TWO_LEVEL and len(b) > 1:
        pre = _two_level(a, diag, cells)
    return _pcg(a, b, diag, x0, config.cg_tol, config.cg_maxiter, pre)


def _two_level(a: sparse.csr_matrix, diag: np.ndarray, cells: np.ndarray):
    """``r -> r / diag + P A_c⁻¹ Pᵀ r`` (docs/design-notes.md)."""
    c = np.asarray(cells, np.int64) // _AGGREGATE
    c -= c.min(axis=0)
    span = c.max(axis=0) + 1
    _, agg = np.unique(c[:, 0] + span[0] * (c[:, 1] + span[1] * c[:, 2]), return_inverse=True)
    m = int(agg.max()) + 1
    p = sparse.csr_matrix((np.ones(len(agg)), (np.arange(len(agg)), agg)), shape=(len(agg), m))
    pt = p.T.tocsr()
    lu = splu((pt @ a @ p).tocsc())
    return lambda r: r / diag + p @ lu.solve(pt @ r)


def _dot(u: np.ndarray, v: np.ndarray, scratch: np.ndarray) -> float:
    """``u·v`` as NumPy's pairwise sum of the products: one thread, the same bits on
    every machine with this NumPy (BLAS ``ddot`` is threaded and rounds by core count)."""
    return float(np.add.reduce(np.multiply(u, v, out=scratch)))


def _pcg(a, b, diag, x, rtol: float, maxiter: int, pre=None) -> np.ndarray:
    """Preconditioned CG, SciPy ``cg``'s operations in its order (``pre`` None: Jacobi,
    ``r / diag``), the inner products by :func:`_dot`; ``‖r‖`` as ``sqrt(r·r)`` and the
    updates in place."""
    scratch = np.empty_like(b)
    atol = rtol * math.sqrt(_dot(b, b, scratch))
    if atol == 0.0:
        return b
    x = x.copy()
    r = b - a @ x if x.any() else b.copy()
    rho_prev, p = 1.0, np.empty_like(r)
    z, step = np.empty_like(r), np.empty_like(r)
    for it in range(maxiter):
        if math.sqrt(_dot(r, r, scratch)) < atol:
            break
        if pre is None:
            np.divide(r, diag, out=z)
        else:
            z = pre(r)
        rho = _dot(r, z, scratch)
        if it > 0:
            p *= rho / rho_prev
            p += z
        else:
            p[:] = z
        q = a @ p
        alpha = rho / _dot(p, q, scratch)
        x += np.multiply(alpha, p, out=step)
        r -= np.multiply(alpha, q, out=step)
        rho_prev = rho
    return x

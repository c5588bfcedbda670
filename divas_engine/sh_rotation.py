"""Real spherical harmonics of Gaussian-splat colour (degrees 0–3) and their rotation.

The basis and sign convention are the 3DGS reference code's (``kernels/sh.py`` evaluates
the same one on the device): ``colour(d) = 0.5 + Σ_k Y_k(d) c_k`` for a unit direction
``d`` from the camera centre to the splat, ``Y_0 = C0`` and, for k ≥ 1, the products of
constants and monomials of ``d = (x, y, z)`` in :data:`SH_MONOMIALS`.

Rotating a scene by ``R`` must rotate every splat's colour function with it: the new
coefficients ``c'`` satisfy ``Σ Y_k(d) c'_k = Σ Y_k(Rᵀ d) c_k`` for every ``d``. Each band
l spans a rotation-invariant space, so ``c'_l = D_l(R) c_l`` for one ``(2l+1)²`` matrix per
band (:func:`sh_rotation_matrices`). ``D_l`` is found without Wigner formulas: evaluate
the band's basis at a fixed set of well-spread directions ``U`` (more than 2l+1) and at
``Rᵀ U``, then solve ``Y_l(U) D_l = Y_l(Rᵀ U)`` in the least-squares sense — exact up to
float rounding because both sides lie in the band's span. The DC term (l = 0) never
changes.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SH_C0",
    "SH_MONOMIALS",
    "sh_basis",
    "eval_sh",
    "sh_rotation_matrices",
    "rotate_sh",
]

SH_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)

#: ``Y_k(x, y, z) = Σ coef · x^a y^b z^c`` for k = 1 … 15, as ``(coef, a, b, c)`` terms.
SH_MONOMIALS: tuple[tuple[tuple[float, int, int, int], ...], ...] = (
    ((-_C1, 0, 1, 0),),
    ((_C1, 0, 0, 1),),
    ((-_C1, 1, 0, 0),),
    ((_C2[0], 1, 1, 0),),
    ((_C2[1], 0, 1, 1),),
    ((2 * _C2[2], 0, 0, 2), (-_C2[2], 2, 0, 0), (-_C2[2], 0, 2, 0)),
    ((_C2[3], 1, 0, 1),),
    ((_C2[4], 2, 0, 0), (-_C2[4], 0, 2, 0)),
    ((3 * _C3[0], 2, 1, 0), (-_C3[0], 0, 3, 0)),
    ((_C3[1], 1, 1, 1),),
    ((4 * _C3[2], 0, 1, 2), (-_C3[2], 2, 1, 0), (-_C3[2], 0, 3, 0)),
    ((2 * _C3[3], 0, 0, 3), (-3 * _C3[3], 2, 0, 1), (-3 * _C3[3], 0, 2, 1)),
    ((4 * _C3[4], 1, 0, 2), (-_C3[4], 3, 0, 0), (-_C3[4], 1, 2, 0)),
    ((_C3[5], 2, 0, 1), (-_C3[5], 0, 2, 1)),
    ((_C3[6], 3, 0, 0), (-3 * _C3[6], 1, 2, 0)),
)


def _check_degree(degree: int) -> int:
    if not 0 <= int(degree) <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return int(degree)


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """``[M, (degree+1)²]`` basis values ``Y_k(d)`` at unit directions ``dirs [M,3]``."""
    degree = _check_degree(degree)
    d = np.asarray(dirs, np.float64).reshape(-1, 3)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = np.empty((len(d), (degree + 1) ** 2))
    out[:, 0] = SH_C0
    for k in range(1, (degree + 1) ** 2):
        out[:, k] = sum(c * x**a * y**b * z**e for c, a, b, e in SH_MONOMIALS[k - 1])
    return out


def eval_sh(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """``[N,3]`` colour ``0.5 + Σ_k Y_k(d_i) sh[i,k]`` (unclamped) of ``sh [N,K,3]`` seen
    along unit directions ``dirs [N,3]``."""
    sh = np.asarray(sh, np.float64)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1
    if (degree + 1) ** 2 != sh.shape[1]:
        raise ValueError(f"sh has {sh.shape[1]} coefficients, not (degree+1)^2")
    y = sh_basis(dirs, degree)
    return 0.5 + np.einsum("nk,nkc->nc", y, sh)


def _fibonacci_dirs(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


_SAMPLE_DIRS = _fibonacci_dirs(64)


def _check_rotation(rotation: np.ndarray) -> np.ndarray:
    """A 3×3 orthogonal matrix; a mirror (det −1) is allowed: each real SH band is
    invariant under every orthogonal map, so its ``D_l`` exists the same way."""
    r = np.asarray(rotation, np.float64)
    if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-6):
        raise ValueError("rotation must be a 3x3 orthonormal matrix")
    return r


def sh_rotation_matrices(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """``[D_1, …, D_degree]``: band l's ``(2l+1)×(2l+1)`` matrix with ``c'_l = D_l c_l``
    for a scene rotated by ``rotation`` (module docstring)."""
    degree = _check_degree(degree)
    r = _check_rotation(rotation)
    y_u = sh_basis(_SAMPLE_DIRS, degree)
    y_ru = sh_basis(_SAMPLE_DIRS @ r, degree)  # rows: Y(Rᵀ u)
    out = []
    for band in range(1, degree + 1):
        cols = slice(band * band, (band + 1) ** 2)
        d, *_ = np.linalg.lstsq(y_u[:, cols], y_ru[:, cols], rcond=None)
        out.append(d)
    return out


def rotate_sh(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``sh [N,K,3]`` (K = (degree+1)², DC first) of splats rotated by ``rotation``;
    same dtype as the input."""
    sh = np.asarray(sh)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1
    if (degree + 1) ** 2 != sh.shape[1]:
        raise ValueError(f"sh has {sh.shape[1]} coefficients, not (degree+1)^2")
    out = np.array(sh, copy=True)
    for band, d in enumerate(sh_rotation_matrices(rotation, degree), start=1):
        cols = slice(band * band, (band + 1) ** 2)
        out[:, cols] = np.einsum("ij,njc->nic", d, sh[:, cols].astype(np.float64))
    return out

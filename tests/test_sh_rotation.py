"""SH rotation (:mod:`divas_engine.sh_rotation`) against NumPy references.

The reference for the basis is the 3DGS evaluation written out term by term (the same
polynomials as ``kernels/sh.py``), independent of the monomial table the module and the
Blender display use. The rotation property: evaluating the rotated coefficients along
``d`` equals evaluating the originals along ``Rᵀ d``, per band, for degrees 1–3.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from divas_engine.sh_rotation import eval_sh, rotate_sh, sh_basis, sh_rotation_matrices


def _reference_colour(sh: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The 3DGS reference code's ``eval_sh`` (+0.5), spelled out."""
    c0, c1 = 0.28209479177387814, 0.4886025119029199
    c2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
          0.5462742152960396]  # fmt: skip
    c3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
          -0.4570457994644658, 1.445305721320277, -0.5900435899266435]  # fmt: skip
    deg = int(np.sqrt(sh.shape[1])) - 1
    x, y, z = (d[:, i : i + 1] for i in range(3))
    out = c0 * sh[:, 0]
    if deg > 0:
        out = out - c1 * y * sh[:, 1] + c1 * z * sh[:, 2] - c1 * x * sh[:, 3]
    if deg > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out = (
            out
            + c2[0] * xy * sh[:, 4]
            + c2[1] * yz * sh[:, 5]
            + c2[2] * (2 * zz - xx - yy) * sh[:, 6]
            + c2[3] * xz * sh[:, 7]
            + c2[4] * (xx - yy) * sh[:, 8]
        )
    if deg > 2:
        out = (
            out
            + c3[0] * y * (3 * xx - yy) * sh[:, 9]
            + c3[1] * xy * z * sh[:, 10]
            + c3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
            + c3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
            + c3[4] * x * (4 * zz - xx - yy) * sh[:, 13]
            + c3[5] * z * (xx - yy) * sh[:, 14]
            + c3[6] * x * (xx - 3 * yy) * sh[:, 15]
        )
    return out + 0.5


def _dirs(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_basis_matches_the_3dgs_reference(degree):
    rng = np.random.default_rng(degree)
    sh = rng.normal(size=(200, (degree + 1) ** 2, 3))
    d = _dirs(rng, 200)
    np.testing.assert_allclose(eval_sh(sh, d), _reference_colour(sh, d), rtol=1e-12, atol=1e-12)
    assert sh_basis(d, degree).shape == (200, (degree + 1) ** 2)


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotated_function_is_the_original_at_the_inverse_rotated_direction(degree, seed):
    rng = np.random.default_rng(10 * degree + seed)
    r = Rotation.random(random_state=seed).as_matrix()
    sh = rng.normal(size=(300, (degree + 1) ** 2, 3))
    d = _dirs(rng, 300)
    rotated = rotate_sh(sh, r)
    np.testing.assert_allclose(
        _reference_colour(rotated, d), _reference_colour(sh, d @ r), rtol=0, atol=1e-11
    )
    np.testing.assert_array_equal(rotated[:, 0], sh[:, 0])  # DC never changes
    # each band on its own (the others zero) stays in its band
    for band in range(1, degree + 1):
        only = np.zeros_like(sh)
        cols = slice(band * band, (band + 1) ** 2)
        only[:, cols] = sh[:, cols]
        out = rotate_sh(only, r)
        assert np.abs(np.delete(out, np.r_[cols], axis=1)).max() == 0.0
        np.testing.assert_allclose(
            _reference_colour(out, d), _reference_colour(only, d @ r), atol=1e-11
        )


def test_band_matrices_are_orthogonal_and_compose():
    a = Rotation.random(random_state=5).as_matrix()
    b = Rotation.random(random_state=6).as_matrix()
    for da, db, dab in zip(
        sh_rotation_matrices(a, 3), sh_rotation_matrices(b, 3), sh_rotation_matrices(a @ b, 3)
    ):
        np.testing.assert_allclose(da @ da.T, np.eye(len(da)), atol=1e-12)
        np.testing.assert_allclose(da @ db, dab, atol=1e-12)
    for d in sh_rotation_matrices(np.eye(3), 3):
        np.testing.assert_allclose(d, np.eye(len(d)), atol=1e-12)


def test_a_mirror_transforms_the_bands_too():
    m = np.diag([1.0, -1.0, 1.0])
    rng = np.random.default_rng(3)
    sh = rng.normal(size=(50, 16, 3))
    d = _dirs(rng, 50)
    np.testing.assert_allclose(
        _reference_colour(rotate_sh(sh, m), d), _reference_colour(sh, d @ m), atol=1e-11
    )


def test_bad_input():
    with pytest.raises(ValueError, match="orthonormal"):
        sh_rotation_matrices(np.diag([1.0, 2.0, 1.0]), 2)
    with pytest.raises(ValueError, match="degree"):
        sh_rotation_matrices(np.eye(3), 4)
    with pytest.raises(ValueError, match="coefficients"):
        rotate_sh(np.zeros((2, 5, 3)), np.eye(3))

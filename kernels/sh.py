"""Real spherical-harmonic colour of a splat, degrees 0..3 (the 3DGS/2DGS convention).

``colour = max(0, 0.5 + Σ_l Σ_m c_lm · Y_lm(d))`` with the standard real SH basis
(sign convention of the 3DGS reference code) and ``d`` the unit direction from the
camera centre to the splat mean. Coefficients are ``[N, K]`` ``vec3`` with
``K = (degree+1)^2``; index 0 is the DC term.
"""

from __future__ import annotations

import warp as wp

__all__ = ["eval_sh", "SH_C0", "SH_C1", "SH_C2", "SH_C3"]

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


@wp.func
def eval_sh(sh: wp.array2d(dtype=wp.vec3), i: int, degree: int, d: wp.vec3) -> wp.vec3:
    """Colour of splat ``i`` seen along unit direction ``d`` (clamped at 0)."""
    c = wp.float32(0.28209479177387814) * sh[i, 0]
    if degree > 0:
        x = d[0]
        y = d[1]
        z = d[2]
        c1 = wp.float32(0.4886025119029199)
        c = c - c1 * y * sh[i, 1] + c1 * z * sh[i, 2] - c1 * x * sh[i, 3]
        if degree > 1:
            xx = x * x
            yy = y * y
            zz = z * z
            xy = x * y
            yz = y * z
            xz = x * z
            c = (
                c
                + wp.float32(1.0925484305920792) * xy * sh[i, 4]
                + wp.float32(-1.0925484305920792) * yz * sh[i, 5]
                + wp.float32(0.31539156525252005) * (2.0 * zz - xx - yy) * sh[i, 6]
                + wp.float32(-1.0925484305920792) * xz * sh[i, 7]
                + wp.float32(0.5462742152960396) * (xx - yy) * sh[i, 8]
            )
            if degree > 2:
                c = (
                    c
                    + wp.float32(-0.5900435899266435) * y * (3.0 * xx - yy) * sh[i, 9]
                    + wp.float32(2.890611442640554) * xy * z * sh[i, 10]
                    + wp.float32(-0.4570457994644658) * y * (4.0 * zz - xx - yy) * sh[i, 11]
                    + wp.float32(0.3731763325901154)
                    * z
                    * (2.0 * zz - 3.0 * xx - 3.0 * yy)
                    * sh[i, 12]
                    + wp.float32(-0.4570457994644658) * x * (4.0 * zz - xx - yy) * sh[i, 13]
                    + wp.float32(1.445305721320277) * z * (xx - yy) * sh[i, 14]
                    + wp.float32(-0.5900435899266435) * x * (xx - 3.0 * yy) * sh[i, 15]
                )
    c = c + wp.vec3(0.5, 0.5, 0.5)
    return wp.vec3(wp.max(c[0], 0.0), wp.max(c[1], 0.0), wp.max(c[2], 0.0))

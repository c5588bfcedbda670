"""Helpers shared by the 2DGS and NeRF fusion kernels (paper Sec. 3.5, App. A, App. D).

Conventions: OpenCV camera (x right, y down, z forward), pixel ``(i, j)`` covers the
continuous square ``[i, i+1) × [j, j+1)`` with its centre at ``+0.5``; every depth
buffer is *planar* (camera z) and ``0`` where invalid.

Per-(voxel, view) contributions are produced in float32 and accumulated in
**int64 fixed point** (:data:`QSCALE` = 2⁵²): integer addition is associative and
exactly invertible, so incremental adds/undos, full re-fuses in any order, and CPU
vs CUDA launch orders all give bit-identical sums (see ``divas_engine.fusion.state``).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .integral_image import integral_images, sat_sum

__all__ = [
    "ViewData",
    "QSCALE",
    "vec3l",
    "project",
    "pixel_ray",
    "unproject",
    "footprint",
    "centre_pixel",
    "footprint_sums",
    "footprint_mean",
    "layered_exact",
    "pixel_depths",
    "quantize",
    "depth_gradient_factor",
    "upload_view_data",
]

#: Fixed-point scale of the accumulators. Contributions lie in [0, 1]; with ≤ 2^11
#: views the sums stay below 2^63. Resolution 2.2e-16 ≈ float64.
QSCALE = 4503599627370496.0  # 2**52
_QS = wp.constant(wp.float64(QSCALE))


@wp.struct
class ViewData:
    """One fused view on the device.

    ``rot``/``trans``: world→camera rotation (rows) and translation; ``origin``: camera
    centre; the ``*_d`` twins are float64 (per-voxel geometry runs in float64: the
    depth weight eq:gs-depthweight is ill-conditioned when the surface segment is
    thin, so float32 would set P's precision; per-pixel thin sweeps use float32).
    ``mask`` [H,W] refined probabilities; ``dmin``, ``dref`` (D_med for 2DGS,
    D_exp for NeRF), ``dmax`` [H,W] planar depths; ``nsamp`` [H,W] int32; ``sat_*``
    [H+1,W+1] integral images; ``pdg`` [H,W] depth-gradient factor π_dg; ``d_cam``
    the view's camera-to-target distance.
    """

    rot: wp.mat33
    trans: wp.vec3
    origin: wp.vec3
    fx: float
    fy: float
    cx: float
    cy: float
    rot_d: wp.mat33d
    trans_d: wp.vec3d
    origin_d: wp.vec3d
    fx_d: wp.float64
    fy_d: wp.float64
    cx_d: wp.float64
    cy_d: wp.float64
    width: int
    height: int
    d_cam: float
    mask: wp.array2d(dtype=float)
    dmin: wp.array2d(dtype=float)
    dref: wp.array2d(dtype=float)
    dmax: wp.array2d(dtype=float)
    nsamp: wp.array2d(dtype=wp.int32)
    sat_n: wp.array2d(dtype=wp.int64)
    sat_n2: wp.array2d(dtype=wp.int64)
    sat_pos: wp.array2d(dtype=wp.int32)
    pdg: wp.array2d(dtype=float)


vec3l = wp.types.vector(length=3, dtype=wp.int64)


@wp.func
def project(v: ViewData, x: wp.vec3d) -> wp.vec3d:
    """(u, v, z): continuous pixel coordinates and planar depth of world point ``x``."""
    pc = v.rot_d @ x + v.trans_d
    z = pc[2]
    return wp.vec3d(v.fx_d * pc[0] / z + v.cx_d, v.fy_d * pc[1] / z + v.cy_d, z)


@wp.func
def pixel_ray(v: ViewData, px: int, py: int) -> wp.vec4d:
    """World unit direction of the ray through the centre of pixel (px, py) and
    cos θ = ⟨ê_fwd, d̂⟩ (eq:planar-to-ray), packed as (dx, dy, dz, cos θ)."""
    half = wp.float64(0.5)
    dc = wp.vec3d(
        (wp.float64(px) + half - v.cx_d) / v.fx_d,
        (wp.float64(py) + half - v.cy_d) / v.fy_d,
        wp.float64(1.0),
    )
    inv = wp.float64(1.0) / wp.length(dc)
    d = wp.transpose(v.rot_d) @ (dc * inv)
    return wp.vec4d(d[0], d[1], d[2], inv)


@wp.func
def unproject(v: ViewData, px: int, py: int, z: float) -> wp.vec3:
    """World point at planar depth ``z`` behind the centre of pixel (px, py) (float32)."""
    pc = wp.vec3((float(px) + 0.5 - v.cx) / v.fx * z, (float(py) + 0.5 - v.cy) / v.fy * z, z)
    return wp.transpose(v.rot) @ pc + v.origin


@wp.func
def footprint(v: ViewData, xc: wp.vec3d, half: wp.vec3d, eps: float) -> wp.vec4i:
    """Pixel bounding box (x0, y0, x1, y1), inclusive and clipped to the image, of the 8
    projected voxel corners ``xc ± half`` (alg:gs-thin, alg:nerf-thin). x0 = −1 when a
    corner is not in front of the camera (z ≤ ε) or the box misses the image."""
    umin = wp.float64(1.0e30)
    vmin = wp.float64(1.0e30)
    umax = wp.float64(-1.0e30)
    vmax = wp.float64(-1.0e30)
    for j in range(8):
        sx = wp.float64(2 * (j & 1) - 1)
        sy = wp.float64(2 * ((j >> 1) & 1) - 1)
        sz = wp.float64(2 * ((j >> 2) & 1) - 1)
        q = project(v, xc + wp.vec3d(sx * half[0], sy * half[1], sz * half[2]))
        if q[2] <= wp.float64(eps):
            return wp.vec4i(-1, -1, -1, -1)
        umin = wp.min(umin, q[0])
        umax = wp.max(umax, q[0])
        vmin = wp.min(vmin, q[1])
        vmax = wp.max(vmax, q[1])
    w = wp.float64(v.width)
    h = wp.float64(v.height)
    zero = wp.float64(0.0)
    if umax < zero or vmax < zero or umin >= w or vmin >= h:
        return wp.vec4i(-1, -1, -1, -1)
    x0 = int(wp.floor(wp.max(umin, zero)))
    y0 = int(wp.floor(wp.max(vmin, zero)))
    x1 = wp.min(int(wp.floor(wp.min(umax, w))), v.width - 1)
    y1 = wp.min(int(wp.floor(wp.min(vmax, h))), v.height - 1)
    return wp.vec4i(x0, y0, x1, y1)


@wp.func
def centre_pixel(v: ViewData, q: wp.vec3d, eps: float) -> wp.vec2i:
    """Nearest pixel of a projected centre ``q = (u, v, z)``; (−1, −1) when out of frame
    (z ≤ ε or outside ``[0, W) × [0, H)``)."""
    zero = wp.float64(0.0)
    if q[2] <= wp.float64(eps):
        return wp.vec2i(-1, -1)
    if not (
        q[0] >= zero and q[0] < wp.float64(v.width) and q[1] >= zero and q[1] < wp.float64(v.height)
    ):
        return wp.vec2i(-1, -1)
    return wp.vec2i(
        wp.min(int(wp.floor(q[0])), v.width - 1), wp.min(int(wp.floor(q[1])), v.height - 1)
    )


@wp.func
def footprint_sums(v: ViewData, fp: wp.vec4i) -> vec3l:
    """(A_B, Σ N_samp, Σ N_samp²) over the footprint — exact, from the integral images."""
    area = wp.int64((fp[2] - fp[0] + 1) * (fp[3] - fp[1] + 1))
    return vec3l(
        area,
        sat_sum(v.sat_n, fp[0], fp[1], fp[2], fp[3]),
        sat_sum(v.sat_n2, fp[0], fp[1], fp[2], fp[3]),
    )


@wp.func
def footprint_mean(s: vec3l) -> float:
    """n̄_samp over the footprint."""
    return float(wp.float64(s[1]) / wp.float64(s[0]))


@wp.func
def layered_exact(n: int, s: vec3l) -> bool:
    """eq:seethrough ``n > n̄ + σ_n`` in exact integer arithmetic:
    ⟺ d = n·A − S₁ > 0 ∧ d² > A·S₂ − S₁² (σ_n is the population std over B).
    Exact while |d| < 3·10⁹ (e.g. N_samp ≤ 1400 on a 2-Mpixel footprint)."""
    d = wp.int64(n) * s[0] - s[1]
    if d <= wp.int64(0):
        return False
    return d * d > s[0] * s[2] - s[1] * s[1]


@wp.func
def pixel_depths(v: ViewData, px: int, py: int, eps: float) -> wp.vec3:
    """(d_min, d_ref, d_max) at a pixel; a missing d_min / d_max (< ε) falls back to d_ref."""
    dr = v.dref[py, px]
    dn = v.dmin[py, px]
    dx = v.dmax[py, px]
    if dn < eps:
        dn = dr
    if dx < eps:
        dx = dr
    return wp.vec3(dn, dr, dx)


@wp.func
def quantize(x: float) -> wp.int64:
    return wp.int64(wp.round(wp.float64(x) * _QS))


@wp.func
def _centre_depth(
    dmin: wp.array2d(dtype=float),
    dref: wp.array2d(dtype=float),
    dmax: wp.array2d(dtype=float),
    x: int,
    y: int,
    eps: float,
) -> float:
    """App. D centre depth ½(D_min + D_max) (with the ``pixel_depths`` fallback); 0 where
    the pixel has no surface (D_ref < ε)."""
    dr = dref[y, x]
    if dr < eps:
        return 0.0
    dn = dmin[y, x]
    dx = dmax[y, x]
    if dn < eps:
        dn = dr
    if dx < eps:
        dx = dr
    return 0.5 * (dn + dx)


@wp.kernel
def _depth_gradient_kernel(
    dmin: wp.array2d(dtype=float),
    dref: wp.array2d(dtype=float),
    dmax: wp.array2d(dtype=float),
    k: float,
    eps: float,
    out: wp.array2d(dtype=float),
):
    y, x = wp.tid()
    h = dref.shape[0]
    w = dref.shape[1]
    d = _centre_depth(dmin, dref, dmax, x, y, eps)
    if d < eps:
        out[y, x] = 0.0
        return
    xp = wp.min(x + 1, w - 1)
    xm = wp.max(x - 1, 0)
    yp = wp.min(y + 1, h - 1)
    ym = wp.max(y - 1, 0)
    gx = (
        _centre_depth(dmin, dref, dmax, xp, y, eps) - _centre_depth(dmin, dref, dmax, xm, y, eps)
    ) / (2.0 * d)
    gy = (
        _centre_depth(dmin, dref, dmax, x, yp, eps) - _centre_depth(dmin, dref, dmax, x, ym, eps)
    ) / (2.0 * d)
    out[y, x] = wp.exp(-k * (gx * gx + gy * gy))


def depth_gradient_factor(
    dmin: wp.array2d, dref: wp.array2d, dmax: wp.array2d, k: float, eps: float, device=None
) -> wp.array2d:
    """π_dg ``[H,W]`` (App. D; NOTES): relative central differences of the centre depth
    d = ½(D_min + D_max), G = g_x² + g_y², π_dg = exp(−k G). Border pixels replicate
    their edge neighbour; a pixel without a surface has π_dg = 0 and reads as depth 0
    when it is a neighbour (a silhouette is a depth discontinuity)."""
    device = device or dref.device
    out = wp.empty(dref.shape, dtype=float, device=device)
    wp.launch(
        _depth_gradient_kernel,
        dim=dref.shape,
        inputs=[dmin, dref, dmax, float(k), float(eps), out],
        device=device,
    )
    return out


def upload_view_data(
    w2c: np.ndarray,
    center: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    d_cam: float,
    mask: np.ndarray,
    d_min: np.ndarray,
    d_ref: np.ndarray,
    d_max: np.ndarray,
    n_samp: np.ndarray,
    *,
    mask_pos: float,
    k_dg: float,
    eps: float,
    device,
) -> ViewData:
    """Copy one view to ``device`` (:class:`ViewData`) and precompute its integral images
    and π_dg. ``intrinsics`` = ``(fx, fy, cx, cy)``; ``n_samp`` ``[H,W]`` int32; the image
    buffers ``[H,W]`` (converted to float32)."""
    fx, fy, cx, cy = (float(x) for x in intrinsics)
    w2c = np.asarray(w2c, dtype=np.float64)
    center = np.asarray(center, dtype=np.float64)

    def f32(a: np.ndarray) -> wp.array2d:
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=float, device=device)

    v = ViewData()
    v.rot = wp.mat33(*w2c[:3, :3].astype(np.float32).ravel())
    v.trans = wp.vec3(*w2c[:3, 3].astype(np.float32))
    v.origin = wp.vec3(*center.astype(np.float32))
    v.fx, v.fy, v.cx, v.cy = fx, fy, cx, cy
    v.rot_d = wp.mat33d(*w2c[:3, :3].ravel())
    v.trans_d = wp.vec3d(*w2c[:3, 3])
    v.origin_d = wp.vec3d(*center)
    v.fx_d, v.fy_d = wp.float64(fx), wp.float64(fy)
    v.cx_d, v.cy_d = wp.float64(cx), wp.float64(cy)
    h, w = np.shape(mask)
    v.width, v.height = int(w), int(h)
    v.d_cam = float(d_cam)
    v.mask = f32(mask)
    v.dmin, v.dref, v.dmax = f32(d_min), f32(d_ref), f32(d_max)
    v.nsamp = wp.array(np.ascontiguousarray(n_samp, dtype=np.int32), dtype=wp.int32, device=device)
    v.sat_n, v.sat_n2, v.sat_pos = integral_images(v.nsamp, v.mask, mask_pos, device=device)
    v.pdg = depth_gradient_factor(v.dmin, v.dref, v.dmax, k_dg, eps, device=device)
    return v

"""2DGS fusion kernel, one thread per active voxel and one view per launch
(alg:gs-fusion thick path, alg:gs-thin thin path; Sec. 3.5 eq:planar-to-ray …
eq:thin-tthin-gs).

Per (voxel x, view i) the kernel writes the view's contribution to eq:compact-fusion:
``kind = 1`` thick vote (num m·w, den w), ``kind = 2`` thin vote (num t, den 1) when
t ≥ τ_thin, else nothing. Accumulation is done by ``divas_kernels.fusion_accum``.
Per-voxel geometry is float64 (eq:gs-depthweight divides by a half-width that is a tiny
fraction of the depth); the per-pixel thin sweep is float32; ``layered`` is exact in integers.
The choices where the paper is silent (pixel sampling, gates, the ordered depth-weight
segment ``[d_min, max(d_max, d_ref)]``) are listed in docs/design-notes.md.
"""

from __future__ import annotations

import warp as wp

from ._launch import cpu_threads, launch_split
from .fusion_common import (
    ViewData,
    centre_pixel,
    footprint,
    footprint_mean,
    footprint_sums,
    layered_exact,
    pixel_depths,
    pixel_ray,
    project,
    unproject,
    vec3l,
)
from .integral_image import sat_sum_i32
from .occupancy import GridGeom, voxel_center_d

__all__ = ["GsParams", "gs_fuse_view"]


@wp.struct
class GsParams:
    """Kernel constants (see ``GsFusionConfig``); ``h`` = h_v."""

    h: float
    gamma: float
    beta: float
    gamma_st: float
    tau_thin: float
    behind_margin: float
    rho_cover: float
    rho_occ: float
    n_abs: int
    dist_gate: float
    rho_thin: float
    alpha1: float
    m_thick: float
    m_pos: float
    eps: float
    early_out: int


@wp.func
def gs_flags(layered: bool, dmin: float, dmed: float, d_cam: float, gamma_st: float) -> wp.vec3i:
    """(layered, see-through, trusted) of eq:seethrough / alg:gs-fusion."""
    seethru = dmed > gamma_st * d_cam
    trusted = dmin <= dmed
    return wp.vec3i(wp.where(layered, 1, 0), wp.where(seethru, 1, 0), wp.where(trusted, 1, 0))


@wp.func
def gs_depth_ok(xd: float, dmin: float, dmed: float, front: bool, tol: float) -> bool:
    """eq:asym-gate: one-sided against d_min when ``front``, two-sided against d_med."""
    if front:
        return xd - dmin <= tol
    return wp.abs(xd - dmed) <= tol


@wp.func
def gs_n_min(area: int, p: GsParams) -> int:
    """eq:thin-nmin, n_min = max(n_abs, ⌈ρ_occ A_B⌉); the 1e-4 slack keeps a decimal
    product such as 0.1·30 from rounding up to 4 in binary."""
    return wp.max(
        p.n_abs, int(wp.ceil(wp.float64(p.rho_occ) * wp.float64(area) - wp.float64(1.0e-4)))
    )


@wp.func
def gs_thin_score(
    v: ViewData, p: GsParams, xc: wp.vec3, xd: float, fp: wp.vec4i, sums: vec3l
) -> float:
    """alg:gs-thin: two-counter footprint coverage, t_x^i of eq:thin-tthin-gs."""
    mean = footprint_mean(sums)
    n_depth = int(0)
    n_md = int(0)
    m_max = float(0.0)
    d2 = float(1.0e30)
    for py in range(fp[1], fp[3] + 1):
        for px in range(fp[0], fp[2] + 1):
            dd = pixel_depths(v, px, py, p.eps)
            if dd[1] < p.eps:
                continue
            ni = int(v.nsamp[py, px])
            tol = p.gamma * p.h / (1.0 + p.beta * wp.max(float(ni) - mean, 0.0))  # eq:tightening
            layered = layered_exact(ni, sums)
            if gs_depth_ok(xd, dd[0], dd[1], layered, tol):
                n_depth += 1
                m = v.mask[py, px]
                if m > p.m_pos:
                    n_md += 1
                    m_max = wp.max(m_max, m)
                    z = wp.where(layered, dd[0], dd[1])  # layered → front hit
                    q = unproject(v, px, py, z)
                    d2 = wp.min(d2, wp.length_sq(q - xc))  # eq:thin-d2min
    if n_depth < gs_n_min(int(sums[0]), p):
        return 0.0
    cover = float(n_md) / float(n_depth)  # eq:gs-coverage
    gate = p.dist_gate * p.h
    if cover >= p.rho_cover and d2 <= gate * gate:
        return m_max
    return 0.0


@wp.func
def gs_contribution(v: ViewData, p: GsParams, xc: wp.vec3d, rho: float) -> wp.vec3:
    """(num, den, kind) of voxel ``xc`` in view ``v`` — alg:gs-fusion loop body.

    Per-voxel geometry (projection, footprint, ray, spatial gate, depth weight) runs in
    float64; the thin per-pixel sweep in float32."""
    none = wp.vec3(0.0, 0.0, 0.0)
    q = project(v, xc)
    pix = centre_pixel(v, q, p.eps)
    if pix[0] < 0:
        return none
    px = pix[0]
    py = pix[1]
    hd = wp.float64(p.h)
    half = wp.float64(0.5) * hd
    fp = footprint(v, xc, wp.vec3d(half, half, half), p.eps)
    if fp[0] < 0:
        return none
    sums = footprint_sums(v, fp)  # (A_B, Σn, Σn²) for n̄, σ_n
    mean = wp.float64(footprint_mean(sums))
    m = v.mask[py, px]
    dd = pixel_depths(v, px, py, p.eps)
    dmin = wp.float64(dd[0])
    dmed = wp.float64(dd[1])
    xd = q[2]
    ni = int(v.nsamp[py, px])
    surf = dd[1] >= p.eps
    fl = gs_flags(layered_exact(ni, sums), dd[0], dd[1], v.d_cam, p.gamma_st)
    trusted = fl[2] == 1
    front = (fl[0] == 1 or fl[1] == 1) and trusted
    if m >= p.m_thick and surf and trusted:  # thick entry; untrusted → thin
        r = pixel_ray(v, px, py)
        rd = wp.vec3d(r[0], r[1], r[2])
        dmin_r = dmin / r[3]  # eq:planar-to-ray
        dmed_r = dmed / r[3]
        dmax_r = wp.float64(dd[2]) / r[3]
        dref_r = wp.where(front, dmin_r, dmed_r)
        t_hat = wp.clamp(wp.dot(xc - v.origin_d, rd), dmin_r, dref_r)
        delta = wp.length(xc - (v.origin_d + t_hat * rd))
        tau_sp = hd * wp.float64(v.pdg[py, px])  # eq:gs-spatial
        e = wp.max(wp.float64(ni) - mean, wp.float64(0.0))
        tol = wp.float64(p.gamma) * hd / (wp.float64(1.0) + wp.float64(p.beta) * e)  # eq:tightening
        depth_ok = wp.abs(xd - dmed) <= tol  # eq:asym-gate
        if front:
            depth_ok = xd - dmin <= tol
        if delta <= tau_sp and depth_ok:
            # the segment [d_min, d_max] ordered to hold t̂'s range [d_min, d_ref] (decision
            # in the module docstring: 2DGS depths are per-primitive and not monotone)
            seg_hi = wp.max(dmax_r, wp.max(dref_r, dmin_r))
            d_ctr = wp.float64(0.5) * (dmin_r + seg_hi)
            d_hw = wp.max(wp.float64(0.5) * (seg_hi - dmin_r), wp.float64(p.eps))
            rr = (t_hat - d_ctr) / d_hw
            w = wp.exp(-wp.float64(p.alpha1) * rr * rr)  # eq:gs-depthweight
            return wp.vec3(float(wp.float64(m) * w), float(w), 1.0)
    if surf:  # eq:behind-gate
        d_surf = wp.where(trusted and fl[1] == 1, dmin, dmed)
        if xd > d_surf + wp.float64(p.behind_margin) * hd:
            return none
    if rho < p.rho_thin:
        return none
    if p.early_out != 0:  # exact: n_{m∧d} ≤ n_pos and acceptance needs n_{m∧d} ≥ ρ_cover n_min
        n_pos = sat_sum_i32(v.sat_pos, fp[0], fp[1], fp[2], fp[3])
        if float(n_pos) < p.rho_cover * float(gs_n_min(int(sums[0]), p)) * (1.0 - 1.0e-4):
            return none
    t = gs_thin_score(v, p, wp.vec3(xc), float(xd), fp, sums)
    if t >= p.tau_thin and t > 0.0:
        return wp.vec3(t, 1.0, 2.0)
    return none


@wp.kernel
def _gs_fuse_kernel(
    codes: wp.array(dtype=wp.int64),
    density: wp.array(dtype=float),
    geom: GridGeom,
    v: ViewData,
    p: GsParams,
    out_num: wp.array(dtype=float),
    out_den: wp.array(dtype=float),
    out_kind: wp.array(dtype=wp.uint8),
    base: int,
    stride: int,
):
    a = base + wp.tid() * stride
    xc = voxel_center_d(codes[a], geom)
    c = gs_contribution(v, p, xc, density[a])
    out_num[a] = c[0]
    out_den[a] = c[1]
    out_kind[a] = wp.uint8(int(c[2]))


def gs_fuse_view(
    codes: wp.array,
    density: wp.array,
    geom: GridGeom,
    view: ViewData,
    params: GsParams,
    out_num: wp.array,
    out_den: wp.array,
    out_kind: wp.array,
    device=None,
    threads: int | None = None,
) -> None:
    """Contribution of one view to every active voxel (dense ``[A]`` outputs; voxels are
    independent, so the CPU work is split over ``threads`` sub-launches, default all
    cores — bit-identical to one)."""
    device = device or codes.device
    n = codes.shape[0]
    for name, arr in (
        ("density", density),
        ("out_num", out_num),
        ("out_den", out_den),
        ("out_kind", out_kind),
    ):
        if arr.shape[0] != n:
            raise ValueError(f"gs_fuse_view: {name} has {arr.shape[0]} entries, expected {n}")
    if n:
        launch_split(
            _gs_fuse_kernel,
            n,
            [codes, density, geom, view, params, out_num, out_den, out_kind],
            wp.get_device(device),
            cpu_threads(threads),
        )

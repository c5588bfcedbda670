"""NeRF fusion kernel, one thread per active voxel (ρ ≥ ρ_thresh) and one view per
launch (alg:nerf-fusion thick path, alg:nerf-thin thin path; App. A eq:distance_cond …
eq:nerf-thin).

Writes the view's contribution to eq:compact-fusion: ``kind = 1`` thick vote (num m·w,
den w) or ``kind = 2`` thin vote (num t, den 1) when t ≥ τ_thin.

Choices where the paper is silent:
* NOTES: planar depths are converted to ray distances (eq:planar-to-ray) for the
  ray-segment clamp, τ_spatial's range term and the depth weight; the depth test
  |x_d − d_exp| compares planar with planar (same pixel ray);
* nearest-pixel sampling, ray through the centre of the projected pixel;
* the surface band is [min(d_min, d_max), max(d_min, d_max)]; a missing d_min/d_max
  (< ε) falls back to d_exp; a centre pixel with d_exp < ε cannot vote thick;
* a footprint pixel with d_exp < ε is never supportive but counts in N_pixels and in
  m_max (eq:nerf-counters takes the max over the whole footprint);
* Δx = the largest cell edge of the grid; the footprint uses the exact cell box;
* no contraction: the density grid is in world coordinates.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._launch import cpu_threads, launch_split
from .fusion_common import ViewData, centre_pixel, footprint, pixel_depths, pixel_ray, project
from .integral_image import sat_sum_i32

__all__ = ["NerfGridGeom", "NerfParams", "make_nerf_grid_geom", "nerf_fuse_view"]


@wp.struct
class NerfGridGeom:
    """Lattice of a DensityGrid: cell ``(ix, iy, iz)`` centred at ``origin + (i+½)·cell``;
    linear index ``(iz·ny + iy)·nx + ix``; ``dx`` = Δx."""

    origin: wp.vec3
    cell: wp.vec3
    origin_d: wp.vec3d
    cell_d: wp.vec3d
    nx: int
    ny: int
    dx: float


def make_nerf_grid_geom(
    origin: np.ndarray, cell: np.ndarray, shape_xyz: tuple[int, int, int], dx: float
) -> NerfGridGeom:
    """:class:`NerfGridGeom` of a lattice (``origin`` = AABB min, ``cell`` edges, float64)."""
    origin = np.asarray(origin, dtype=np.float64)
    cell = np.asarray(cell, dtype=np.float64)
    g = NerfGridGeom()
    g.origin = wp.vec3(*origin.astype(np.float32))
    g.cell = wp.vec3(*cell.astype(np.float32))
    g.origin_d = wp.vec3d(*origin)
    g.cell_d = wp.vec3d(*cell)
    g.nx, g.ny = int(shape_xyz[0]), int(shape_xyz[1])
    g.dx = float(dx)
    return g


@wp.struct
class NerfParams:
    """Kernel constants (see ``NerfFusionConfig``)."""

    gamma: float
    beta: float
    b_max: float
    lambda_range: float
    rho_thin: float
    rho_cover: float
    tau_thin: float
    alpha1: float
    m_thick: float
    m_thin_gate: float
    m_pos: float
    eps: float
    early_out: int


@wp.func
def nerf_center(lin: int, g: NerfGridGeom) -> wp.vec3d:
    """float64 world centre of linear cell ``lin``."""
    ix = lin % g.nx
    iy = (lin / g.nx) % g.ny
    iz = lin / (g.nx * g.ny)
    h = wp.float64(0.5)
    return g.origin_d + wp.cw_mul(
        wp.vec3d(wp.float64(ix) + h, wp.float64(iy) + h, wp.float64(iz) + h), g.cell_d
    )


@wp.func
def nerf_thin_score(v: ViewData, p: NerfParams, dx: float, xd: float, fp: wp.vec4i) -> float:
    """alg:nerf-thin: t_x^i of eq:nerf-thin."""
    n_valid = int(0)
    m_max = float(0.0)
    for py in range(fp[1], fp[3] + 1):
        for px in range(fp[0], fp[2] + 1):
            m = v.mask[py, px]
            m_max = wp.max(m_max, m)  # eq:nerf-counters
            d_exp = v.dref[py, px]
            if m > p.m_pos and d_exp >= p.eps:
                b = wp.min(p.beta * float(v.nsamp[py, px]), p.b_max)
                tol = (2.0 * p.gamma + b) * dx  # eq:nerf-thindepth
                if wp.abs(xd - d_exp) <= tol:  # eq:nerf-support
                    n_valid += 1
    n_pix = (fp[2] - fp[0] + 1) * (fp[3] - fp[1] + 1)
    if float(n_valid) / float(n_pix) >= p.rho_cover:  # eq:nerf-coverage
        return m_max
    return 0.0


@wp.func
def nerf_contribution(
    v: ViewData, p: NerfParams, g: NerfGridGeom, xc: wp.vec3d, rho: float
) -> wp.vec3:
    """(num, den, kind) of voxel ``xc`` in view ``v`` — alg:nerf-fusion loop body
    (per-voxel geometry in float64, the thin per-pixel sweep in float32)."""
    none = wp.vec3(0.0, 0.0, 0.0)
    q = project(v, xc)
    pix = centre_pixel(v, q, p.eps)
    if pix[0] < 0:
        return none
    px = pix[0]
    py = pix[1]
    xd = q[2]
    dx = wp.float64(g.dx)
    m = v.mask[py, px]
    if m >= p.m_thick:
        dd = pixel_depths(v, px, py, p.eps)
        if dd[1] >= p.eps:
            r = pixel_ray(v, px, py)
            rd = wp.vec3d(r[0], r[1], r[2])
            lo = wp.float64(wp.min(dd[0], dd[2])) / r[3]  # eq:planar-to-ray (NOTES)
            hi = wp.float64(wp.max(dd[0], dd[2])) / r[3]
            t_c = wp.clamp(wp.dot(xc - v.origin_d, rd), lo, hi)
            delta = wp.length(xc - (v.origin_d + t_c * rd))  # eq:distance_cond
            tau_sp = dx * wp.float64(v.pdg[py, px]) + wp.float64(p.lambda_range) * (
                hi - lo
            )  # eq:dist_tol
            b = wp.min(wp.float64(p.beta) * wp.float64(v.nsamp[py, px]), wp.float64(p.b_max))
            tau_d = (wp.float64(p.gamma) + b) * dx  # eq:depth_tol
            if delta <= tau_sp and wp.abs(xd - wp.float64(dd[1])) <= tau_d:  # eq:nerf-accept
                mu = wp.float64(0.5) * (lo + hi)
                hd = wp.max(wp.float64(0.5) * (hi - lo), wp.float64(p.eps))
                rr = wp.abs(t_c - mu) / hd
                w = wp.exp(-wp.float64(p.alpha1) * rr * rr)  # eq:nerf-vote
                return wp.vec3(float(wp.float64(m) * w), float(w), 1.0)
    if m > p.m_thin_gate and rho >= p.rho_thin:
        fp = footprint(v, xc, wp.float64(0.5) * g.cell_d, p.eps)
        if fp[0] < 0:
            return none
        if p.early_out != 0:  # exact: n_valid ≤ n_pos
            n_pos = sat_sum_i32(v.sat_pos, fp[0], fp[1], fp[2], fp[3])
            n_pix = float((fp[2] - fp[0] + 1) * (fp[3] - fp[1] + 1))
            if float(n_pos) < p.rho_cover * n_pix * (1.0 - 1.0e-4):
                return none
        t = nerf_thin_score(v, p, g.dx, float(xd), fp)
        if t >= p.tau_thin and t > 0.0:
            return wp.vec3(t, 1.0, 2.0)
    return none


@wp.kernel
def _nerf_fuse_kernel(
    index: wp.array(dtype=wp.int32),
    density: wp.array(dtype=float),
    g: NerfGridGeom,
    v: ViewData,
    p: NerfParams,
    out_num: wp.array(dtype=float),
    out_den: wp.array(dtype=float),
    out_kind: wp.array(dtype=wp.uint8),
    base: int,
    stride: int,
):
    a = base + wp.tid() * stride
    xc = nerf_center(int(index[a]), g)
    c = nerf_contribution(v, p, g, xc, density[a])
    out_num[a] = c[0]
    out_den[a] = c[1]
    out_kind[a] = wp.uint8(int(c[2]))


def nerf_fuse_view(
    index: wp.array,
    density: wp.array,
    geom: NerfGridGeom,
    view: ViewData,
    params: NerfParams,
    out_num: wp.array,
    out_den: wp.array,
    out_kind: wp.array,
    device=None,
    threads: int | None = None,
) -> None:
    """Contribution of one view to every active voxel (dense ``[A]`` outputs; voxels are
    independent, so the CPU work is split over ``threads`` sub-launches, default all
    cores — bit-identical to one)."""
    device = device or index.device
    n = index.shape[0]
    for name, arr in (
        ("density", density),
        ("out_num", out_num),
        ("out_den", out_den),
        ("out_kind", out_kind),
    ):
        if arr.shape[0] != n:
            raise ValueError(f"nerf_fuse_view: {name} has {arr.shape[0]} entries, expected {n}")
    if n:
        launch_split(
            _nerf_fuse_kernel,
            n,
            [index, density, geom, view, params, out_num, out_den, out_kind],
            wp.get_device(device),
            cpu_threads(threads),
        )

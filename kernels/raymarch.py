"""NeRF density-grid ray-marcher (Warp, CPU and CUDA).

Per pixel: the ray through the pixel centre is clipped to the grid AABB by the
slab test (and to the near plane), then cut into segments of length
``δ = step_scale · min(voxel edge)`` starting at the entry point (the last one
shorter, ending at the exit). Each segment is sampled at its midpoint:
trilinear density σ (cell-centred samples, clamp to edge), ``α_k = 1 − exp(−σ δ_k)``,
planar depth ``z_k = t_mid · cos θ``. Samples are composited front to back with
:mod:`divas_kernels.composite` (``N_samp`` anchored at ``D_max``; every sample with
``α > 0`` is blended, ``α ≥ 1/255`` ones are *contributing*); traversal stops once
``T < T_min``.

Exact empty-space skipping: a coarse grid holds, per block of ``B³`` cells, the
maximum density over the block's cells dilated by one cell (the trilinear
support of any point in the block). A sample in a zero block has σ = 0 exactly,
so the marcher jumps to the first sample past the block — same output as
visiting every sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from . import render_defaults as RD
from ._launch import cpu_threads, launch_split
from .composite import (
    ANCHOR_MAX,
    FLAG_DONE,
    BlendParams,
    PixelOut,
    blend_step,
    finish_pixel,
    state_init,
)

# forward only: no adjoint code (halves compile time)
wp.set_module_options({"enable_backward": False})

__all__ = ["GridBuffers", "upload_grid", "raymarch_grid", "MarchSettings", "occupancy_blocks"]


@dataclass
class MarchSettings:
    """Constants of one march (see :class:`divas_engine.render.RenderConfig`)."""

    tau_sig: float = RD.TAU_SIG
    tau_cw: float = RD.TAU_CW
    t_min: float = RD.T_MIN
    alpha_min: float = RD.ALPHA_MIN
    near: float = RD.NEAR
    step_scale: float = RD.NERF_STEP_SCALE
    threads: int | None = None


@wp.struct
class GridInfo:
    lo: wp.vec3  # AABB min
    hi: wp.vec3  # AABB max
    inv_vox: wp.vec3  # 1 / voxel edge per axis
    nx: int
    ny: int
    nz: int
    block: int  # B, cells per coarse block edge
    step: float  # δ, world units


@wp.struct
class MarchCamera:
    Rc: wp.mat33  # camera → world rotation
    center: wp.vec3
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    near: float


@dataclass
class GridBuffers:
    """A density grid on one device: ``density`` ``[D,H,W]``, optional ``rgb``
    ``[D,H,W,3]`` and the coarse occupancy ``occ`` ``[⌈D/B⌉,⌈H/B⌉,⌈W/B⌉]``."""

    density: wp.array
    rgb: wp.array | None
    occ: wp.array
    aabb: np.ndarray
    shape: tuple[int, int, int]
    block: int
    device: wp.context.Device


def occupancy_blocks(density: np.ndarray, block: int) -> np.ndarray:
    """Max density over each ``block³`` cell block dilated by one cell."""
    from scipy.ndimage import maximum_filter

    dil = maximum_filter(np.asarray(density, np.float32), size=3, mode="nearest")
    D, H, W = dil.shape
    pad = [(0, (-s) % block) for s in (D, H, W)]
    dil = np.pad(dil, pad, mode="edge")
    d, h, w = (s // block for s in dil.shape)
    return dil.reshape(d, block, h, block, w, block).max(axis=(1, 3, 5))


def upload_grid(
    density: np.ndarray, aabb: np.ndarray, rgb: np.ndarray | None, device, block: int = 8
) -> GridBuffers:
    """Copy a density grid (``[D,H,W]``, σ ≥ 0) and its optional RGB to ``device``."""
    density = np.ascontiguousarray(np.maximum(np.asarray(density, np.float32), 0.0))
    if density.ndim != 3 or min(density.shape) < 1:
        raise ValueError(f"upload_grid: density must be [D,H,W], got {density.shape}")
    aabb = np.asarray(aabb, np.float64).reshape(2, 3)
    if not np.all(aabb[1] > aabb[0]):
        raise ValueError(f"upload_grid: empty AABB {aabb.tolist()}")
    if rgb is not None and np.shape(rgb) != density.shape + (3,):
        raise ValueError(f"upload_grid: rgb must be {density.shape + (3,)}, got {np.shape(rgb)}")
    occ = occupancy_blocks(density, block)
    return GridBuffers(
        density=wp.array(density, dtype=float, device=device),
        rgb=None
        if rgb is None
        else wp.array(np.ascontiguousarray(rgb, np.float32), dtype=float, device=device),
        occ=wp.array(np.ascontiguousarray(occ), dtype=float, device=device),
        aabb=aabb,
        shape=density.shape,
        block=int(block),
        device=device,
    )


# --------------------------------------------------------------------------- funcs
@wp.func
def cell_coords(g: GridInfo, p: wp.vec3):
    """Trilinear corner indices (clamped) and weights of world point ``p``."""
    f = wp.cw_mul(p - g.lo, g.inv_vox) - wp.vec3(0.5, 0.5, 0.5)
    fx = wp.floor(f[0])
    fy = wp.floor(f[1])
    fz = wp.floor(f[2])
    x0 = int(fx)
    y0 = int(fy)
    z0 = int(fz)
    w = wp.vec3(f[0] - fx, f[1] - fy, f[2] - fz)
    return (
        wp.clamp(x0, 0, g.nx - 1),
        wp.clamp(x0 + 1, 0, g.nx - 1),
        wp.clamp(y0, 0, g.ny - 1),
        wp.clamp(y0 + 1, 0, g.ny - 1),
        wp.clamp(z0, 0, g.nz - 1),
        wp.clamp(z0 + 1, 0, g.nz - 1),
        w,
    )


@wp.func
def lerp3(
    a: wp.array3d(dtype=float), x0: int, x1: int, y0: int, y1: int, z0: int, z1: int, w: wp.vec3
) -> float:
    c00 = a[z0, y0, x0] * (1.0 - w[0]) + a[z0, y0, x1] * w[0]
    c01 = a[z0, y1, x0] * (1.0 - w[0]) + a[z0, y1, x1] * w[0]
    c10 = a[z1, y0, x0] * (1.0 - w[0]) + a[z1, y0, x1] * w[0]
    c11 = a[z1, y1, x0] * (1.0 - w[0]) + a[z1, y1, x1] * w[0]
    c0 = c00 * (1.0 - w[1]) + c01 * w[1]
    c1 = c10 * (1.0 - w[1]) + c11 * w[1]
    return c0 * (1.0 - w[2]) + c1 * w[2]


@wp.func
def lerp4(
    a: wp.array4d(dtype=float),
    x0: int,
    x1: int,
    y0: int,
    y1: int,
    z0: int,
    z1: int,
    w: wp.vec3,
    c: int,
) -> float:
    c00 = a[z0, y0, x0, c] * (1.0 - w[0]) + a[z0, y0, x1, c] * w[0]
    c01 = a[z0, y1, x0, c] * (1.0 - w[0]) + a[z0, y1, x1, c] * w[0]
    c10 = a[z1, y0, x0, c] * (1.0 - w[0]) + a[z1, y0, x1, c] * w[0]
    c11 = a[z1, y1, x0, c] * (1.0 - w[0]) + a[z1, y1, x1, c] * w[0]
    c0 = c00 * (1.0 - w[1]) + c01 * w[1]
    c1 = c10 * (1.0 - w[1]) + c11 * w[1]
    return c0 * (1.0 - w[2]) + c1 * w[2]


@wp.func
def one_minus_exp(x: float) -> float:
    """``1 − exp(−x)`` for ``x ≥ 0`` without float32 cancellation at small ``x``."""
    r = float(0.0)
    if x < 1.0e-3:
        r = x * (1.0 - 0.5 * x * (1.0 - x / 3.0))
    else:
        r = 1.0 - wp.exp(-x)
    return r


@wp.func
def slab(o: wp.vec3, d: wp.vec3, lo: wp.vec3, hi: wp.vec3, t0: float, t1: float):
    """Clip ``[t0, t1]`` to the box ``[lo, hi]`` along ``o + t d``."""
    a = t0
    b = t1
    for i in range(3):
        if wp.abs(d[i]) > 1.0e-12:
            ta = (lo[i] - o[i]) / d[i]
            tb = (hi[i] - o[i]) / d[i]
            a = wp.max(a, wp.min(ta, tb))
            b = wp.min(b, wp.max(ta, tb))
        elif o[i] < lo[i] or o[i] > hi[i]:
            b = -1.0
            a = 1.0
    return a, b


# --------------------------------------------------------------------------- kernel
@wp.kernel
def march_kernel(
    dens: wp.array3d(dtype=float),
    occ: wp.array3d(dtype=float),
    feat: wp.array4d(dtype=float),
    const_color: int,
    color: wp.vec3,
    g: GridInfo,
    cam: MarchCamera,
    bp: BlendParams,
    out: PixelOut,
    base: int,
    stride: int,
):
    """One pixel: march, composite, write the tuple (``feat`` ``[D,H,W,C]`` or constant)."""
    p = base + wp.tid() * stride
    x = p % cam.width
    y = p // cam.width
    rc = wp.vec3((float(x) + 0.5 - cam.cx) / cam.fx, (float(y) + 0.5 - cam.cy) / cam.fy, 1.0)
    nrm = wp.length(rc)
    cosv = 1.0 / nrm
    d = cam.Rc * (rc / nrm)
    o = cam.center
    t0, t1 = slab(o, d, g.lo, g.hi, cam.near * nrm, 1.0e30)
    s = state_init()
    nc = out.feat.shape[1]
    if t1 > t0:
        n = int(wp.ceil((t1 - t0) / g.step))
        bsz = wp.vec3(float(g.block), float(g.block), float(g.block))
        k = int(0)
        while k < n:
            ta = t0 + float(k) * g.step
            tb = wp.min(ta + g.step, t1)
            tm = 0.5 * (ta + tb)
            pos = o + tm * d
            q = wp.cw_mul(pos - g.lo, g.inv_vox)
            bx = wp.clamp(int(wp.floor(q[0] / bsz[0])), 0, occ.shape[2] - 1)
            by = wp.clamp(int(wp.floor(q[1] / bsz[1])), 0, occ.shape[1] - 1)
            bz = wp.clamp(int(wp.floor(q[2] / bsz[2])), 0, occ.shape[0] - 1)
            if occ[bz, by, bx] <= 0.0:
                # σ = 0 throughout this block: jump past its exit (never backwards)
                blo = g.lo + wp.cw_div(
                    wp.vec3(float(bx), float(by), float(bz)) * float(g.block), g.inv_vox
                )
                bhi = blo + wp.cw_div(bsz, g.inv_vox)
                ea, eb = slab(o, d, blo, bhi, -1.0e30, 1.0e30)
                kn = int(wp.ceil(wp.min((eb - t0) / g.step - 0.5, float(n)))) - 1
                k = wp.max(k + 1, kn)
            else:
                x0, x1, y0, y1, z0, z1, w = cell_coords(g, pos)
                sigma = lerp3(dens, x0, x1, y0, y1, z0, z1, w)
                alpha = one_minus_exp(sigma * (tb - ta))
                if alpha > 0.0:
                    s, wk = blend_step(s, alpha, tm * cosv, bp)
                    if const_color != 0:
                        for c in range(nc):
                            out.feat[p, c] = out.feat[p, c] + wk * color[c]
                    else:
                        for c in range(nc):
                            out.feat[p, c] = out.feat[p, c] + wk * lerp4(
                                feat, x0, x1, y0, y1, z0, z1, w, c
                            )
                    if (s.flags & FLAG_DONE) != 0:
                        break
                k += 1
    finish_pixel(s, p, out)


# --------------------------------------------------------------------------- wrapper
def raymarch_grid(
    buf: GridBuffers,
    c2w: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    settings: MarchSettings | None = None,
    values: np.ndarray | None = None,
    color=(0.8, 0.8, 0.8),
    background=(0.0, 0.0, 0.0),
) -> PixelOut:
    """March every pixel of a ``width × height`` OpenCV pinhole view (``c2w`` 4×4).

    Args:
        values: ``None`` → RGB (the grid's, else ``color``) over ``background``; else
            per-voxel ``[D,H,W]`` or ``[D,H,W,C]`` values composited with the same
            weights (no background).
    Returns: :class:`divas_kernels.composite.PixelOut` on ``buf.device``.
    """
    from .rasterize import alloc_pixel_out

    s = settings or MarchSettings()
    dev = buf.device
    W, H = int(width), int(height)
    if W <= 0 or H <= 0:
        raise ValueError(f"raymarch_grid: empty image {W}x{H}")
    D_, H_, W_ = buf.shape
    vox = (buf.aabb[1] - buf.aabb[0]) / np.array([W_, H_, D_], np.float64)
    g = GridInfo()
    g.lo, g.hi = wp.vec3(*buf.aabb[0].astype(np.float32)), wp.vec3(*buf.aabb[1].astype(np.float32))
    g.inv_vox = wp.vec3(*(1.0 / vox).astype(np.float32))
    g.nx, g.ny, g.nz, g.block = W_, H_, D_, buf.block
    g.step = float(s.step_scale * vox.min())
    cam = MarchCamera()
    c2w = np.asarray(c2w, np.float64)
    cam.Rc = wp.mat33(*c2w[:3, :3].astype(np.float32).ravel())
    cam.center = wp.vec3(*c2w[:3, 3].astype(np.float32))
    cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.near = (
        float(fx),
        float(fy),
        float(cx),
        float(cy),
        W,
        float(s.near),
    )
    bp = BlendParams()
    bp.tau_sig, bp.tau_cw, bp.t_min = float(s.tau_sig), float(s.tau_cw), float(s.t_min)
    bp.alpha_min, bp.anchor = float(s.alpha_min), ANCHOR_MAX
    with wp.ScopedDevice(dev):
        if values is None:
            C, bg = 3, np.asarray(background, np.float32).reshape(3)
            const = 1 if buf.rgb is None else 0
            feat = wp.zeros((1, 1, 1, 3), dtype=float) if buf.rgb is None else buf.rgb
        else:
            v = np.asarray(values, np.float32)
            if v.shape[:3] != buf.shape or v.ndim not in (3, 4):
                raise ValueError(
                    f"raymarch_grid: values must be {buf.shape} or {buf.shape}+(C,), got {v.shape}"
                )
            v = v.reshape(buf.shape + (-1,))
            C, bg, const = v.shape[3], np.zeros(v.shape[3], np.float32), 0
            feat = wp.array(np.ascontiguousarray(v), dtype=float)
        out = alloc_pixel_out(W * H, C, bg, dev)
        launch_split(
            march_kernel,
            W * H,
            [
                buf.density,
                buf.occ,
                feat,
                const,
                wp.vec3(*np.asarray(color, np.float32)),
                g,
                cam,
                bp,
                out,
            ],
            dev,
            cpu_threads(s.threads),
        )
    return out

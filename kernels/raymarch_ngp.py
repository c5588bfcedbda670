"""Ray-march an instant-ngp radiance network (Warp, CPU and CUDA).

Per pixel, the ray through the pixel centre (OpenCV camera, training frame) is taken into
instant-ngp's NeRF frame, clipped to the snapshot's box and the near plane, and marched like
instant-ngp's renderer (``nerf_device.cuh`` ``if_unoccupied_advance_to_next_occupied_voxel``):
it jumps out of the largest empty cascade cell where the occupancy is empty, else takes a step
``dt = STEPSIZE`` (``clamp(t·cone, STEPSIZE, MAX_CONE_STEPSIZE)`` for ``aabb_scale > 1``),
samples its midpoint, ``α = 1 − exp(−σ dt)``, and composites front to back with
:mod:`kernels.composite` (planar depths, training-frame units). Colour is evaluated where
``w ≥`` :data:`COLOR_MIN_WEIGHT`; per-voxel values are sampled trilinearly on the grid's
lattice. Step by step: docs/design-notes.md.
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
from .ngp_field import NgpNet, NgpNetBuffers, color_of, density_features
from .raymarch import GridInfo, MarchCamera, cell_coords, lerp4, one_minus_exp, slab

wp.set_module_options({"enable_backward": False})

__all__ = ["NgpMarchSettings", "NgpOccupancy", "upload_ngp_occupancy", "raymarch_ngp"]

#: samples lighter than this skip the colour network
COLOR_MIN_WEIGHT = 1.0e-4
MAX_ITERS = 1 << 16


@dataclass
class NgpMarchSettings:
    """Constants of one march (``step``/``cone``/``max_step`` in NeRF-frame units)."""

    step: float
    cone: float = 0.0
    max_step: float = 1.0
    tau_sig: float = RD.TAU_SIG
    tau_cw: float = RD.TAU_CW
    t_min: float = RD.T_MIN
    alpha_min: float = RD.ALPHA_MIN
    near: float = RD.NEAR
    threads: int | None = None


@wp.struct
class NgpMarch:
    scale: float  # training frame → NeRF frame
    offset: wp.vec3  # in training-frame axes
    ax: wp.vec3i  # NeRF axis i ← training axis ax[i]
    lo: wp.vec3  # march box (NeRF frame)
    hi: wp.vec3
    n_casc: int  # cascades the snapshot holds (sampling)
    n_levels: int  # occupancy levels (skipping)
    res: int
    step: float
    cone: float
    max_step: float


@dataclass
class NgpOccupancy:
    """``[L, R, R, R]`` uint8 occupancy (``[m, x, y, z]``) on a device: the snapshot's
    cascades then coarser max-pooled levels."""

    occ: wp.array
    n_cascades: int
    res: int


def upload_ngp_occupancy(occ: np.ndarray, device) -> NgpOccupancy:
    """Copy instant-ngp's cascade occupancy (already max-pooled into coarser cascades)."""
    a = np.ascontiguousarray(occ, np.uint8)
    if a.ndim != 4 or not (a.shape[1] == a.shape[2] == a.shape[3]):
        raise ValueError(f"upload_ngp_occupancy: expected [C, R, R, R], got {a.shape}")
    dev = wp.get_device(device)
    return NgpOccupancy(wp.array(a, dtype=wp.uint8, device=dev), a.shape[0], a.shape[1])


@wp.func
def to_ngp(g: NgpMarch, p: wp.vec3) -> wp.vec3:
    q = wp.vec3()
    for i in range(3):
        a = g.ax[i]
        q[i] = g.scale * p[a] + g.offset[a]
    return q


@wp.func
def to_world(g: NgpMarch, q: wp.vec3) -> wp.vec3:
    p = wp.vec3()
    for i in range(3):
        a = g.ax[i]
        p[a] = (q[i] - g.offset[a]) / g.scale
    return p


@wp.func
def mip_of(g: NgpMarch, pos: wp.vec3) -> int:
    """``mip_from_pos``: the finest cascade whose box ``0.5 ± 2^(m−1)`` holds ``pos``."""
    mx = wp.max(wp.abs(pos[0] - 0.5), wp.max(wp.abs(pos[1] - 0.5), wp.abs(pos[2] - 0.5)))
    m = int(0)
    half = float(0.5)
    while m < g.n_casc - 1 and mx >= half:
        m += 1
        half = half * 2.0
    return m


@wp.func
def cell_of(g: NgpMarch, pos: wp.vec3, m: int) -> wp.vec3i:
    h = wp.pow(2.0, float(m)) / float(g.res)
    lo = 0.5 - 0.5 * wp.pow(2.0, float(m))
    return wp.vec3i(
        wp.clamp(int(wp.floor((pos[0] - lo) / h)), 0, g.res - 1),
        wp.clamp(int(wp.floor((pos[1] - lo) / h)), 0, g.res - 1),
        wp.clamp(int(wp.floor((pos[2] - lo) / h)), 0, g.res - 1),
    )


@wp.kernel
def march_ngp_kernel(
    net: NgpNet,
    occ: wp.array4d(dtype=wp.uint8),
    g: NgpMarch,
    cam: MarchCamera,
    bp: BlendParams,
    vals: wp.array4d(dtype=float),
    vg: GridInfo,
    use_vals: int,
    out: PixelOut,
    base: int,
    stride: int,
):
    p = base + wp.tid() * stride
    x = p % cam.width
    y = p // cam.width
    rc = wp.vec3((float(x) + 0.5 - cam.cx) / cam.fx, (float(y) + 0.5 - cam.cy) / cam.fy, 1.0)
    nrm = wp.length(rc)
    cosv = 1.0 / nrm
    dw = cam.Rc * (rc / nrm)
    o = to_ngp(g, cam.center)
    d = wp.vec3(dw[g.ax[0]], dw[g.ax[1]], dw[g.ax[2]])
    t0, t1 = slab(o, d, g.lo, g.hi, cam.near * nrm * g.scale, 1.0e30)
    s = state_init()
    nc = out.feat.shape[1]
    t = t0
    it = int(0)
    while t < t1 and it < MAX_ITERS:
        it += 1
        pos = o + t * d
        m = mip_of(g, pos)
        c = cell_of(g, pos, m)
        if occ[m, c[0], c[1], c[2]] == wp.uint8(0):
            # jump out of the largest empty cascade cell around pos
            while m < g.n_levels - 1:
                c2 = cell_of(g, pos, m + 1)
                if occ[m + 1, c2[0], c2[1], c2[2]] != wp.uint8(0):
                    break
                m += 1
                c = c2
            h = wp.pow(2.0, float(m)) / float(g.res)
            lo = 0.5 - 0.5 * wp.pow(2.0, float(m))
            blo = wp.vec3(lo + float(c[0]) * h, lo + float(c[1]) * h, lo + float(c[2]) * h)
            bhi = blo + wp.vec3(h, h, h)
            ea, eb = slab(o, d, blo, bhi, -1.0e30, 1.0e30)
            t = wp.max(eb, t) + 1.0e-4 * h
        else:
            dt = wp.clamp(t * g.cone, g.step, g.max_step)
            tb = wp.min(t + dt, t1)
            tm = 0.5 * (t + tb)
            pm = o + tm * d
            f = density_features(net, pm)
            sigma = wp.exp(wp.min(f[0], 80.0))
            alpha = one_minus_exp(sigma * (tb - t))
            if alpha > 0.0:
                s, wk = blend_step(s, alpha, tm / g.scale * cosv, bp)
                if use_vals != 0:
                    x0, x1, y0, y1, z0, z1, w = cell_coords(vg, to_world(g, pm))
                    for ch in range(nc):
                        out.feat[p, ch] = out.feat[p, ch] + wk * lerp4(
                            vals, x0, x1, y0, y1, z0, z1, w, ch
                        )
                elif wk >= COLOR_MIN_WEIGHT:
                    rgb = color_of(net, f, d)
                    for ch in range(3):
                        out.feat[p, ch] = out.feat[p, ch] + wk * rgb[ch]
                if (s.flags & FLAG_DONE) != 0:
                    break
            t = tb
    finish_pixel(s, p, out)


def _grid_info(aabb: np.ndarray, shape: tuple[int, int, int]) -> GridInfo:
    D, H, W = shape
    aabb = np.asarray(aabb, np.float64).reshape(2, 3)
    vox = (aabb[1] - aabb[0]) / np.array([W, H, D], np.float64)
    gi = GridInfo()
    gi.lo, gi.hi = wp.vec3(*aabb[0].astype(np.float32)), wp.vec3(*aabb[1].astype(np.float32))
    gi.inv_vox = wp.vec3(*(1.0 / vox).astype(np.float32))
    gi.nx, gi.ny, gi.nz, gi.block, gi.step = W, H, D, 1, float(vox.min())
    return gi


def raymarch_ngp(
    net: NgpNetBuffers,
    occ: NgpOccupancy,
    frame: tuple[float, np.ndarray, tuple[int, int, int]],
    box: np.ndarray,
    n_cascades: int,
    c2w: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    settings: NgpMarchSettings,
    values: np.ndarray | None = None,
    values_aabb: np.ndarray | None = None,
    background=(0.0, 0.0, 0.0),
) -> PixelOut:
    """March every pixel of a ``width × height`` OpenCV view of the network.

    Args:
        frame: ``(scale, offset [3], axes)`` training frame → NeRF frame.
        box: ``[2,3]`` NeRF-frame march box.
        n_cascades: the snapshot's cascades (``occ`` may hold more, coarser levels).
        values: ``None`` → the network's RGB over ``background``; else per-voxel
            ``[D,H,W]`` or ``[D,H,W,C]`` values on the lattice ``values_aabb``
            (training frame) composited with the same weights (no background).
    """
    from .rasterize import alloc_pixel_out

    dev = net.device
    W, H = int(width), int(height)
    if W <= 0 or H <= 0:
        raise ValueError(f"raymarch_ngp: empty image {W}x{H}")
    scale, offset, axes = frame
    g = NgpMarch()
    g.scale, g.offset = float(scale), wp.vec3(*np.asarray(offset, np.float32))
    g.ax = wp.vec3i(*[int(a) for a in axes])
    box = np.asarray(box, np.float64).reshape(2, 3)
    g.lo, g.hi = wp.vec3(*box[0].astype(np.float32)), wp.vec3(*box[1].astype(np.float32))
    g.n_casc, g.n_levels, g.res = int(n_cascades), occ.n_cascades, occ.res
    g.step, g.cone, g.max_step = (
        float(settings.step),
        float(settings.cone),
        float(settings.max_step),
    )
    cam = MarchCamera()
    c2w = np.asarray(c2w, np.float64)
    cam.Rc = wp.mat33(*c2w[:3, :3].astype(np.float32).ravel())
    cam.center = wp.vec3(*c2w[:3, 3].astype(np.float32))
    cam.fx, cam.fy, cam.cx, cam.cy = float(fx), float(fy), float(cx), float(cy)
    cam.width, cam.near = W, float(settings.near)
    bp = BlendParams()
    bp.tau_sig, bp.tau_cw, bp.t_min = settings.tau_sig, settings.tau_cw, settings.t_min
    bp.alpha_min, bp.anchor = settings.alpha_min, ANCHOR_MAX
    with wp.ScopedDevice(dev):
        if values is None:
            C, bg, use = 3, np.asarray(background, np.float32).reshape(3), 0
            va = wp.zeros((1, 1, 1, 1), dtype=float)
            vg = _grid_info(np.array([[0.0] * 3, [1.0] * 3]), (1, 1, 1))
        else:
            v = np.asarray(values, np.float32)
            if v.ndim not in (3, 4) or values_aabb is None:
                raise ValueError(f"raymarch_ngp: values must be [D,H,W(,C)], got {v.shape}")
            v = v.reshape(v.shape[:3] + (-1,))
            C, bg, use = v.shape[3], np.zeros(v.shape[3], np.float32), 1
            va = wp.array(np.ascontiguousarray(v), dtype=float)
            vg = _grid_info(values_aabb, v.shape[:3])
        out = alloc_pixel_out(W * H, C, bg, dev)
        launch_split(
            march_ngp_kernel,
            W * H,
            [net.net, occ.occ, g, cam, bp, va, vg, use, out],
            dev,
            1 if dev.is_cuda else cpu_threads(settings.threads),
        )
    return out

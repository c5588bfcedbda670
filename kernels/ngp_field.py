"""An instant-ngp radiance network evaluated per point (Warp, CPU and CUDA).

The layouts are tiny-cuda-nn's (docs/design-notes.md, ``ngp_network.py``, says where each
comes from): multiresolution grid encoding (coherent prime hash
``x ⊕ y·2654435761 ⊕ z·805459861`` where a level's dense index would not fit, trilinear blend
of the 8 corners at ``x·scale + 0.5``), bias-free ReLU MLPs with row-major ``[out, in]``
matrices, the 16 spherical harmonics of degree < 4 of the direction. σ = exp(density MLP
output 0); colour = logistic (exp for HDR) of the RGB MLP fed ``[density MLP outputs, SH]``.
Widths up to :data:`MAX_WIDTH` (every width instant-ngp's FullyFusedMLP allows).
:func:`eval_ngp_points` evaluates raw outputs at given points: what the ray-marcher
(:mod:`kernels.raymarch_ngp`) runs per sample, and what the tests compare with a float64
NumPy reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ._launch import cpu_threads, launch_split

wp.set_module_options({"enable_backward": False})

__all__ = ["NgpNetBuffers", "upload_ngp_network", "eval_ngp_points", "MAX_WIDTH"]

MAX_WIDTH = 128
vec_w = wp.types.vector(length=MAX_WIDTH, dtype=float)

PRIME_Y = wp.constant(wp.uint32(2654435761))
PRIME_Z = wp.constant(wp.uint32(805459861))
U32_MAX = wp.constant(wp.uint32(0xFFFFFFFF))
GRID_HASH = wp.constant(0)
GRID_DENSE = wp.constant(1)
GRID_TILED = wp.constant(2)


@wp.struct
class NgpNet:
    table: wp.array(dtype=float)  # [entries · F]
    lvl_off: wp.array(dtype=int)  # [L + 1] first entry per level
    lvl_scale: wp.array(dtype=float)  # [L] grid_scale
    lvl_res: wp.array(dtype=int)  # [L] grid_resolution
    n_levels: int
    n_feat: int
    grid_type: int
    weights: wp.array(dtype=float)  # every MLP matrix, row-major, one after another
    d_layers: wp.array(dtype=wp.vec3i)  # (offset, out, in) of the density MLP's layers
    n_d: int
    r_layers: wp.array(dtype=wp.vec3i)  # … of the RGB MLP
    n_r: int
    d_out: int  # padded density-MLP output width (the RGB MLP's first inputs)
    hdr: int
    lo: wp.vec3  # network warp box (NeRF frame)
    inv_ext: wp.vec3


@wp.func
def grid_index(net: NgpNet, level: int, res: int, x: int, y: int, z: int) -> int:
    """tiny-cuda-nn ``grid_index`` (uint32 arithmetic, wrapping as in C++)."""
    size = wp.uint32(net.lvl_off[level + 1] - net.lvl_off[level])
    ures = wp.uint32(res)
    idx = wp.uint32(0)
    stride = U32_MAX
    if res <= 0x659:
        idx = wp.uint32(x) + wp.uint32(y) * ures + wp.uint32(z) * ures * ures
        stride = ures * ures * ures
    if net.grid_type == GRID_HASH and size < stride:
        idx = wp.uint32(x) ^ (wp.uint32(y) * PRIME_Y) ^ (wp.uint32(z) * PRIME_Z)
    return int(idx % size)


@wp.func
def encode_position(net: NgpNet, p: wp.vec3) -> vec_w:
    """Grid features of a warped position ``p ∈ [0,1]³`` (zeros past the levels)."""
    x = vec_w()
    F = net.n_feat
    for lv in range(net.n_levels):
        scale = net.lvl_scale[lv]
        res = net.lvl_res[lv]
        base = net.lvl_off[lv]
        qx = wp.float32(scale * p[0] + 0.5)
        qy = wp.float32(scale * p[1] + 0.5)
        qz = wp.float32(scale * p[2] + 0.5)
        fx = wp.floor(qx)
        fy = wp.floor(qy)
        fz = wp.floor(qz)
        gx = int(fx)
        gy = int(fy)
        gz = int(fz)
        wx = qx - fx
        wy = qy - fy
        wz = qz - fz
        for c in range(8):
            bx = c & 1
            by = (c >> 1) & 1
            bz = (c >> 2) & 1
            w = float(1.0)
            if bx != 0:
                w = w * wx
            else:
                w = w * (1.0 - wx)
            if by != 0:
                w = w * wy
            else:
                w = w * (1.0 - wy)
            if bz != 0:
                w = w * wz
            else:
                w = w * (1.0 - wz)
            e = base + grid_index(net, lv, res, gx + bx, gy + by, gz + bz)
            for f in range(F):
                x[lv * F + f] = x[lv * F + f] + w * net.table[e * F + f]
    return x


@wp.func
def mlp(w: wp.array(dtype=float), layers: wp.array(dtype=wp.vec3i), n: int, x0: vec_w) -> vec_w:
    """Bias-free MLP: ReLU after every layer but the last."""
    x = x0
    for li in range(n):
        L = layers[li]
        off = L[0]
        n_out = L[1]
        n_in = L[2]
        y = vec_w()
        for o in range(n_out):
            acc = float(0.0)
            row = off + o * n_in
            for i in range(n_in):
                acc += w[row + i] * x[i]
            if li < n - 1:
                acc = wp.max(acc, 0.0)
            y[o] = acc
        x = y
    return x


@wp.func
def sh16(d: wp.vec3, x0: vec_w, at: int) -> vec_w:
    """tiny-cuda-nn ``sh_enc`` degree 4 of unit ``d`` written at ``x[at:at+16]``."""
    x = x0
    a = d[0]
    b = d[1]
    c = d[2]
    xy = a * b
    xz = a * c
    yz = b * c
    x2 = a * a
    y2 = b * b
    z2 = c * c
    x[at + 0] = 0.28209479177387814
    x[at + 1] = -0.48860251190291987 * b
    x[at + 2] = 0.48860251190291987 * c
    x[at + 3] = -0.48860251190291987 * a
    x[at + 4] = 1.0925484305920792 * xy
    x[at + 5] = -1.0925484305920792 * yz
    x[at + 6] = 0.94617469575755997 * z2 - 0.31539156525251999
    x[at + 7] = -1.0925484305920792 * xz
    x[at + 8] = 0.54627421529603959 * x2 - 0.54627421529603959 * y2
    x[at + 9] = 0.59004358992664352 * b * (-3.0 * x2 + y2)
    x[at + 10] = 2.8906114426405538 * xy * c
    x[at + 11] = 0.45704579946446572 * b * (1.0 - 5.0 * z2)
    x[at + 12] = 0.3731763325901154 * c * (5.0 * z2 - 3.0)
    x[at + 13] = 0.45704579946446572 * a * (1.0 - 5.0 * z2)
    x[at + 14] = 1.4453057213202769 * c * (x2 - y2)
    x[at + 15] = 0.59004358992664352 * a * (-x2 + 3.0 * y2)
    return x


@wp.func
def warp_pos(net: NgpNet, p: wp.vec3) -> wp.vec3:
    return wp.cw_mul(p - net.lo, net.inv_ext)


@wp.func
def density_features(net: NgpNet, p: wp.vec3) -> vec_w:
    """Density-MLP outputs at NeRF-frame ``p`` (output 0 is log σ)."""
    return mlp(net.weights, net.d_layers, net.n_d, encode_position(net, warp_pos(net, p)))


@wp.func
def color_of(net: NgpNet, feats: vec_w, d: wp.vec3) -> wp.vec3:
    """RGB from the density-MLP outputs and the unit direction ``d`` (NeRF frame)."""
    x = vec_w()
    for i in range(net.d_out):
        x[i] = feats[i]
    # warp_direction then the SH input's ·2 − 1, as float32 does it
    u = wp.vec3((d[0] + 1.0) * 0.5, (d[1] + 1.0) * 0.5, (d[2] + 1.0) * 0.5)
    dd = wp.vec3(u[0] * 2.0 - 1.0, u[1] * 2.0 - 1.0, u[2] * 2.0 - 1.0)
    x = sh16(dd, x, net.d_out)
    y = mlp(net.weights, net.r_layers, net.n_r, x)
    out = wp.vec3()
    for c in range(3):
        v = y[c]
        if net.hdr != 0:
            out[c] = wp.exp(wp.clamp(v, -10.0, 10.0))
        else:
            out[c] = 1.0 / (1.0 + wp.exp(-v))
    return out


@wp.kernel
def eval_points_kernel(
    net: NgpNet,
    pts: wp.array(dtype=wp.vec3),
    dirs: wp.array(dtype=wp.vec3),
    out: wp.array(dtype=wp.vec4),
    base: int,
    stride: int,
):
    i = base + wp.tid() * stride
    f = density_features(net, pts[i])
    c = color_of(net, f, dirs[i])
    out[i] = wp.vec4(c[0], c[1], c[2], f[0])


@dataclass
class NgpNetBuffers:
    """A network resident on one device (keeps the arrays the struct points to alive)."""

    net: NgpNet
    arrays: list
    device: object


def upload_ngp_network(
    table: np.ndarray,
    level_offsets: np.ndarray,
    level_scales: np.ndarray,
    level_res: np.ndarray,
    grid_type: int,
    density_layers: list[np.ndarray],
    rgb_layers: list[np.ndarray],
    density_out: int,
    aabb: np.ndarray,
    hdr: bool,
    device,
) -> NgpNetBuffers:
    """Copy a network to ``device`` (``table`` ``[entries, F]``; matrices ``[out, in]``)."""
    device = wp.get_device(device)
    mats = list(density_layers) + list(rgb_layers)
    if any(max(m.shape) > MAX_WIDTH for m in mats):
        raise ValueError(f"upload_ngp_network: a layer is wider than {MAX_WIDTH}")
    if table.shape[1] * (len(level_offsets) - 1) > MAX_WIDTH:
        raise ValueError("upload_ngp_network: encoding wider than the MLP input limit")
    offs, lay = 0, []
    for m in mats:
        lay.append((offs, m.shape[0], m.shape[1]))
        offs += m.size
    w = np.concatenate([m.ravel() for m in mats]).astype(np.float32)
    nd = len(density_layers)
    aabb = np.asarray(aabb, np.float64).reshape(2, 3)
    arrs = dict(
        table=wp.array(np.ascontiguousarray(table, np.float32).ravel(), dtype=float, device=device),
        lvl_off=wp.array(np.asarray(level_offsets, np.int32), dtype=int, device=device),
        lvl_scale=wp.array(np.asarray(level_scales, np.float32), dtype=float, device=device),
        lvl_res=wp.array(np.asarray(level_res, np.int32), dtype=int, device=device),
        weights=wp.array(w, dtype=float, device=device),
        d_layers=wp.array(np.asarray(lay[:nd], np.int32), dtype=wp.vec3i, device=device),
        r_layers=wp.array(np.asarray(lay[nd:], np.int32), dtype=wp.vec3i, device=device),
    )
    net = NgpNet()
    for k, v in arrs.items():
        setattr(net, k, v)
    net.n_levels, net.n_feat, net.grid_type = len(level_offsets) - 1, int(table.shape[1]), grid_type
    net.n_d, net.n_r, net.d_out, net.hdr = nd, len(rgb_layers), int(density_out), int(hdr)
    net.lo = wp.vec3(*aabb[0].astype(np.float32))
    net.inv_ext = wp.vec3(*(1.0 / (aabb[1] - aabb[0])).astype(np.float32))
    return NgpNetBuffers(net, list(arrs.values()), device)


def eval_ngp_points(
    buf: NgpNetBuffers, points: np.ndarray, dirs: np.ndarray, threads: int | None = None
) -> np.ndarray:
    """``[N, 4]``: RGB (after the activation) and the raw log density at NeRF-frame
    ``points`` seen along unit ``dirs``."""
    p = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, np.float32).reshape(-1, 3)
    if p.shape != d.shape:
        raise ValueError(f"eval_ngp_points: {p.shape} points vs {d.shape} directions")
    dev = buf.device
    pa = wp.array(p, dtype=wp.vec3, device=dev)
    da = wp.array(d, dtype=wp.vec3, device=dev)
    out = wp.zeros(len(p), dtype=wp.vec4, device=dev)
    if len(p):
        th = 1 if dev.is_cuda else cpu_threads(threads)
        launch_split(eval_points_kernel, len(p), [buf.net, pa, da, out], dev, th)
    return out.numpy().reshape(-1, 4)

"""Tile-based 2DGS surfel rasterizer (Warp, CPU and CUDA).

Pipeline per view (the 2DGS rasterizer structure, re-derived here):

1. ``preprocess``: per surfel, camera-space homogeneous splat rows, projected
   centre, planar centre depth (the sort key), SH colour, and a *conservative
   exact* pixel rectangle: the screen bounding box of the projected cutoff disc
   ``u² + v² ≤ ρ_cut`` (a conic; closed form below) united with the low-pass disc.
   ``ρ_cut = 2 ln(255 · opacity)`` is where ``opacity · G`` falls to ``α_min = 1/255``
   (``≤ 3.33``σ), so no pixel with ``α ≥ 1/255`` lies outside the rectangle — the
   fixed 3σ box of 2DGS would drop the 3σ–3.33σ rim the definition keeps.
   A surfel is rendered only when its whole cutoff disc lies beyond the near
   plane (2DGS culls by centre depth; a straddling disc would need the whole
   screen, its image being unbounded). So every rendered splat has a
   projected centre and an elliptic footprint.
2. depth sort of all surfels (stable float radix sort: ties keep index order).
3. per band of tile rows: tile counts in depth order, exclusive scan, duplication
   into (tile, surfel) pairs, stable radix sort on the tile bits, tile ranges.
   Bands are split so the duplicate count stays under ``max_duplicates``.
4. blending, front to back per pixel (``kernels.composite`` rules), in one of two
   equivalent Warp kernels that call the same per-pair function:
   ``pixel`` (one thread per pixel, loops its tile's list — the GPU form) and
   ``tile`` (one thread per tile, walks each surfel's exact row spans ∩ tile —
   the CPU form: work ∝ covered pixels instead of list length × 256).

Ray–splat intersection (NOTES): for pixel ray ``r = ((x−c_x)/f_x, (y−c_y)/f_y, 1)``
and the surfel plane ``X(u,v) = μ + u t_u + v t_v`` in camera space (``t_u, t_v``
scaled by ``s_1, s_2``), with rows ``m_x = (t_u.x, t_v.x, μ.x)`` (likewise ``m_y, m_z``)
the hit satisfies ``(u, v, 1) ∝ p = (r_x m_z − m_x) × (r_y m_z − m_y)``, which is
linear in ``r``: ``p = Q r`` (:class:`kernels.splat.Splat`, evaluated from the offset
to the projected centre's ray). So ``ρ_3 = u² + v²`` with ``u = p_x/p_z, v = p_y/p_z``
and the planar depth is ``z = m_z·(u, v, 1) = det[m]/p_z``. Low-pass: ``ρ_2 = d² / σ²`` with
``d`` the pixel
distance to the projected centre and ``σ = √2/2`` px. ``ρ = min(ρ_3, ρ_2)`` (the max
of the two Gaussians, as 2DGS does: it takes over exactly when the ray is near
edge-on or the surfel is sub-pixel); the depth is the intersection depth when
``ρ_3 ≤ ρ_2``, else the centre depth. ``α = min(α_max, opacity · exp(−ρ/2))``;
``α < α_min`` or depth < near → skipped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from ._launch import cpu_threads, launch_split
from .composite import ANCHOR_MED, BlendParams, PixelOut, PixState
from .sh import eval_sh
from .splat import BIG, RasterCamera, Splat, conic_range, make_raster_camera, splat_plane_rows

# forward only: no adjoint code (halves compile time)
wp.set_module_options({"enable_backward": False})

__all__ = [
    "RasterSettings",
    "RasterOutput",
    "SurfelBuffers",
    "upload_surfels",
    "rasterize_surfels",
    "tile_bands",
    "make_raster_camera",
]


@dataclass
class RasterSettings:
    """Constants of one rasterization (defaults: NOTES / 2DGS).

    Attributes:
        tau_sig: τ_sig, weight of the first significant primitive (``D_min``).
        tau_cw: τ_cw, cumulative opacity fixing ``D_max``.
        t_min: early-termination transmittance.
        alpha_min: smallest opacity that contributes (1/255).
        alpha_max: opacity clamp (0.99).
        lowpass_sigma: σ of the screen-space low-pass Gaussian, pixels (√2/2).
        near: near plane, planar depth in world units.
        tile: tile edge in pixels.
        max_duplicates: soft cap on (tile, surfel) pairs held at once (bands above it).
        blend: ``"auto"`` (``tile`` on CPU, ``pixel`` on CUDA), ``"tile"`` or ``"pixel"``.
        threads: CPU launch threads (None: all usable cores).
        profile: synchronise after each stage and record stage seconds in ``stats``.
    """

    tau_sig: float = 0.05
    tau_cw: float = 0.75
    t_min: float = 1e-4
    alpha_min: float = 1.0 / 255.0
    alpha_max: float = 0.99
    lowpass_sigma: float = float(np.sqrt(0.5))
    near: float = 0.01
    tile: int = 16
    max_duplicates: int = 1 << 25
    blend: str = "auto"
    threads: int | None = None
    profile: bool = False


class _Timer:
    """Stage timer (only when profiling: synchronises the device)."""

    def __init__(self, on: bool, stats: dict):
        self.on, self.stats, self.t = on, stats, time.perf_counter()
        if on:
            stats["seconds"] = {}

    def lap(self, name: str) -> None:
        if self.on:
            wp.synchronize()
            t = time.perf_counter()
            self.stats["seconds"][name] = self.stats["seconds"].get(name, 0.0) + t - self.t
            self.t = t


@dataclass
class SurfelBuffers:
    """A surfel scene resident on one device (uploaded once).

    Attributes:
        means, tu, tv: ``[N]`` vec3 centre and scaled tangents ``s_1 R_0``, ``s_2 R_1``.
        opacity: ``[N]`` opacity.
        rho_cut: ``[N]`` ``2 ln(255·opacity)`` (≤ 0: never visible).
        sh: ``[N, K]`` vec3 SH coefficients; ``sh_degree`` 0..3.
    """

    means: wp.array
    tu: wp.array
    tv: wp.array
    opacity: wp.array
    rho_cut: wp.array
    sh: wp.array
    sh_degree: int
    device: wp.context.Device

    def __len__(self) -> int:
        return self.means.shape[0]


def upload_surfels(
    means: np.ndarray,
    rotations: np.ndarray,
    scales: np.ndarray,
    opacities: np.ndarray,
    sh: np.ndarray,
    sh_degree: int,
    device,
    alpha_min: float = 1.0 / 255.0,
) -> SurfelBuffers:
    """Copy a surfel scene to ``device``. ``rotations`` ``[N,3,3]`` (columns t_u, t_v, n)."""
    n = len(means)
    if rotations.shape != (n, 3, 3) or scales.shape != (n, 2) or opacities.shape != (n,):
        raise ValueError("upload_surfels: inconsistent array shapes")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[1] != (sh_degree + 1) ** 2 or sh.shape[2] != 3:
        raise ValueError(f"upload_surfels: sh must be [N,{(sh_degree + 1) ** 2},3], got {sh.shape}")
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"upload_surfels: sh_degree {sh_degree} outside 0..3")
    tu = rotations[:, :, 0] * scales[:, :1]
    tv = rotations[:, :, 1] * scales[:, 1:2]
    op = np.asarray(opacities, dtype=np.float64)
    with np.errstate(divide="ignore"):
        rho_cut = np.where(op * 255.0 > 1.0, 2.0 * np.log(np.maximum(op, 1e-30) / alpha_min), -1.0)
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    return SurfelBuffers(
        means=wp.array(f32(means), dtype=wp.vec3, device=device),
        tu=wp.array(f32(tu), dtype=wp.vec3, device=device),
        tv=wp.array(f32(tv), dtype=wp.vec3, device=device),
        opacity=wp.array(f32(op), dtype=float, device=device),
        rho_cut=wp.array(f32(rho_cut), dtype=float, device=device),
        sh=wp.array(f32(sh), dtype=wp.vec3, device=device),
        sh_degree=int(sh_degree),
        device=device,
    )


# --------------------------------------------------------------------------- kernels
@wp.kernel
def preprocess_kernel(
    means: wp.array(dtype=wp.vec3),
    tu: wp.array(dtype=wp.vec3),
    tv: wp.array(dtype=wp.vec3),
    opacity: wp.array(dtype=float),
    rho_cut: wp.array(dtype=float),
    sh: wp.array2d(dtype=wp.vec3),
    sh_degree: int,
    with_color: int,
    cam: RasterCamera,
    inv_var: float,
    splats: wp.array(dtype=Splat),
    sort_keys: wp.array(dtype=float),
    sort_vals: wp.array(dtype=wp.int32),
    colors: wp.array2d(dtype=float),
    base: int,
    stride: int,
):
    """Per surfel: splat rows, bounds, sort key (+inf when culled) and SH colour."""
    i = base + wp.tid() * stride
    mu = means[i]
    pc = cam.R * mu + cam.t
    a = cam.R * tu[i]
    b = cam.R * tv[i]
    mx = wp.vec3(a[0], b[0], pc[0])
    my = wp.vec3(a[1], b[1], pc[1])
    mz = wp.vec3(a[2], b[2], pc[2])
    sp = splat_plane_rows(mx, my, mz)
    sp.pz0 = 1.0
    sp.r2 = 0.0
    sp.depth = pc[2]
    sp.opacity = opacity[i]
    k2 = rho_cut[i]
    sp.rho_cut = k2
    sp.center = wp.vec2(0.0, 0.0)
    sp.center_lo = wp.vec2(0.0, 0.0)
    sp.x0 = 1
    sp.x1 = 0
    sp.y0 = 1
    sp.y1 = 0
    W = float(cam.width)
    H = float(cam.height)
    zr = wp.sqrt(wp.max(k2, 0.0) * (a[2] * a[2] + b[2] * b[2]))
    # rendered only when the whole cutoff disc lies beyond the near plane
    if k2 > 0.0 and pc[2] - zr > cam.near:
        # exact screen bounds of the projected cutoff disc (an ellipse) …
        ox, hx = conic_range(mx, mz, k2)
        oy, hy = conic_range(my, mz, k2)
        cxp = cam.fx * ox + cam.cx
        cyp = cam.fy * oy + cam.cy
        rx = cam.fx * hx
        ry = cam.fy * hy
        mgx = 0.01 + 1.0e-4 * (wp.abs(cxp) + rx)
        mgy = 0.01 + 1.0e-4 * (wp.abs(cyp) + ry)
        sp.pz0 = wp.dot(sp.qn, pc) / pc[2]  # = det / depth (triple product (t_u×t_v)·μ)
        # projected centre in float64, stored as float32 hi + lo
        pd = cam.R64 * wp.vec3d(wp.float64(mu[0]), wp.float64(mu[1]), wp.float64(mu[2])) + cam.t64
        cxd = wp.float64(cam.fx) * pd[0] / pd[2] + wp.float64(cam.cx)
        cyd = wp.float64(cam.fy) * pd[1] / pd[2] + wp.float64(cam.cy)
        c = wp.vec2(wp.float32(cxd), wp.float32(cyd))
        sp.center = c
        sp.center_lo = wp.vec2(
            wp.float32(cxd - wp.float64(c[0])), wp.float32(cyd - wp.float64(c[1]))
        )
        # … united with the low-pass disc around the projected centre
        r2 = wp.sqrt(k2 / inv_var) + 0.01
        sp.r2 = r2
        xlo = wp.min(cxp - rx - mgx, c[0] - r2)
        xhi = wp.max(cxp + rx + mgx, c[0] + r2)
        ylo = wp.min(cyp - ry - mgy, c[1] - r2)
        yhi = wp.max(cyp + ry + mgy, c[1] + r2)
        # pixel centres at i + 0.5; clamp before int conversion
        xlo = wp.clamp(xlo, -2.0, W + 2.0)
        xhi = wp.clamp(xhi, -2.0, W + 2.0)
        ylo = wp.clamp(ylo, -2.0, H + 2.0)
        yhi = wp.clamp(yhi, -2.0, H + 2.0)
        sp.x0 = wp.max(int(wp.ceil(xlo - 0.5)), 0)
        sp.x1 = wp.min(int(wp.floor(xhi - 0.5)), cam.width - 1)
        sp.y0 = wp.max(int(wp.ceil(ylo - 0.5)), 0)
        sp.y1 = wp.min(int(wp.floor(yhi - 0.5)), cam.height - 1)
    key = BIG
    if sp.x0 <= sp.x1 and sp.y0 <= sp.y1:
        key = sp.depth
    else:
        sp.x0 = 1
        sp.x1 = 0
    splats[i] = sp
    sort_keys[i] = key
    sort_vals[i] = wp.int32(i)
    if with_color != 0:
        d = wp.normalize(mu - cam.center)
        col = eval_sh(sh, i, sh_degree, d)
        colors[i, 0] = col[0]
        colors[i, 1] = col[1]
        colors[i, 2] = col[2]


@wp.func
def band_tiles(sp: Splat, tile: int, band_lo: int, band_hi: int):
    """Tile rectangle of ``sp`` clipped to tile rows ``[band_lo, band_hi)``; empty → tx0 > tx1."""
    tx0 = sp.x0 // tile
    tx1 = sp.x1 // tile
    ty0 = wp.max(sp.y0 // tile, band_lo)
    ty1 = wp.min(sp.y1 // tile, band_hi - 1)
    if sp.x0 > sp.x1 or ty0 > ty1:
        tx0 = 1
        tx1 = 0
    return tx0, tx1, ty0, ty1


@wp.kernel
def count_kernel(
    splats: wp.array(dtype=Splat),
    order: wp.array(dtype=wp.int32),
    tile: int,
    band_lo: int,
    band_hi: int,
    counts: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Tiles touched in the band by the ``j``-th surfel in depth order."""
    j = base + wp.tid() * stride
    tx0, tx1, ty0, ty1 = band_tiles(splats[order[j]], tile, band_lo, band_hi)
    n = int(0)
    if tx0 <= tx1:
        n = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
    counts[j] = wp.int32(n)


@wp.kernel
def duplicate_kernel(
    splats: wp.array(dtype=Splat),
    order: wp.array(dtype=wp.int32),
    tile: int,
    band_lo: int,
    band_hi: int,
    tiles_x: int,
    incl: wp.array(dtype=wp.int32),
    counts: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int32),
    vals: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Emit one (band-local tile id, surfel) pair per touched tile, in depth order."""
    j = base + wp.tid() * stride
    i = order[j]
    tx0, tx1, ty0, ty1 = band_tiles(splats[i], tile, band_lo, band_hi)
    o = int(incl[j]) - int(counts[j])  # exclusive offset
    if tx0 <= tx1:
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                keys[o] = wp.int32((ty - band_lo) * tiles_x + tx)
                vals[o] = i
                o += 1


@wp.kernel
def ranges_kernel(
    keys: wp.array(dtype=wp.int32),
    n: int,
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """``[rstart[t], rend[t])``: the sorted pairs of tile ``t``."""
    e = base + wp.tid() * stride
    k = keys[e]
    if e == 0:
        rstart[k] = wp.int32(0)
    elif keys[e - 1] != k:
        rstart[k] = wp.int32(e)
    if e == n - 1:
        rend[k] = wp.int32(n)
    elif keys[e + 1] != k:
        rend[k] = wp.int32(e + 1)


# --------------------------------------------------------------------------- wrapper
@dataclass
class RasterOutput:
    """Device buffers of one rasterization, flattened ``p = y * width + x``.

    ``feat`` ``[P, C]`` (RGB + background, or the composited values), ``alpha``,
    ``d_min``, ``d_med``, ``d_max``, ``d_mw``, ``d_exp`` ``[P]`` float32, ``n_samp``
    ``[P]`` int32; ``stats`` holds counts (pairs, bands; visible surfels and stage
    seconds when profiling).
    """

    out: PixelOut
    width: int
    height: int
    stats: dict


def blend_params(s: RasterSettings, anchor: int = ANCHOR_MED) -> BlendParams:
    bp = BlendParams()
    bp.tau_sig, bp.tau_cw, bp.t_min = float(s.tau_sig), float(s.tau_cw), float(s.t_min)
    bp.alpha_min, bp.anchor = float(s.alpha_min), int(anchor)
    return bp


def alloc_pixel_out(P: int, C: int, bg: np.ndarray, device) -> PixelOut:
    out = PixelOut()
    out.feat = wp.zeros((P, C), dtype=float, device=device)
    out.bg = wp.array(np.asarray(bg, dtype=np.float32).reshape(C), dtype=float, device=device)
    for name in ("alpha", "d_min", "d_med", "d_max", "d_mw", "d_exp"):
        setattr(out, name, wp.empty(P, dtype=float, device=device))
    out.n_samp = wp.empty(P, dtype=wp.int32, device=device)
    return out


def rasterize_surfels(
    buf: SurfelBuffers,
    w2c: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    settings: RasterSettings | None = None,
    values: np.ndarray | None = None,
    background: np.ndarray | tuple = (0.0, 0.0, 0.0),
) -> RasterOutput:
    """Rasterize ``buf`` into a ``width × height`` view (OpenCV pinhole, ``w2c`` 4×4).

    Args:
        values: ``None`` → composite SH colours over ``background``; else ``[N]`` or
            ``[N, C]`` per-surfel values composited with the same weights (no background).
    Returns:
        :class:`RasterOutput` on ``buf.device``.
    """
    s = settings or RasterSettings()
    dev = buf.device
    n = len(buf)
    W, H, T = int(width), int(height), int(s.tile)
    if W <= 0 or H <= 0:
        raise ValueError(f"rasterize_surfels: empty image {W}x{H}")
    if T <= 0 or T > 64:
        raise ValueError(f"rasterize_surfels: tile size {T} outside 1..64")
    mode = s.blend if s.blend != "auto" else ("pixel" if dev.is_cuda else "tile")
    if mode not in ("pixel", "tile"):
        raise ValueError(f"rasterize_surfels: blend mode {s.blend!r} is not auto/pixel/tile")
    threads = cpu_threads(s.threads)
    cam = make_raster_camera(np.asarray(w2c, dtype=np.float64), fx, fy, cx, cy, W, H, s.near)
    inv_var = 1.0 / float(s.lowpass_sigma) ** 2
    P = W * H
    with wp.ScopedDevice(dev):
        if values is None:
            C, with_color, bg = 3, 1, np.asarray(background, dtype=np.float32).reshape(3)
            feat = wp.empty((max(n, 1), 3), dtype=float)
        else:
            v = np.asarray(values, dtype=np.float32)
            v = v.reshape(len(v), -1) if v.ndim > 1 else v.reshape(-1, 1)
            if v.shape[0] != n:
                raise ValueError(f"rasterize_surfels: values has {v.shape[0]} rows for {n} surfels")
            C, with_color, bg = v.shape[1], 0, np.zeros(v.shape[1], np.float32)
            feat = wp.array(np.ascontiguousarray(v), dtype=float)
        out = alloc_pixel_out(P, C, bg, dev)
        stats = {"surfels": n, "pairs": 0, "bands": 0, "mode": mode}
        tiles_x, tiles_y = -(-W // T), -(-H // T)
        if n == 0:
            _blend_empty(out, P, cam, s, T, tiles_x, tiles_y, feat, mode, threads, dev)
            return RasterOutput(out, W, H, stats)
        tm = _Timer(s.profile, stats)
        splats = wp.empty(n, dtype=Splat)
        keys = wp.empty(2 * n, dtype=float)
        order = wp.empty(2 * n, dtype=wp.int32)
        launch_split(
            preprocess_kernel,
            n,
            [
                buf.means,
                buf.tu,
                buf.tv,
                buf.opacity,
                buf.rho_cut,
                buf.sh,
                buf.sh_degree,
                with_color,
                cam,
                inv_var,
                splats,
                keys,
                order,
                feat if with_color else wp.empty((1, 3), dtype=float),
            ],
            dev,
            threads,
        )
        tm.lap("preprocess")
        wp.utils.radix_sort_pairs(keys, order, n)
        tm.lap("depth_sort")
        states = wp.empty(P, dtype=PixState) if mode == "tile" else None
        bp = blend_params(s)
        for lo, nt, dvals, rstart, rend, _ in tile_bands(
            splats, order, n, T, tiles_x, tiles_y, s.max_duplicates, stats, dev, threads, tm
        ):
            _blend(
                mode,
                splats,
                dvals,
                rstart,
                rend,
                feat,
                cam,
                inv_var,
                s,
                bp,
                T,
                tiles_x,
                lo,
                nt,
                states,
                out,
                dev,
                threads,
            )
            tm.lap("blend")
        if s.profile:  # a device → host copy of the sort keys: only when profiling
            stats["visible"] = int(np.count_nonzero(keys[:n].numpy() < 1e29))
    return RasterOutput(out, W, H, stats)


def tile_bands(
    splats: wp.array,
    order: wp.array,
    n: int,
    T: int,
    tiles_x: int,
    tiles_y: int,
    max_duplicates: int,
    stats: dict,
    dev,
    threads: int,
    tm: _Timer | None = None,
):
    """Bin depth-sorted splats into tiles, one band of tile rows at a time.

    Per band: count the tiles each splat touches, scan, split the band in two while it
    holds more than ``max_duplicates`` (splat, tile) pairs (bounded memory), duplicate
    keys, sort them by tile (stable, so depth order survives) and find each tile's range.
    Yields ``(band_lo, n_tiles, sorted_splat_ids, range_start, range_end, pairs)``; also
    used by the contribution pass (``kernels.contrib``) so both see the same binning.
    """
    lap = tm.lap if tm is not None else (lambda _stage: None)
    counts = wp.empty(n, dtype=wp.int32)
    incl = wp.empty(n, dtype=wp.int32)
    bands = [(0, tiles_y)]
    while bands:
        lo, hi = bands.pop(0)
        launch_split(count_kernel, n, [splats, order, T, lo, hi, counts], dev, threads)
        wp.utils.array_scan(counts, incl, inclusive=True)
        total = int(incl[n - 1 : n].numpy()[0])
        lap("count")
        if total > max_duplicates and hi - lo > 1:
            mid = (lo + hi) // 2
            bands[:0] = [(lo, mid), (mid, hi)]
            continue
        stats["pairs"] += total
        stats["bands"] += 1
        nt = (hi - lo) * tiles_x
        rstart = wp.zeros(nt, dtype=wp.int32)
        rend = wp.zeros(nt, dtype=wp.int32)
        if total > 0:
            dkeys = wp.empty(2 * total, dtype=wp.int32)
            dvals = wp.empty(2 * total, dtype=wp.int32)
            launch_split(
                duplicate_kernel,
                n,
                [splats, order, T, lo, hi, tiles_x, incl, counts, dkeys, dvals],
                dev,
                threads,
            )
            lap("duplicate")
            wp.utils.radix_sort_pairs(dkeys, dvals, total, 0, max(1, (nt - 1).bit_length()))
            lap("tile_sort")
            launch_split(ranges_kernel, total, [dkeys, total, rstart, rend], dev, threads)
        else:
            dvals = wp.empty(1, dtype=wp.int32)
        yield lo, nt, dvals, rstart, rend, total


def _blend(
    mode,
    splats,
    vals,
    rstart,
    rend,
    feat,
    cam,
    inv_var,
    s,
    bp,
    T,
    tiles_x,
    band_lo,
    nt,
    states,
    out,
    dev,
    threads,
) -> None:
    from .rasterize_blend import blend_pixel_kernel, blend_tile_kernel

    common = [
        splats,
        vals,
        rstart,
        rend,
        feat,
        cam,
        inv_var,
        float(s.alpha_max),
        bp,
        T,
        tiles_x,
        band_lo,
    ]
    if mode == "pixel":
        launch_split(blend_pixel_kernel, nt * T * T, common + [out], dev, threads)
    else:
        launch_split(blend_tile_kernel, nt, common + [states, out], dev, threads, mode="interleave")


def _blend_empty(out, P, cam, s, T, tiles_x, tiles_y, feat, mode, threads, dev) -> None:
    """No surfels: every pixel gets the empty tuple and the background."""
    z = wp.zeros(tiles_x * tiles_y, dtype=wp.int32, device=dev)
    splats = wp.empty(1, dtype=Splat, device=dev)
    _blend(
        mode,
        splats,
        wp.empty(1, dtype=wp.int32, device=dev),
        z,
        z,
        feat,
        cam,
        1.0 / float(s.lowpass_sigma) ** 2,
        s,
        blend_params(s),
        T,
        tiles_x,
        0,
        tiles_x * tiles_y,
        wp.empty(P, dtype=PixState, device=dev) if mode == "tile" else None,
        out,
        dev,
        threads,
    )

"""Per-surfel blending contributions split by a binary view mask (evaluation baseline).

For one view with a binary mask ``B`` (``[H, W]``), every surfel ``i`` gets

    A₁[i] = Σ_{p: B[p]=1} w_{i,p},     A₀[i] = Σ_{p: B[p]=0} w_{i,p},

with ``w_{i,p} = α_{i,p} T_{i,p}`` the front-to-back blending weight of surfel ``i`` at
pixel ``p`` — exactly the weight the rasterizer gives it (``render_values`` composites
``Σ_i w_{i,p} v_i``). This is the per-primitive accumulation of contribution-weighted
voting in the style of FlashSplat (ECCV 2024): a Gaussian is foreground when it
contributes more to mask-positive than to mask-negative pixels.

It reuses the rasterizer entirely: its preprocessing, depth sort and tile binning
kernels (``kernels.rasterize``: ``preprocess_kernel``, ``count_kernel``,
``duplicate_kernel``, ``ranges_kernel``), the ray–splat evaluation
(:func:`kernels.splat.splat_alpha`, :func:`kernels.splat.row_span`) and the
compositing step (:func:`kernels.composite.blend_step`, so early termination and
``α_min`` skipping are the renderer's). Only the per-pair action differs: instead of
adding ``w · feat`` to the pixel, ``w`` is atomically added to the surfel's ``A₁`` or
``A₀``.

Two blend forms, as in the rasterizer: ``pixel`` (one thread per pixel, the GPU form,
``wp.atomic_add`` into ``[1, N]`` accumulators) and ``tile`` (one thread per tile, the
CPU form). Warp's CPU ``atomic_add`` is a plain add and the CPU wrapper runs several
sub-launches concurrently (:func:`kernels._launch.launch_split`, ``interleave``: the
sub-launch ``j`` gets ``base = j``), so on the CPU each sub-launch owns the row
``base`` of ``[threads, N]`` accumulators; the rows are summed at the end.
Results are float32 and, up to float rounding of the sums, independent of the form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import warp as wp

from ._launch import cpu_threads, launch_split
from .composite import FLAG_DONE, BlendParams, PixState, blend_step, state_init
from .rasterize import RasterSettings, SurfelBuffers, blend_params, preprocess_kernel, tile_bands
from .splat import RasterCamera, Splat, make_raster_camera, row_span, splat_alpha

wp.set_module_options({"enable_backward": False})

__all__ = [
    "ContribOutput",
    "contrib_pixel_kernel",
    "contrib_tile_kernel",
    "accumulate_contributions",
]


# --------------------------------------------------------------------------- kernels
@wp.kernel
def contrib_pixel_kernel(
    splats: wp.array(dtype=Splat),
    vals: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    bp: BlendParams,
    tile: int,
    tiles_x: int,
    band_lo: int,
    positive: wp.array(dtype=wp.uint8),
    a1: wp.array2d(dtype=float),
    a0: wp.array2d(dtype=float),
    base: int,
    stride: int,
):
    """Work item ``g`` = band-local tile ``g // tile²``, pixel ``g % tile²`` (as
    ``blend_pixel_kernel``); adds each surfel's weight to row ``base`` of ``a1``/``a0``."""
    g = base + wp.tid() * stride
    row = base % a1.shape[0]
    tpix = tile * tile
    t = g // tpix
    q = g - t * tpix
    x = (t % tiles_x) * tile + q % tile
    y = (t // tiles_x + band_lo) * tile + q // tile
    if x >= cam.width or y >= cam.height:
        return
    p = y * cam.width + x
    pos = positive[p] != wp.uint8(0)
    px = float(x) + 0.5
    py = float(y) + 0.5
    s = state_init()
    for e in range(int(rstart[t]), int(rend[t])):
        i = vals[e]
        sp = splats[i]
        if x >= sp.x0 and x <= sp.x1 and y >= sp.y0 and y <= sp.y1:
            alpha, z = splat_alpha(sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near)
            if alpha >= bp.alpha_min:
                s, w = blend_step(s, alpha, z, bp)
                if pos:
                    wp.atomic_add(a1, row, i, w)
                else:
                    wp.atomic_add(a0, row, i, w)
                if (s.flags & FLAG_DONE) != 0:
                    break


@wp.kernel
def contrib_tile_kernel(
    splats: wp.array(dtype=Splat),
    vals: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    bp: BlendParams,
    tile: int,
    tiles_x: int,
    band_lo: int,
    positive: wp.array(dtype=wp.uint8),
    states: wp.array(dtype=PixState),
    a1: wp.array2d(dtype=float),
    a0: wp.array2d(dtype=float),
    base: int,
    stride: int,
):
    """Work item ``t`` = band-local tile (as ``blend_tile_kernel``): walks each surfel's
    exact row spans ∩ tile; adds the weights to row ``base`` of ``a1``/``a0``."""
    t = base + wp.tid() * stride
    row = base % a1.shape[0]
    X0 = (t % tiles_x) * tile
    Y0 = (t // tiles_x + band_lo) * tile
    X1 = wp.min(X0 + tile, cam.width) - 1
    Y1 = wp.min(Y0 + tile, cam.height) - 1
    W = cam.width
    for y in range(Y0, Y1 + 1):
        for x in range(X0, X1 + 1):
            states[y * W + x] = state_init()
    npix = (X1 - X0 + 1) * (Y1 - Y0 + 1)
    ndone = int(0)
    for e in range(int(rstart[t]), int(rend[t])):
        i = vals[e]
        sp = splats[i]
        xa = wp.max(sp.x0, X0)
        xb = wp.min(sp.x1, X1)
        ya = wp.max(sp.y0, Y0)
        yb = wp.min(sp.y1, Y1)
        for y in range(ya, yb + 1):
            py = float(y) + 0.5
            xs, xe = row_span(sp, py, cam.fx, cam.fy, xa, xb)
            for x in range(xs, xe + 1):
                p = y * W + x
                s = states[p]
                if (s.flags & FLAG_DONE) == 0:
                    px = float(x) + 0.5
                    alpha, z = splat_alpha(sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near)
                    if alpha >= bp.alpha_min:
                        s, w = blend_step(s, alpha, z, bp)
                        if positive[p] != wp.uint8(0):
                            wp.atomic_add(a1, row, i, w)
                        else:
                            wp.atomic_add(a0, row, i, w)
                        states[p] = s
                        if (s.flags & FLAG_DONE) != 0:
                            ndone += 1
        if ndone == npix:
            break


@wp.kernel
def _sum_rows_kernel(
    rows: wp.array2d(dtype=float), out: wp.array(dtype=float), base: int, stride: int
):
    i = base + wp.tid() * stride
    acc = float(0.0)
    for r in range(rows.shape[0]):
        acc += rows[r, i]
    out[i] = acc


# --------------------------------------------------------------------------- wrapper
@dataclass
class ContribOutput:
    """``a1``/``a0``: ``[N]`` float32 device arrays (A₁, A₀ of the module docstring);
    ``stats``: pairs, bands and the blend mode."""

    a1: wp.array
    a0: wp.array
    stats: dict


def accumulate_contributions(
    buf: SurfelBuffers,
    w2c: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    positive: np.ndarray,
    settings: RasterSettings | None = None,
) -> ContribOutput:
    """A₁ / A₀ of every surfel of ``buf`` for one view (OpenCV pinhole, ``w2c`` 4×4).

    Args:
        positive: ``[H, W]`` (or ``[H·W]``) mask, nonzero = mask-positive pixel.
        settings: the rasterizer's settings (same defaults: α_min, α_max, T_min, near,
            low-pass σ, tile, blend form, threads).
    Returns:
        :class:`ContribOutput` on ``buf.device``.
    """
    s = settings or RasterSettings()
    dev = buf.device
    n = len(buf)
    W, H, T = int(width), int(height), int(s.tile)
    if W <= 0 or H <= 0:
        raise ValueError(f"accumulate_contributions: empty image {W}x{H}")
    if T <= 0 or T > 64:
        raise ValueError(f"accumulate_contributions: tile size {T} outside 1..64")
    pos = np.asarray(positive)
    if pos.size != W * H:
        raise ValueError(f"accumulate_contributions: mask has {pos.size} pixels, the view {W}x{H}")
    mode = s.blend if s.blend != "auto" else ("pixel" if dev.is_cuda else "tile")
    if mode not in ("pixel", "tile"):
        raise ValueError(f"accumulate_contributions: blend mode {s.blend!r} is not auto/pixel/tile")
    threads = 1 if dev.is_cuda else cpu_threads(s.threads)
    cam = make_raster_camera(np.asarray(w2c, dtype=np.float64), fx, fy, cx, cy, W, H, s.near)
    inv_var = 1.0 / float(s.lowpass_sigma) ** 2
    P = W * H
    stats = {"surfels": n, "pairs": 0, "bands": 0, "mode": mode}
    with wp.ScopedDevice(dev):
        a1 = wp.zeros(n, dtype=float)
        a0 = wp.zeros(n, dtype=float)
        if n == 0:
            return ContribOutput(a1, a0, stats)
        pos_dev = wp.array(
            np.ascontiguousarray(pos.reshape(-1) != 0, dtype=np.uint8), dtype=wp.uint8
        )
        rows1 = wp.zeros((threads, n), dtype=float)
        rows0 = wp.zeros((threads, n), dtype=float)
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
                0,
                cam,
                inv_var,
                splats,
                keys,
                order,
                wp.empty((1, 3), dtype=float),
            ],
            dev,
            threads,
        )
        wp.utils.radix_sort_pairs(keys, order, n)
        states = wp.empty(P, dtype=PixState) if mode == "tile" else None
        bp = blend_params(s)
        tiles_x, tiles_y = -(-W // T), -(-H // T)
        for lo, nt, dvals, rstart, rend, total in tile_bands(
            splats, order, n, T, tiles_x, tiles_y, s.max_duplicates, stats, dev, threads
        ):
            if total == 0:
                continue
            common = [
                splats,
                dvals,
                rstart,
                rend,
                cam,
                inv_var,
                float(s.alpha_max),
                bp,
                T,
                tiles_x,
                lo,
                pos_dev,
            ]
            # interleave: CPU sub-launch j gets base = j, i.e. its own accumulator row
            if mode == "pixel":
                launch_split(
                    contrib_pixel_kernel,
                    nt * T * T,
                    common + [rows1, rows0],
                    dev,
                    threads,
                    mode="interleave",
                )
            else:
                launch_split(
                    contrib_tile_kernel,
                    nt,
                    common + [states, rows1, rows0],
                    dev,
                    threads,
                    mode="interleave",
                )
        launch_split(_sum_rows_kernel, n, [rows1, a1], dev, threads)
        launch_split(_sum_rows_kernel, n, [rows0, a0], dev, threads)
    return ContribOutput(a1, a0, stats)

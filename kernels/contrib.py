"""Per-surfel blending contributions split by a binary view mask (evaluation baseline).

For one view with a binary mask ``B`` (``[H, W]``), every surfel ``i`` gets

    A₁[i] = Σ_{p: B[p]=1} w_{i,p},     A₀[i] = Σ_{p: B[p]=0} w_{i,p},

with ``w_{i,p} = α_{i,p} T_{i,p}`` the front-to-back blending weight of surfel ``i`` at
pixel ``p`` — exactly the weight the rasterizer gives it (``render_values`` composites
``Σ_i w_{i,p} v_i``). This is the per-primitive accumulation of contribution-weighted
voting in the style of FlashSplat (ECCV 2024): a Gaussian is foreground when it
contributes more to mask-positive than to mask-negative pixels.

It reuses the rasterizer entirely: its preprocessing and depth sort
(:func:`kernels.rasterize.project_splats`), its tile binning (:mod:`kernels.tile_binning`)
and its tile walk (:mod:`kernels.tile_walk`: the ray–splat evaluation and the compositing
step, so early termination and ``α_min`` skipping are the renderer's). Only the per-pair
action differs (the walk's :class:`~kernels.tile_walk.ContribSink`): instead of adding
``w · feat`` to the pixel, ``w`` is atomically added to the surfel's ``A₁`` or ``A₀``.

Two walk forms, as in the rasterizer: ``pixel`` (one thread per pixel, the GPU form,
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

from ._launch import launch_split
from .composite import PixState
from .rasterize import (
    RasterSettings,
    SurfelBuffers,
    ViewBinning,
    binning_key,
    blend_params,
    check_view,
    project_splats,
)
from .splat import make_raster_camera
from .tile_binning import sort_visible, tile_bands, visible_splats
from .tile_walk import ContribSink, launch_walk

wp.set_module_options({"enable_backward": False})

__all__ = ["ContribOutput", "accumulate_contributions"]


# --------------------------------------------------------------------------- kernels
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
    *,
    binning: ViewBinning | None = None,
    window: tuple[int, int, int, int] | None = None,
) -> ContribOutput:
    """A₁ / A₀ of every surfel of ``buf`` for one view (OpenCV pinhole, ``w2c`` 4×4).

    Args:
        positive: ``[H, W]`` (or ``[H·W]``) mask, nonzero = mask-positive pixel.
        settings: the rasterizer's settings (same defaults: α_min, α_max, T_min, near,
            low-pass σ, tile, blend form, threads).
        binning: a :class:`~kernels.rasterize.ViewBinning` a render of this view kept
            (same buffers, camera and settings, :func:`~kernels.rasterize.binning_key`):
            its projection, depth order and tiles are reused and only the walk runs —
            the same kernels on the same inputs, so the sums are those of a fresh pass;
            ignored when its key does not match (and with a ``window``).
        window: ``(x0, y0, x1, y1)`` (half-open): walk only these pixels, as
            :func:`~kernels.rasterize.rasterize_surfels`' ``window`` — surfels whose
            bounds miss it are culled and bounds are clipped to it, tiles keep their image
            numbers. So each surfel's weights at the window's pixels are the whole pass's,
            summed in the same per-thread rows and tile order (while both passes walk the
            image in one band): a surfel whose footprint lies inside the window gets the
            whole pass's A₁ / A₀ bit for bit; one reaching beyond it only its window's part.
    Returns:
        :class:`ContribOutput` on ``buf.device``.
    """
    if window is not None:
        binning = None
    return _accumulate(buf, w2c, fx, fy, cx, cy, width, height, positive, settings, binning, window)


def _accumulate(
    buf, w2c, fx, fy, cx, cy, width, height, positive, settings, binning, window=None
) -> ContribOutput:
    s = settings or RasterSettings()
    dev = buf.device
    n = len(buf)
    W, H = int(width), int(height)
    mode, T, threads = check_view("accumulate_contributions", W, H, s, dev)
    pos = np.asarray(positive)
    if pos.size != W * H:
        raise ValueError(f"accumulate_contributions: mask has {pos.size} pixels, the view {W}x{H}")
    if binning is not None and binning.key != binning_key(buf, w2c, fx, fy, cx, cy, W, H, s):
        binning = None
    cam = (
        binning.cam
        if binning is not None
        else make_raster_camera(
            np.asarray(w2c, dtype=np.float64), fx, fy, cx, cy, W, H, s.near, window
        )
    )
    inv_var = 1.0 / float(s.lowpass_sigma) ** 2
    P = W * H
    stats = {"surfels": n, "pairs": 0, "bands": 0, "mode": mode, "reused": binning is not None}
    with wp.ScopedDevice(dev):
        a1 = wp.zeros(n, dtype=float)
        a0 = wp.zeros(n, dtype=float)
        if n == 0:
            return ContribOutput(a1, a0, stats)
        sink = ContribSink()
        sink.positive = wp.array(
            np.ascontiguousarray(pos.reshape(-1) != 0, dtype=np.uint8), dtype=wp.uint8
        )
        sink.a1 = rows1 = wp.zeros((threads, n), dtype=float)
        sink.a0 = rows0 = wp.zeros((threads, n), dtype=float)
        tiles_x, tiles_y = -(-W // T), -(-H // T)
        if binning is None:
            splats, keys = project_splats(buf, cam, inv_var, None, threads)
            order, n_vis = sort_visible(keys, n, dev, threads)
            splats, ids = visible_splats(splats, order, n_vis, dev, threads)
        else:
            splats, ids, n_vis = binning.splats, binning.ids, binning.n_visible
        if binning is not None and binning.bands is not None:
            bands = iter(binning.bands)
            stats["pairs"], stats["bands"] = binning.stats["pairs"], binning.stats["bands"]
        else:
            bands = tile_bands(
                splats, n_vis, T, tiles_x, tiles_y, s.max_duplicates, stats, dev, threads
            )
        states = wp.empty(P, dtype=PixState) if mode == "tile" else None
        bp = blend_params(s)
        for lo, nt, dvals, rstart, rend, total in bands:
            if total == 0:
                continue
            # interleave: CPU sub-launch j gets base = j, i.e. its own accumulator row
            args = (splats, ids, dvals, rstart, rend, cam, inv_var, float(s.alpha_max), bp, T,
                    tiles_x)  # fmt: skip
            launch_walk(mode, sink, *args, lo, nt, states, dev, threads, "interleave")
        launch_split(_sum_rows_kernel, n, [rows1, a1], dev, threads)
        launch_split(_sum_rows_kernel, n, [rows0, a0], dev, threads)
    return ContribOutput(a1, a0, stats)

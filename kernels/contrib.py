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
from .tile_walk import ContribSink, launch_walk, walk_tile_kernel

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


@wp.kernel
def _slot_kernel(
    ids: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32),
    out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """``out[j] = slot[ids[j]]``: a visible splat's accumulator slot (its target's
    position, or the shared dump slot ``K`` of every other surfel)."""
    j = base + wp.tid() * stride
    out[j] = slot[ids[j]]


@wp.kernel
def _last_target_kernel(
    vals: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.int32),
    dump: int,
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Per tile: the end of its depth-ordered list cut right after its last target
    (``slots != dump``); a tile without a target gets an empty list."""
    t = base + wp.tid() * stride
    a = rstart[t]
    e = rend[t]
    while e > a:
        if slots[vals[e - 1]] != dump:
            break
        e = e - 1
    out[t] = e


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
    rows: np.ndarray | None = None,
    targets: np.ndarray | None = None,
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
        rows: project only these surfels of ``buf`` (ascending; the others are culled) —
            as a scene of their own in the scene's order (ties in depth break the same
            way): sums are indexed by position in ``rows``. Ignored with a ``binning``.
        targets: only the sums of these surfels (ascending; surfel indices, or positions
            in ``rows``) are wanted: the output holds ``[len(targets)]`` sums, every other
            surfel adds into one shared dump slot, and each tile's depth-ordered list is
            walked only up to its last target (a tile without one not at all). What a
            target's weight depends on — the surfels before it at its pixels, in the same
            order — is walked as before, in the same tiles, accumulator rows and tile
            order, so each target's sums are those of the pass without ``targets`` bit for
            bit (issue 15: the completion's gather from a kept view binning).
    Returns:
        :class:`ContribOutput` on ``buf.device`` (``[len(targets)]`` with ``targets``).
    """
    if window is not None or rows is not None:
        binning = None
    return _accumulate(
        buf, w2c, fx, fy, cx, cy, width, height, positive, settings, binning, window, rows, targets
    )


def _accumulate(
    buf, w2c, fx, fy, cx, cy, width, height, positive, settings, binning, window=None,
    rows=None, targets=None,
) -> ContribOutput:  # fmt: skip
    s = settings or RasterSettings()
    dev = buf.device
    n = len(buf) if rows is None else len(rows)
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
    stats["walked"] = 0  # (tile, surfel) pairs walked
    # accumulator slots: one per surfel, or one per target plus the dump slot K
    k = n if targets is None else len(targets)
    with wp.ScopedDevice(dev):
        a1 = wp.zeros(k, dtype=float)
        a0 = wp.zeros(k, dtype=float)
        if n == 0 or k == 0:
            return ContribOutput(a1, a0, stats)
        sink = ContribSink()
        sink.positive = wp.array(
            np.ascontiguousarray(pos.reshape(-1) != 0, dtype=np.uint8), dtype=wp.uint8
        )
        sink.a1 = rows1 = wp.zeros((threads, k + (targets is not None)), dtype=float)
        sink.a0 = rows0 = wp.zeros((threads, k + (targets is not None)), dtype=float)
        tiles_x, tiles_y = -(-W // T), -(-H // T)
        if binning is None:
            sel = None if rows is None else wp.array(np.asarray(rows, np.int32), dtype=wp.int32)
            splats, keys = project_splats(buf, cam, inv_var, None, threads, rows=sel)
            order, n_vis = sort_visible(keys, n, dev, threads)
            splats, ids = visible_splats(splats, order, n_vis, dev, threads)
        else:
            splats, ids, n_vis = binning.splats, binning.ids, binning.n_visible
        if targets is not None:  # the walk adds into slots, not surfel indices
            ids = _target_slots(ids, n_vis, n, targets, dev, threads)
        if binning is not None and binning.bands is not None:
            bands = iter(binning.bands)
            stats["pairs"], stats["bands"] = binning.stats["pairs"], binning.stats["bands"]
        else:
            bands = tile_bands(
                splats, n_vis, T, tiles_x, tiles_y, s.max_duplicates, stats, dev, threads
            )
        states = wp.empty(P, dtype=PixState) if mode == "tile" else None
        bp = blend_params(s)
        walked = 0
        for lo, nt, dvals, rstart, rend, total in bands:
            if total == 0:
                continue
            span = None
            if targets is not None:  # each tile's list up to its last target only
                cut = wp.empty(nt, dtype=wp.int32)
                launch_split(
                    _last_target_kernel, nt, [dvals, ids, k, rstart, rend, cut], dev, threads
                )
                rend = cut
                left = cut.numpy() - rstart.numpy()
                walked += int(left.sum())
                busy = np.flatnonzero(left)
                if len(busy) == 0:
                    continue
                span = (int(busy[0]), int(busy[-1]) + 1)  # the tiles that hold targets
            # interleave: CPU sub-launch j gets base = j, i.e. its own accumulator row
            args = (splats, ids, dvals, rstart, rend, cam, inv_var, float(s.alpha_max), bp, T,
                    tiles_x)  # fmt: skip
            if span is not None and mode == "tile":
                # only the range of tiles that hold targets, each tile in the sub-launch
                # (accumulator row) and order it has in the whole walk
                launch_split(
                    walk_tile_kernel, nt, [*args, lo, states, sink], dev, threads,
                    "interleave", items=span,
                )  # fmt: skip
            else:
                launch_walk(mode, sink, *args, lo, nt, states, dev, threads, "interleave")
        stats["walked"] = walked if targets is not None else stats["pairs"]
        launch_split(_sum_rows_kernel, k, [rows1, a1], dev, threads)
        launch_split(_sum_rows_kernel, k, [rows0, a0], dev, threads)
    return ContribOutput(a1, a0, stats)


def _target_slots(ids: wp.array, n_vis: int, n: int, targets, dev, threads: int) -> wp.array:
    """Per visible splat (depth rank) the accumulator slot of its surfel ``ids[j]``
    (``< n``): its position in ``targets``, or ``len(targets)`` (the dump slot)."""
    t = np.asarray(targets, np.int64)
    if len(t) and (t[0] < 0 or t[-1] >= n or np.any(t[1:] <= t[:-1])):
        raise ValueError("accumulate_contributions: targets must be ascending indices < N")
    host = np.full(n, len(t), np.int32)
    host[t] = np.arange(len(t), dtype=np.int32)
    out = wp.empty(max(n_vis, 1), dtype=wp.int32, device=dev)
    slot = wp.array(host, dtype=wp.int32, device=dev, copy=not dev.is_cpu)  # CPU: aliased
    launch_split(_slot_kernel, n_vis, [ids, slot, out], dev, threads)
    del host
    return out

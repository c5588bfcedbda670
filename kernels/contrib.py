"""Per-surfel blending contributions split by a binary view mask (evaluation baseline).

For one view with a binary mask ``B`` every surfel ``i`` gets

    A₁[i] = Σ_{p: B[p]=1} w_{i,p},     A₀[i] = Σ_{p: B[p]=0} w_{i,p},

with ``w_{i,p} = α_{i,p} T_{i,p}`` the rasterizer's own blending weight (contribution-weighted
voting in the style of FlashSplat). It reuses the rasterizer's projection, binning and tile walk
(:class:`~divas_kernels.tile_walk.ContribSink` adds ``w`` to ``A₁`` or ``A₀``). On the CPU each
concurrent sub-launch owns one row of ``[threads, N]`` accumulators (Warp's CPU ``atomic_add``
is a plain add); the rows are summed at the end. Details: docs/design-notes.md.
"""

from __future__ import annotations

import threading
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
from .splat import RasterCamera, Splat, make_raster_camera, row_span, splat_alpha
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
    dump: int,
    out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """``out[j]``: the accumulator slot of visible splat ``j``'s surfel for the generic
    walk — its target position ``slot[ids[j]]``, or the shared dump slot."""
    j = base + wp.tid() * stride
    k = slot[ids[j]]
    if k < 0:
        k = dump
    out[j] = k


@wp.kernel
def _last_target_kernel(
    vals: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    slot: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Per tile: the end of its depth-ordered list cut right after its last target
    (``slot[surfel] >= 0``); a tile without a target gets an empty list."""
    t = base + wp.tid() * stride
    a = rstart[t]
    e = rend[t]
    while e > a:
        if slot[ids[vals[e - 1]]] >= 0:
            break
        e = e - 1
    out[t] = e


@wp.kernel
def _walk_weights_kernel(
    splats: wp.array(dtype=Splat),
    ids: wp.array(dtype=wp.int32),
    vals: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    alpha_min: float,
    t_min: float,
    tile: int,
    tiles_x: int,
    band_lo: int,
    trans: wp.array(dtype=float),
    positive: wp.array(dtype=wp.uint8),
    slot: wp.array(dtype=wp.int32),
    use_slot: int,
    a1: wp.array2d(dtype=float),
    a0: wp.array2d(dtype=float),
    base: int,
    stride: int,
):
    """The tile walk (:data:`divas_kernels.tile_walk.walk_tile_kernel`, CPU form) reduced to
    what a contribution needs: per pixel only the transmittance ``T`` (``trans``; ``-1``
    once the pixel is done), not the depth tuple's state. The pair's weight ``w = α T``
    and the update ``T ← T (1 − α)`` are :func:`divas_kernels.composite.blend_step`'s float
    operations on the same operands, and a pixel is done exactly when that step sets
    ``FLAG_DONE`` (``T < T_min`` after a blend; ``T`` starts at 1 and never grows), so
    every ``w`` is the generic walk's bit for bit. ``w`` is added to row ``base`` of
    ``a1`` / ``a0`` at the surfel's slot: ``slot[i]`` (``use_slot``; ``-1``: not a
    target, nothing added) or ``i``."""
    t = base + wp.tid() * stride
    row = base % a1.shape[0]
    X0 = (t % tiles_x) * tile
    Y0 = (t // tiles_x + band_lo) * tile
    X1 = wp.min(X0 + tile, cam.width) - 1
    Y1 = wp.min(Y0 + tile, cam.height) - 1
    W = cam.width
    for y in range(Y0, Y1 + 1):
        for x in range(X0, X1 + 1):
            trans[y * W + x] = 1.0
    npix = (X1 - X0 + 1) * (Y1 - Y0 + 1)
    ndone = int(0)
    for e in range(int(rstart[t]), int(rend[t])):
        j = vals[e]  # depth rank: the visible splats are stored in depth order
        sp = splats[j]
        i = ids[j]
        if use_slot != 0:
            i = slot[i]
        xa = wp.max(sp.x0, X0)
        xb = wp.min(sp.x1, X1)
        ya = wp.max(sp.y0, Y0)
        yb = wp.min(sp.y1, Y1)
        for y in range(ya, yb + 1):
            py = float(y) + 0.5
            xs, xe = row_span(sp, py, cam.fx, cam.fy, xa, xb)
            for x in range(xs, xe + 1):
                p = y * W + x
                T = trans[p]
                if T >= 0.0:
                    px = float(x) + 0.5
                    alpha, z = splat_alpha(sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near)
                    if alpha >= alpha_min:
                        w = alpha * T
                        T = T * (1.0 - alpha)
                        if T < t_min:
                            T = -1.0
                            ndone += 1
                        trans[p] = T
                        if i >= 0:
                            if positive[p] != wp.uint8(0):
                                a1[row, i] = a1[row, i] + w
                            else:
                                a0[row, i] = a0[row, i] + w
        if ndone == npix:
            break


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
        binning: a :class:`~divas_kernels.rasterize.ViewBinning` a render of this view kept
            (same buffers, camera and settings, :func:`~divas_kernels.rasterize.binning_key`):
            its projection, depth order and tiles are reused and only the walk runs —
            the same kernels on the same inputs, so the sums are those of a fresh pass;
            ignored when its key does not match (and with a ``window``).
        window: ``(x0, y0, x1, y1)`` (half-open): walk only these pixels, as
            :func:`~divas_kernels.rasterize.rasterize_surfels`' ``window`` — surfels whose
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
            order — is walked unchanged, in the same tiles, accumulator rows and tile
            order, so each target's sums are those of the pass without ``targets`` bit for
            bit (the completion's gather from a kept view binning).
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
    rows=None, targets=None, generic=False,
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
    stats = {"surfels": n, "pairs": 0, "bands": 0, "mode": mode, "reused": binning is not None}
    stats["walked"] = 0  # (tile, surfel) pairs walked
    # accumulator slots: one per surfel, or one per target (the generic walk: plus the
    # dump slot K every other surfel adds into)
    k = n if targets is None else len(targets)
    fast = mode == "tile" and not generic  # the transmittance-only walk (CPU form)
    with wp.ScopedDevice(dev):
        a1 = wp.zeros(k, dtype=float)
        a0 = wp.zeros(k, dtype=float)
        if n == 0 or k == 0:
            return ContribOutput(a1, a0, stats)
        table = _SlotTable.take(n, targets, dev) if targets is not None else None
        try:
            _walk(buf, cam, W, H, s, mode, T, threads, n, k, pos, binning, rows, table, fast,
                  stats, a1, a0)  # fmt: skip
        finally:
            if table is not None:
                table.give_back()
    return ContribOutput(a1, a0, stats)


def _walk(
    buf, cam, W, H, s, mode, T, threads, n, k, pos, binning, rows, table, fast, stats, a1, a0
) -> None:
    """Project/sort/bin (unless a kept ``binning``) and walk: the body of
    :func:`accumulate_contributions` (``table``: the targets' :class:`_SlotTable`)."""
    dev = buf.device
    P = W * H
    inv_var = 1.0 / float(s.lowpass_sigma) ** 2
    positive = wp.array(np.ascontiguousarray(pos.reshape(-1) != 0, dtype=np.uint8), dtype=wp.uint8)
    extra = 0 if fast or table is None else 1  # the generic walk's dump slot
    rows1 = wp.zeros((threads, k + extra), dtype=float)
    rows0 = wp.zeros((threads, k + extra), dtype=float)
    tiles_x, tiles_y = -(-W // T), -(-H // T)
    if binning is None:
        sel = None if rows is None else wp.array(np.asarray(rows, np.int32), dtype=wp.int32)
        splats, keys = project_splats(buf, cam, inv_var, None, threads, rows=sel)
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
    slot = table.arr if table is not None else wp.zeros(1, dtype=wp.int32)
    if fast:
        trans = wp.empty(P, dtype=float)
    else:
        sink = ContribSink()
        sink.positive, sink.a1, sink.a0 = positive, rows1, rows0
        states = wp.empty(P, dtype=PixState) if mode == "tile" else None
        bp = blend_params(s)
        sids = ids
        if table is not None:  # the generic walk adds into per-rank slots (dump: k)
            sids = wp.empty(max(n_vis, 1), dtype=wp.int32)
            launch_split(_slot_kernel, n_vis, [ids, slot, k, sids], dev, threads)
    walked = 0
    for lo, nt, dvals, rstart, rend, total in bands:
        if total == 0:
            continue
        span = None
        if table is not None:  # each tile's list up to its last target only
            cut = wp.empty(nt, dtype=wp.int32)
            launch_split(
                _last_target_kernel, nt, [dvals, ids, slot, rstart, rend, cut], dev, threads
            )
            rend = cut
            left = cut.numpy() - rstart.numpy()
            walked += int(left.sum())
            busy = np.flatnonzero(left)
            if len(busy) == 0:
                continue
            span = (int(busy[0]), int(busy[-1]) + 1)  # the tiles that hold targets
        # interleave: CPU sub-launch j gets base = j, i.e. its own accumulator row; with a
        # span only the range of tiles that hold targets runs, each tile in the
        # sub-launch (accumulator row) and order it has in the whole walk
        if fast:
            launch_split(
                _walk_weights_kernel, nt,
                [splats, ids, dvals, rstart, rend, cam, inv_var, float(s.alpha_max),
                 float(s.alpha_min), float(s.t_min), T, tiles_x, lo, trans, positive, slot,
                 int(table is not None), rows1, rows0],
                dev, threads, "interleave", items=span,
            )  # fmt: skip
            continue
        args = (splats, sids, dvals, rstart, rend, cam, inv_var, float(s.alpha_max), bp, T,
                tiles_x)  # fmt: skip
        if span is not None and mode == "tile":
            launch_split(
                walk_tile_kernel, nt, [*args, lo, states, sink], dev, threads,
                "interleave", items=span,
            )  # fmt: skip
        else:
            launch_walk(mode, sink, *args, lo, nt, states, dev, threads, "interleave")
    stats["walked"] = walked if table is not None else stats["pairs"]
    launch_split(_sum_rows_kernel, k, [rows1, a1], dev, threads)
    launch_split(_sum_rows_kernel, k, [rows0, a0], dev, threads)


class _SlotTable:
    """``[N] int32``: each target's position in ``targets``, ``-1`` for every other
    surfel. On the CPU one table per scene size is kept (reset after each pass: ``O(K)``
    per call instead of filling ``N`` entries); a pass that finds it in use by another
    thread, and every pass on CUDA, makes its own."""

    _kept: dict[tuple[str, int], np.ndarray] = {}
    _lock = threading.Lock()

    def __init__(self, host: np.ndarray, arr: wp.array, idx: np.ndarray, kept: bool):
        self.host, self.arr, self.idx, self.kept = host, arr, idx, kept

    @classmethod
    def take(cls, n: int, targets, dev) -> _SlotTable:
        t = np.asarray(targets, np.int64)
        if len(t) and (t[0] < 0 or t[-1] >= n or np.any(t[1:] <= t[:-1])):
            raise ValueError("accumulate_contributions: targets must be ascending indices < N")
        host = None
        if dev.is_cpu and cls._lock.acquire(blocking=False):
            host = cls._kept.get((str(dev), n))
            if host is None:
                cls._kept.clear()  # one scene size at a time
                host = cls._kept[(str(dev), n)] = np.full(n, -1, np.int32)
        kept = host is not None
        if host is None:
            host = np.full(n, -1, np.int32)
        host[t] = np.arange(len(t), dtype=np.int32)
        arr = wp.array(host, dtype=wp.int32, device=dev, copy=not dev.is_cpu)  # CPU: aliased
        return cls(host, arr, t, kept)

    def give_back(self) -> None:
        if self.kept:
            self.host[self.idx] = -1
            type(self)._lock.release()

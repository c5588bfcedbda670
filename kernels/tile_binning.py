"""Tile binning of depth-sorted splats, shared by every pass that walks tiles
(the rasterizer's blend, ``divas_kernels.rasterize``, and the contribution pass,
``divas_kernels.contrib``), so all of them see the same (tile, surfel) lists.

Per band of tile rows: count the tiles each splat touches (in depth order), exclusive
scan, duplicate into (band-local tile id, surfel) pairs, stable radix sort on the tile
bits (depth order survives within a tile) and find each tile's range. A band holding
more than ``max_duplicates`` pairs is split in two (bounded memory on huge scenes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import warp as wp

from ._launch import launch_split
from .scratch import scratch_empty
from .splat import BIG, RasterCamera, Splat, pixel_window

wp.set_module_options({"enable_backward": False})

__all__ = [
    "ViewBinning",
    "band_tiles",
    "binning_key",
    "depth_ranks",
    "gather_rows",
    "sort_visible",
    "take_rows",
    "tile_bands",
    "visible_splats",
]


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
    tile: int,
    band_lo: int,
    band_hi: int,
    counts: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Tiles touched in the band by the ``j``-th visible surfel in depth order."""
    j = base + wp.tid() * stride
    tx0, tx1, ty0, ty1 = band_tiles(splats[j], tile, band_lo, band_hi)
    n = int(0)
    if tx0 <= tx1:
        n = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
    counts[j] = wp.int32(n)


@wp.kernel
def duplicate_kernel(
    splats: wp.array(dtype=Splat),
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
    """Emit one (band-local tile id, depth rank) pair per touched tile, in depth order."""
    j = base + wp.tid() * stride
    tx0, tx1, ty0, ty1 = band_tiles(splats[j], tile, band_lo, band_hi)
    o = int(incl[j]) - int(counts[j])  # exclusive offset
    if tx0 <= tx1:
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                keys[o] = wp.int32((ty - band_lo) * tiles_x + tx)
                vals[o] = wp.int32(j)
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


@wp.kernel
def _flag_kernel(
    keys: wp.array(dtype=float), flags: wp.array(dtype=wp.int32), base: int, stride: int
):
    i = base + wp.tid() * stride
    flags[i] = wp.int32(0)
    if keys[i] < 0.5 * BIG:
        flags[i] = wp.int32(1)


@wp.kernel
def _scatter_kernel(
    keys: wp.array(dtype=float),
    flags: wp.array(dtype=wp.int32),
    incl: wp.array(dtype=wp.int32),
    out_keys: wp.array(dtype=float),
    out_ids: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    i = base + wp.tid() * stride
    if flags[i] != 0:
        p = incl[i] - 1
        out_keys[p] = keys[i]
        out_ids[p] = wp.int32(i)


def sort_visible(keys: wp.array, n: int, dev, threads: int) -> tuple[wp.array, int]:
    """``(order, n_vis)``: the surfels whose key is not culled (``< BIG``), stably sorted by
    key (ties: index order). They are compacted in index order first and only they are
    radix-sorted — the prefix a stable sort of all ``n`` keys would give (culled keys are
    ``BIG``, after every depth), at the cost of the visible ones (a probe sees a few
    percent of a large scene; the radix sort runs on one CPU thread)."""
    flags = scratch_empty(max(n, 1), wp.int32, dev)
    incl = scratch_empty(max(n, 1), wp.int32, dev)
    n_vis = 0
    if n > 0:
        launch_split(_flag_kernel, n, [keys, flags], dev, threads)
        wp.utils.array_scan(flags, incl, inclusive=True)
        n_vis = int(incl[n - 1 : n].numpy()[0])
    out_keys = scratch_empty(2 * max(n_vis, 1), float, dev)
    order = scratch_empty(2 * max(n_vis, 1), wp.int32, dev)
    if n_vis > 0:
        launch_split(_scatter_kernel, n, [keys, flags, incl, out_keys, order], dev, threads)
        wp.utils.radix_sort_pairs(out_keys, order, n_vis)
    return order, n_vis


@wp.kernel
def _gather_kernel(
    splats: wp.array(dtype=Splat),
    order: wp.array(dtype=wp.int32),
    rows: wp.array(dtype=wp.int32),
    use_rows: int,
    out: wp.array(dtype=Splat),
    ids: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    j = base + wp.tid() * stride
    i = order[j]
    out[j] = splats[i]
    if use_rows != 0:
        ids[j] = rows[i]
    else:
        ids[j] = i


@wp.kernel
def _take_kernel(
    rows: wp.array(dtype=wp.int32),
    use_rows: int,
    order: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    j = base + wp.tid() * stride
    if use_rows != 0:
        ids[j] = rows[order[j]]
    else:
        ids[j] = order[j]


def take_rows(rows: wp.array | None, order: wp.array, n_vis: int, dev, threads: int) -> wp.array:
    """``ids [n_vis]``: the surfel indices of the visible prefix of the depth order
    ``order`` (``rows[order[j]]`` when the keys were those of the surfels ``rows``)."""
    ids = scratch_empty(max(n_vis, 1), wp.int32, dev, kept=True)
    if n_vis > 0:
        use = 0 if rows is None else 1
        r = rows if rows is not None else wp.empty(1, dtype=wp.int32, device=dev)
        launch_split(_take_kernel, n_vis, [r, use, order, ids], dev, threads)
    return ids


def visible_splats(
    splats: wp.array, order: wp.array, n_vis: int, dev, threads: int, rows: wp.array | None = None
):
    """``(splats [n_vis], ids [n_vis])``: the visible prefix of the depth order ``order``
    gathered by depth rank ``j`` (``ids[j]`` its surfel index: ``rows[order[j]]`` when the
    splats are those of the surfels ``rows``). Binning and walks read these, so a kept
    view holds only its visible splats (92 bytes each; a centroid view sees a fraction
    of the scene) and reads them in order."""
    out = scratch_empty(max(n_vis, 1), Splat, dev, kept=True)
    ids = scratch_empty(max(n_vis, 1), wp.int32, dev, kept=True)
    if n_vis > 0:
        use = 0 if rows is None else 1
        r = rows if rows is not None else wp.empty(1, dtype=wp.int32, device=dev)
        launch_split(_gather_kernel, n_vis, [splats, order, r, use, out, ids], dev, threads)
    return out, ids


@wp.kernel
def _gather_rows_kernel(
    src: wp.array2d(dtype=float),
    ids: wp.array(dtype=wp.int32),
    out: wp.array2d(dtype=float),
    base: int,
    stride: int,
):
    j = base + wp.tid() * stride
    i = ids[j]
    for c in range(src.shape[1]):
        out[j, c] = src[i, c]


def gather_rows(src: wp.array, ids: wp.array, n_vis: int, dev, threads: int, kept: bool):
    """``out [n_vis, C]``: ``out[j] = src[ids[j]]`` — per-surfel rows in depth order."""
    out = scratch_empty((max(n_vis, 1), src.shape[1]), float, dev, kept=kept)
    if n_vis > 0 and src.shape[1] > 0:
        launch_split(_gather_rows_kernel, n_vis, [src, ids, out], dev, threads)
    return out


@wp.kernel
def _rank_kernel(
    order: wp.array(dtype=wp.int32), rank: wp.array(dtype=wp.int32), base: int, stride: int
):
    j = base + wp.tid() * stride
    rank[order[j]] = j


def depth_ranks(order: wp.array, n_vis: int, n: int, dev, threads: int) -> wp.array:
    """``rank [n]``: ``rank[order[j]] = j`` for the ``n_vis`` visible items of the depth
    order ``order`` (:func:`divas_kernels.tile_binning.sort_visible`), −1 for the culled ones
    (the second pass skips them before projecting: half of a wide 3M view)."""
    rank = scratch_empty(max(n, 1), wp.int32, dev)
    rank.fill_(-1)
    if n_vis > 0:
        launch_split(_rank_kernel, n_vis, [order, rank], dev, threads)
    return rank


def tile_bands(
    splats: wp.array,
    n: int,
    T: int,
    tiles_x: int,
    tiles_y: int,
    max_duplicates: int,
    stats: dict,
    dev,
    threads: int,
    lap: Callable[[str], None] | None = None,
):
    """Bin depth-sorted splats into tiles, one band of tile rows at a time.

    Per band: count the tiles each splat touches, scan, split the band in two while it
    holds more than ``max_duplicates`` (splat, tile) pairs (bounded memory), duplicate
    keys, sort them by tile (stable, so depth order survives) and find each tile's range.
    Yields ``(band_lo, n_tiles, sorted_splat_ids, range_start, range_end, pairs)``; also
    used by the contribution pass (``divas_kernels.contrib``) so both see the same binning.

    ``splats[:n]``: the visible splats in depth order (:func:`visible_splats`; culled
    splats touch no tile, so leaving them out changes no pair); the pairs hold depth
    ranks ``j`` (the walks map them to surfels through ``ids``).
    """
    lap = lap or (lambda _stage: None)
    counts = scratch_empty(max(n, 1), wp.int32)
    incl = scratch_empty(max(n, 1), wp.int32)
    bands = [(0, tiles_y)]
    while bands:
        lo, hi = bands.pop(0)
        total = 0
        if n > 0:
            launch_split(count_kernel, n, [splats, T, lo, hi, counts], dev, threads)
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
            dkeys = scratch_empty(2 * total, wp.int32)
            dvals = scratch_empty(2 * total, wp.int32, kept=True)  # a binning's bands
            launch_split(
                duplicate_kernel,
                n,
                [splats, T, lo, hi, tiles_x, incl, counts, dkeys, dvals],
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


@dataclass(eq=False)
class ViewBinning:
    """Projection, culling, depth order and tile binning of one view, reusable by every
    later pass over the same camera, settings and scene (the RGB/depth render and the
    value renders of a camera share them; the results are bit-identical, the
    same kernels running on the same inputs).

    Attributes:
        key: what the binning depends on (scene buffers, camera, settings).
        splats, ids: the visible splats in depth order and their surfel indices
            (:func:`divas_kernels.tile_binning.visible_splats`; only these are kept).
        n_visible: how many surfels are not culled
            (:func:`~divas_kernels.tile_binning.sort_visible`).
        bands: the band list of :func:`divas_kernels.tile_binning.tile_bands` when the view
            fits in one band, else None (each pass re-bins band by band: bounded memory).
        colors: ``[N, 3]`` SH colours when an RGB render made it, else None.
        stats: pairs and bands.
    """

    key: tuple
    cam: RasterCamera
    splats: wp.array
    ids: wp.array
    n_visible: int
    bands: list | None
    colors: wp.array | None
    stats: dict

    @property
    def nbytes(self) -> int:
        arrs = [self.splats, self.ids, self.colors]
        for b in self.bands or ():
            arrs += [b[2], b[3], b[4]]
        return sum(a.capacity for a in arrs if a is not None)


def binning_key(buf, w2c, fx, fy, cx, cy, W, H, s, window=None) -> tuple:
    """What a :class:`ViewBinning` depends on (the blend-only settings excluded)."""
    w = np.ascontiguousarray(w2c, dtype=np.float64).tobytes()
    geo = (float(fx), float(fy), float(cx), float(cy), int(W), int(H))
    geo += pixel_window(window, W, H)
    cfg = (float(s.near), float(s.lowpass_sigma), int(s.tile), int(s.max_duplicates))
    return (id(buf), w, geo, cfg)

"""The one tile walk of the 2DGS rasterizer, shared by every pass over the binned
(tile, surfel) lists of ``divas_kernels.tile_binning``: the blend (``divas_kernels.rasterize``)
and the per-surfel contribution pass (``divas_kernels.contrib``).

For every pixel the surfels of its tile are visited in (centre depth, index) order;
:func:`divas_kernels.splat.splat_alpha` then :func:`divas_kernels.composite.blend_step` give the
pair's weight ``w = α T`` and a *sink* says what the pass does with it: :class:`BlendSink` adds
``w · feat`` to the pixel, :class:`ContribSink` adds ``w`` to surfel ``i``'s A₁ or A₀ row.

Two walk forms, generic over the sink and bit-identical: :data:`walk_pixel_kernel` (one thread
per pixel, GPU) and :data:`walk_tile_kernel` (one thread per tile walking each surfel's row
spans ∩ tile, CPU: work scales with covered pixels). A new pass adds a sink struct, its
``sink_pair`` / ``sink_finish`` overloads and one :func:`wp.overload` per walk form.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ._launch import launch_split
from .composite import (
    FLAG_DONE,
    BlendParams,
    PixelOut,
    PixState,
    blend_step,
    finish_pixel,
    state_init,
)
from .splat import RasterCamera, Splat, row_span, splat_alpha

# forward only: no adjoint code (halves compile time)
wp.set_module_options({"enable_backward": False})

__all__ = [
    "BlendSink",
    "ContribSink",
    "walk_pixel_kernel",
    "walk_tile_kernel",
    "launch_walk",
]


#: per-row counters of one tile (tiles are at most 64 pixels a side: ``check_view``)
RowCounts = wp.types.vector(length=64, dtype=wp.int32)


# --------------------------------------------------------------------------- sinks
@wp.struct
class BlendSink:
    """Blend pass: per-surfel features ``feat [N, C]`` (or ``[n_visible, C]`` in depth
    order: ``by_rank`` 1) composited into ``out``."""

    feat: wp.array2d(dtype=float)
    out: PixelOut
    by_rank: int


@wp.struct
class ContribSink:
    """Contribution pass: ``positive [P]`` mask, ``a1``/``a0`` ``[rows, N]`` sums."""

    positive: wp.array(dtype=wp.uint8)
    a1: wp.array2d(dtype=float)
    a0: wp.array2d(dtype=float)


@wp.func
def sink_pair(sink: BlendSink, base: int, i: int, j: int, p: int, w: float):
    # the features in depth order are read in the walk's order (read by surfel index
    # they would be scattered over the whole array)
    row = i
    if sink.by_rank != 0:
        row = j
    for c in range(sink.feat.shape[1]):
        sink.out.feat[p, c] = sink.out.feat[p, c] + w * sink.feat[row, c]


@wp.func
def sink_pair(sink: ContribSink, base: int, i: int, j: int, p: int, w: float):  # noqa: F811
    row = base % sink.a1.shape[0]
    if sink.positive[p] != wp.uint8(0):
        wp.atomic_add(sink.a1, row, i, w)
    else:
        wp.atomic_add(sink.a0, row, i, w)


@wp.func
def sink_finish(sink: BlendSink, s: PixState, p: int):
    finish_pixel(s, p, sink.out)


@wp.func
def sink_finish(sink: ContribSink, s: PixState, p: int):  # noqa: F811
    return


# --------------------------------------------------------------------------- walks
@wp.kernel
def walk_pixel_kernel(
    splats: wp.array(dtype=Splat),
    ids: wp.array(dtype=wp.int32),
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
    sink: Any,
    base: int,
    stride: int,
):
    """Work item ``g`` = band-local tile ``g // tile²``, pixel ``g % tile²`` of that tile."""
    g = base + wp.tid() * stride
    tpix = tile * tile
    t = g // tpix
    q = g - t * tpix
    x = (t % tiles_x) * tile + q % tile
    y = (t // tiles_x + band_lo) * tile + q // tile
    if x >= cam.width or y >= cam.height:
        return
    p = y * cam.width + x
    px = float(x) + 0.5
    py = float(y) + 0.5
    s = state_init()
    for e in range(int(rstart[t]), int(rend[t])):
        j = vals[e]  # depth rank: the visible splats are stored in depth order
        sp = splats[j]
        i = ids[j]
        if x >= sp.x0 and x <= sp.x1 and y >= sp.y0 and y <= sp.y1:
            alpha, z = splat_alpha(sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near)
            if alpha >= bp.alpha_min:
                s, w = blend_step(s, alpha, z, bp)
                sink_pair(sink, base, i, j, p, w)
                if (s.flags & FLAG_DONE) != 0:
                    break
    sink_finish(sink, s, p)


@wp.kernel
def walk_tile_kernel(
    splats: wp.array(dtype=Splat),
    ids: wp.array(dtype=wp.int32),
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
    states: wp.array(dtype=PixState),
    sink: Any,
    base: int,
    stride: int,
):
    """Work item ``t`` = band-local tile index."""
    t = base + wp.tid() * stride
    X0 = (t % tiles_x) * tile
    Y0 = (t // tiles_x + band_lo) * tile
    X1 = wp.min(X0 + tile, cam.width) - 1
    Y1 = wp.min(Y0 + tile, cam.height) - 1
    W = cam.width
    for y in range(Y0, Y1 + 1):
        for x in range(X0, X1 + 1):
            states[y * W + x] = state_init()
    npix = (X1 - X0 + 1) * (Y1 - Y0 + 1)
    wrow = X1 - X0 + 1
    ndone = int(0)
    # done pixels per row of the tile: a row whose pixels are all done is skipped before
    # its span is solved (its pixels would all be skipped anyway)
    rdone = RowCounts()
    for e in range(int(rstart[t]), int(rend[t])):
        j = vals[e]  # depth rank: the visible splats are stored in depth order
        sp = splats[j]
        i = ids[j]
        xa = wp.max(sp.x0, X0)
        xb = wp.min(sp.x1, X1)
        ya = wp.max(sp.y0, Y0)
        yb = wp.min(sp.y1, Y1)
        for y in range(ya, yb + 1):
            if rdone[y - Y0] < wrow:
                py = float(y) + 0.5
                xs, xe = row_span(sp, py, cam.fx, cam.fy, xa, xb)
                for x in range(xs, xe + 1):
                    p = y * W + x
                    s = states[p]
                    if (s.flags & FLAG_DONE) == 0:
                        px = float(x) + 0.5
                        alpha, z = splat_alpha(
                            sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near
                        )
                        if alpha >= bp.alpha_min:
                            s, w = blend_step(s, alpha, z, bp)
                            sink_pair(sink, base, i, j, p, w)
                            states[p] = s
                            if (s.flags & FLAG_DONE) != 0:
                                ndone += 1
                                rdone[y - Y0] = rdone[y - Y0] + 1
        if ndone == npix:
            break
    for y in range(Y0, Y1 + 1):
        for x in range(X0, X1 + 1):
            p = y * W + x
            sink_finish(sink, states[p], p)


# one concrete overload per (walk form, sink): compiled with the module, before any
# concurrent CPU sub-launch (``_launch.ensure_loaded``)
for _sink in (BlendSink, ContribSink):
    wp.overload(walk_pixel_kernel, {"sink": _sink})
    wp.overload(walk_tile_kernel, {"sink": _sink})


def launch_walk(
    mode: str,
    sink,
    splats,
    ids,
    vals,
    rstart,
    rend,
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    bp: BlendParams,
    tile: int,
    tiles_x: int,
    band_lo: int,
    n_tiles: int,
    states,
    device,
    threads: int,
    split: str,
) -> None:
    """Walk one band's ``n_tiles`` tiles in ``mode`` (``"pixel"``/``"tile"``) with ``sink``.

    ``split``: how CPU sub-launches share the work (:func:`divas_kernels._launch.launch_split`;
    a sink with per-thread rows needs ``"interleave"``: sub-launch ``j`` gets ``base = j``).
    """
    common = [splats, ids, vals, rstart, rend, cam, inv_var, alpha_max, bp, tile, tiles_x, band_lo]
    if mode == "pixel":
        launch_split(
            walk_pixel_kernel, n_tiles * tile * tile, common + [sink], device, threads, mode=split
        )
    else:
        launch_split(
            walk_tile_kernel, n_tiles, common + [states, sink], device, threads, "interleave"
        )

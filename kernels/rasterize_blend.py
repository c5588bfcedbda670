"""The two blending kernels of the 2DGS rasterizer (see ``kernels.rasterize``).

Both visit, for every pixel, the surfels of its tile in the sorted (centre depth,
index) order and apply :func:`kernels.rasterize.splat_alpha` then
:func:`kernels.composite.blend_step` — the same float operations in the same
order, so their outputs are bit-identical:

* :data:`blend_pixel_kernel` — one thread per pixel (GPU form).
* :data:`blend_tile_kernel` — one thread per tile; for each surfel of the tile it
  walks only the surfel's row spans (:func:`kernels.splat.row_span`) ∩ tile and keeps the
  pixel states in a
  scratch array (CPU form: Warp runs CPU launches serially per thread, so the
  work should scale with covered pixels, not with list length × tile area).
"""

from __future__ import annotations

import warp as wp

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

__all__ = ["blend_pixel_kernel", "blend_tile_kernel"]


@wp.kernel
def blend_pixel_kernel(
    splats: wp.array(dtype=Splat),
    vals: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    feat: wp.array2d(dtype=float),
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    bp: BlendParams,
    tile: int,
    tiles_x: int,
    band_lo: int,
    out: PixelOut,
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
    nc = feat.shape[1]
    s = state_init()
    for e in range(int(rstart[t]), int(rend[t])):
        i = vals[e]
        sp = splats[i]
        if x >= sp.x0 and x <= sp.x1 and y >= sp.y0 and y <= sp.y1:
            alpha, z = splat_alpha(sp, px, py, cam.fx, cam.fy, inv_var, alpha_max, cam.near)
            if alpha >= bp.alpha_min:
                s, w = blend_step(s, alpha, z, bp)
                for c in range(nc):
                    out.feat[p, c] = out.feat[p, c] + w * feat[i, c]
                if (s.flags & FLAG_DONE) != 0:
                    break
    finish_pixel(s, p, out)


@wp.kernel
def blend_tile_kernel(
    splats: wp.array(dtype=Splat),
    vals: wp.array(dtype=wp.int32),
    rstart: wp.array(dtype=wp.int32),
    rend: wp.array(dtype=wp.int32),
    feat: wp.array2d(dtype=float),
    cam: RasterCamera,
    inv_var: float,
    alpha_max: float,
    bp: BlendParams,
    tile: int,
    tiles_x: int,
    band_lo: int,
    states: wp.array(dtype=PixState),
    out: PixelOut,
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
    ndone = int(0)
    nc = feat.shape[1]
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
                        for c in range(nc):
                            out.feat[p, c] = out.feat[p, c] + w * feat[i, c]
                        states[p] = s
                        if (s.flags & FLAG_DONE) != 0:
                            ndone += 1
        if ndone == npix:
            break
    for y in range(Y0, Y1 + 1):
        for x in range(X0, X1 + 1):
            p = y * W + x
            finish_pixel(states[p], p, out)

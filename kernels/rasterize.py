"""Tile-based 2DGS surfel rasterizer (Warp, CPU and CUDA).

Per view: (1) ``preprocess`` — camera-space splat rows, projected centre, planar centre depth
(the sort key), SH colour and a conservative exact pixel rectangle of the cutoff disc
``u² + v² ≤ ρ_cut``, ``ρ_cut = 2 ln(255 · opacity)`` (where ``α`` falls to ``1/255``); a surfel
is rendered only when its whole cutoff disc lies beyond the near plane; (2) stable depth sort of
the visible surfels; (3) tile binning per band of tile rows (:mod:`divas_kernels.tile_binning`);
(4) front-to-back blending in the ``pixel`` (GPU) or ``tile`` (CPU) walk form.

Ray–splat intersection: with rows ``m_x, m_y, m_z`` of the camera-space surfel plane, the hit
of pixel ray ``r`` is ``(u, v, 1) ∝ p = Q r``; ``ρ_3 = u² + v²``, planar depth
``z = det[m]/p_z``; low-pass ``ρ_2 = d² / σ²`` with ``σ = √2/2`` px; ``ρ = min(ρ_3, ρ_2)``;
``α = min(α_max, opacity · exp(−ρ/2))``, skipped when ``α < α_min`` or depth < near.
The derivation in full: docs/design-notes.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import render_defaults as RD
from ._launch import cpu_threads, launch_split
from .composite import ANCHOR_MED, BlendParams, PixelOut, PixState
from .scratch import scratch_active, scratch_empty
from .sh import eval_sh
from .splat import (
    BIG,
    RasterCamera,
    Splat,
    conic_range,
    make_raster_camera,
    splat_plane_rows,
)
from .surfel_buffers import SurfelBuffers, surfel_rows, upload_surfels
from .tile_binning import (
    ViewBinning,
    binning_key,
    depth_ranks,
    gather_rows,
    sort_visible,
    take_rows,
    tile_bands,
    visible_splats,
)
from .tile_walk import BlendSink, launch_walk

# forward only: no adjoint code (halves compile time)
wp.set_module_options({"enable_backward": False})

__all__ = [
    "RasterSettings",
    "RasterOutput",
    "SurfelBuffers",
    "upload_surfels",
    "surfel_rows",
    "rasterize_surfels",
    "make_raster_camera",
    "project_splats",
    "ViewBinning",
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
        cull_pass_min: from this many projected surfels on, culling is a pass of its own
            (sort keys only), then a second pass stores each visible surfel's splat at its
            depth rank: no splat buffer of the scene's size (92 bytes a surfel: the
            render's peak memory); the same render, at one more projection.
        threads: CPU launch threads (None: all usable cores).
        profile: synchronise after each stage and record stage seconds in ``stats``.
    """

    tau_sig: float = RD.TAU_SIG
    tau_cw: float = RD.TAU_CW
    t_min: float = RD.T_MIN
    alpha_min: float = RD.ALPHA_MIN
    alpha_max: float = RD.ALPHA_MAX
    lowpass_sigma: float = RD.LOWPASS_SIGMA
    near: float = RD.NEAR
    tile: int = RD.TILE
    max_duplicates: int = RD.MAX_DUPLICATES
    blend: str = RD.BLEND
    cull_pass_min: int = 1_500_000
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
    rows: wp.array(dtype=wp.int32),
    use_rows: int,
    write_splat: int,
    dest: wp.array(dtype=wp.int32),
    use_dest: int,
    splats: wp.array(dtype=Splat),
    sort_keys: wp.array(dtype=float),
    colors: wp.array2d(dtype=float),
    extra: wp.array2d(dtype=float),
    n_extra: int,
    base: int,
    stride: int,
):
    """Per surfel: splat rows, bounds, sort key (+inf when culled) and SH colour (the
    splat and the colour only for surfels that are not culled). With ``use_rows``,
    item ``j`` is surfel ``rows[j]`` (splat and key at ``j``, colour at the surfel);
    ``write_splat`` 0: the sort key (and colour) only (the culling pass). With
    ``use_dest`` the splat of a visible item ``j`` goes to ``splats[dest[j]]`` (items with
    ``dest[j] < 0`` are skipped), its colour to ``colors[dest[j]]``, and no key is written
    (the pass after the culling pass: items in index order, splats and colours stored in
    depth order). With the colour, the surfel's ``n_extra`` values ``extra[i]`` go to the
    same row's ``3 …`` columns (value channels blended with the RGB)."""
    j = base + wp.tid() * stride
    if use_dest != 0:
        if dest[j] < 0:
            return  # culled by the culling pass: not projected again
    i = j
    if use_rows != 0:
        i = rows[j]
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
        # … clipped to the rendered window (the whole image: 0 … W − 1, 0 … H − 1)
        sp.x0 = wp.max(int(wp.ceil(xlo - 0.5)), cam.win_x0)
        sp.x1 = wp.min(int(wp.floor(xhi - 0.5)), cam.win_x1)
        sp.y0 = wp.max(int(wp.ceil(ylo - 0.5)), cam.win_y0)
        sp.y1 = wp.min(int(wp.floor(yhi - 0.5)), cam.win_y1)
    if sp.x0 > sp.x1 or sp.y0 > sp.y1:
        # culled: left out of the depth order and never read again (binning, blending
        # and every other pass read only the visible splats), so neither its splat nor
        # its SH colour is written (most surfels of a zoomed view)
        if use_dest == 0:
            sort_keys[j] = BIG
        return
    if write_splat != 0:
        if use_dest != 0:
            splats[dest[j]] = sp
        else:
            splats[j] = sp
    if use_dest == 0:
        sort_keys[j] = sp.depth
    if with_color != 0:
        ci = i  # the colour row: the surfel's, or its depth rank after the culling pass
        if use_dest != 0:
            ci = dest[j]
        d = wp.normalize(mu - cam.center)
        col = eval_sh(sh, i, sh_degree, d)
        colors[ci, 0] = col[0]
        colors[ci, 1] = col[1]
        colors[ci, 2] = col[2]
        for ch in range(n_extra):
            colors[ci, 3 + ch] = extra[i, ch]


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
    binning: ViewBinning | None = None


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


def check_view(who: str, W: int, H: int, s: RasterSettings, dev) -> tuple[str, int, int]:
    """Validate an image size and settings; ``(blend mode, tile, CPU threads)``."""
    T = int(s.tile)
    if W <= 0 or H <= 0:
        raise ValueError(f"{who}: empty image {W}x{H}")
    if T <= 0 or T > 64:
        raise ValueError(f"{who}: tile size {T} outside 1..64")
    mode = s.blend if s.blend != "auto" else ("pixel" if dev.is_cuda else "tile")
    if mode not in ("pixel", "tile"):
        raise ValueError(f"{who}: blend mode {s.blend!r} is not auto/pixel/tile")
    return mode, T, (1 if dev.is_cuda else cpu_threads(s.threads))


def project_splats(
    buf: SurfelBuffers,
    cam: RasterCamera,
    inv_var: float,
    colors: wp.array | None,
    threads: int,
    rows: wp.array | None = None,
    count: int | None = None,
    write_splats: bool = True,
    extra: wp.array | None = None,
    dest: wp.array | None = None,
    n_dest: int = 0,
) -> tuple[wp.array, wp.array]:
    """Preprocess every surfel for ``cam`` (splat rows, exact bounds, culling; SH colours
    into ``colors`` when given); the depth order is :func:`divas_kernels.tile_binning.sort_visible`.
    ``rows``: only these surfels (int32, their first ``count``; ascending, every other
    one culled — or the visible ones in depth order). ``write_splats`` False: the keys
    (and colours) only (``splats`` is a placeholder). ``extra`` ``[N, C]`` (with
    ``colors`` ``[N, 3 + C]``): copied after each visible surfel's colour. ``dest``
    (``[K]`` int32, the depth rank of every visible item): the ``n_dest`` visible splats
    are written at their ranks, in a ``[n_dest]`` buffer, and no keys (``keys`` is a
    placeholder): the items are read in index order (reading them in depth order,
    scattered over the scene's arrays, costs more than the projection).

    Returns ``(splats [K], keys [K])`` (``K`` = N, or the rows): the depth keys, +inf
    (``BIG``) for culled surfels, whose ``splats`` and ``colors`` entries are left unset
    (only the visible ones are read: :func:`divas_kernels.tile_binning.sort_visible`, then
    ``visible_splats``).
    """
    n = len(buf) if rows is None else (rows.shape[0] if count is None else int(count))
    dev = buf.device
    splats = scratch_empty(  # the ranked ones (``dest``) are a binning's
        (n if dest is None else max(int(n_dest), 1)) if write_splats else 1,
        Splat,
        dev,
        kept=dest is not None,
    )
    keys = scratch_empty(n if dest is None else 1, float, dev)
    with_color = 0 if colors is None else 1
    n_extra = 0 if extra is None or not with_color else int(extra.shape[1])
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
            rows if rows is not None else wp.empty(1, dtype=wp.int32, device=dev),
            0 if rows is None else 1,
            int(write_splats),
            dest if dest is not None else wp.empty(1, dtype=wp.int32, device=dev),
            0 if dest is None else 1,
            splats,
            keys,
            colors if with_color else wp.empty((1, 3), dtype=float, device=dev),
            extra if n_extra else wp.empty((1, 1), dtype=float, device=dev),
            n_extra,
        ],
        dev,
        threads,
    )
    return splats, keys


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
    *,
    features: bool = True,
    binning: ViewBinning | None = None,
    keep_binning: bool = False,
    window: tuple[int, int, int, int] | None = None,
    rows: np.ndarray | None = None,
    extra: np.ndarray | wp.array | None = None,
    keep_colours: bool = True,
) -> RasterOutput:
    """Rasterize ``buf`` into a ``width × height`` view (OpenCV pinhole, ``w2c`` 4×4).

    Args:
        values: ``None`` → composite SH colours over ``background``; else ``[N]`` or
            ``[N, C]`` per-surfel values composited with the same weights (no background).
        features: False (with ``values`` None) → the depth tuple only: no SH colours, no
            feature compositing (``feat`` is ``[P, 0]``); the depths are the same.
        binning: a :class:`ViewBinning` of an earlier pass; used when its key matches
            this view (and, for an RGB render, it holds the colours), else ignored.
        keep_binning: return this view's binning in ``RasterOutput.binning``.
        window: ``(x0, y0, x1, y1)``, half-open pixels: render only this part of the
            image — surfels whose bounds miss it are culled, bounds are clipped to it, so
            its pixels equal the whole image's bit for bit at the cost of the window
            (the centroid-view probes read a central patch). Pixels outside it
            are not rendered (partial or empty): read only the window. None: the image.
        rows: ascending surfel indices, a superset of those the view keeps: only they are
            projected (the others would be culled; the survivors keep their index order
            for the stable depth sort): the same render at the rows' cost.
        extra: with an RGB render, ``[N]`` or ``[N, C]`` per-surfel values composited in
            the same blend as channels ``3 … 3 + C − 1`` of ``feat`` (no background): each
            channel bit for bit what ``values=extra`` composites, without a second blend
            (the oracle's ground truth at the view the session renders). A
            ``binning`` is not reused then, nor are the colours kept with a new one.
        keep_colours: False: a kept binning holds no SH colours (an RGB render of its
            camera then projects afresh); their array may then come from an active
            :class:`~divas_kernels.scratch.ScratchPool` (it does not outlive the call).
    Returns:
        :class:`RasterOutput` on ``buf.device``.
    """
    s = settings or RasterSettings()
    dev = buf.device
    n = len(buf)
    W, H = int(width), int(height)
    mode, T, threads = check_view("rasterize_surfels", W, H, s, dev)
    rgb = values is None and features
    if keep_binning and scratch_active(everything=True):
        raise ValueError("rasterize_surfels: a kept binning cannot use scratch buffers")
    if extra is not None and not rgb:
        raise ValueError("rasterize_surfels: extra value channels need an RGB render")
    key = binning_key(buf, w2c, fx, fy, cx, cy, W, H, s, window)
    if binning is not None and (
        binning.key != key or (rgb and (binning.colors is None or extra is not None))
    ):
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
    with wp.ScopedDevice(dev):
        ext = None if extra is None else _value_rows(extra, n, dev)
        # many surfels to project: a culling pass first (keys only), then the visible ones
        two_pass = (
            binning is None and n > 0 and (n if rows is None else len(rows)) >= s.cull_pass_min
        )
        if values is None:
            C = (3 + (0 if ext is None else ext.shape[1])) if features else 0
            bg = np.zeros(C, np.float32)  # the value channels: no background
            bg[: min(C, 3)] = np.asarray(background, dtype=np.float32).reshape(3)[: min(C, 3)]
            # [N, C] by surfel index, or (the culling pass first) [n_visible, C] by depth
            # rank, made with the splats below
            late = two_pass and rgb
            feat = None if late else scratch_empty((max(n, 1), C), float, dev, kept=False)
        else:
            v = np.asarray(values, dtype=np.float32)
            v = v.reshape(len(v), -1) if v.ndim > 1 else v.reshape(-1, 1)
            if v.shape[0] != n:
                raise ValueError(f"rasterize_surfels: values has {v.shape[0]} rows for {n} surfels")
            C, bg = v.shape[1], np.zeros(v.shape[1], np.float32)
            feat = scratch_empty(v.shape, float, dev)  # a copy: kept with no binning
            feat.numpy()[...] = v
        out = alloc_pixel_out(P, C, bg, dev)
        sink = BlendSink()
        sink.out = out
        sink.by_rank = 0
        stats = {"surfels": n, "pairs": 0, "bands": 0, "mode": mode}
        tiles_x, tiles_y = -(-W // T), -(-H // T)
        states = scratch_empty(P, PixState, dev) if mode == "tile" else None
        bp = blend_params(s)
        alpha_max = float(s.alpha_max)
        if n == 0:  # every pixel gets the empty tuple and the background
            sink.feat = feat
            z = wp.zeros(tiles_x * tiles_y, dtype=wp.int32)
            one = wp.empty(1, dtype=wp.int32)
            nt = tiles_x * tiles_y
            args = (wp.empty(1, dtype=Splat), one, one, z, z, cam, inv_var, alpha_max, bp, T,
                    tiles_x)  # fmt: skip
            launch_walk(mode, sink, *args, 0, nt, states, dev, threads, "chunk")
            return RasterOutput(out, W, H, stats)
        tm = _Timer(s.profile, stats)
        if binning is None:
            rws = None if rows is None else wp.array(np.asarray(rows, np.int32), dtype=wp.int32)
            cols = feat if rgb else None
            if not two_pass:
                splats, keys = project_splats(buf, cam, inv_var, cols, threads, rws, extra=ext)
                tm.lap("preprocess")
                order, n_vis = sort_visible(keys, keys.shape[0], dev, threads)
                splats, ids = visible_splats(splats, order, n_vis, dev, threads, rws)
                if rgb:  # the colours in depth order, read so by the blend
                    feat = gather_rows(feat, ids, n_vis, dev, threads, kept=keep_colours)
            else:  # cull first (keys only), then project the visible ones in depth order
                _, keys = project_splats(buf, cam, inv_var, None, threads, rws, write_splats=False)
                order, n_vis = sort_visible(keys, keys.shape[0], dev, threads)
                ids = take_rows(rws, order, n_vis, dev, threads)
                rank = depth_ranks(order, n_vis, keys.shape[0], dev, threads)
                keys = order = None  # freed before the splats are allocated
                # the second pass reads the surfels in index order and stores each visible
                # splat and its SH colour at its depth rank: the same splats, in the same
                # order, and the colours as the blend reads them
                if rgb:
                    feat = scratch_empty((max(n_vis, 1), C), float, dev, kept=keep_colours)
                splats, keys = project_splats(
                    buf, cam, inv_var, feat if rgb else None, threads, rws, dest=rank,
                    n_dest=n_vis, extra=ext,
                )  # fmt: skip
                del rank
                tm.lap("preprocess")
            sink.by_rank = int(rgb)
            del keys, order, rws  # the full-size arrays are not kept
            tm.lap("depth_sort")
            # [n_visible, 3] in depth order: reusable alone
            colours = feat if rgb and extra is None and keep_colours else None
            binning = ViewBinning(key, cam, splats, ids, n_vis, None, colours, {})
            bands = tile_bands(
                splats, n_vis, T, tiles_x, tiles_y, s.max_duplicates, stats, dev, threads, tm.lap
            )
            kept: list | None = []
        else:
            splats, ids = binning.splats, binning.ids
            if rgb:
                feat = binning.colors  # in depth order
                sink.by_rank = 1
            if binning.bands is not None:
                bands = iter(binning.bands)
                stats["pairs"], stats["bands"] = binning.stats["pairs"], binning.stats["bands"]
            else:
                bands = tile_bands(
                    splats, binning.n_visible, T, tiles_x, tiles_y, s.max_duplicates, stats, dev,
                    threads, tm.lap,
                )  # fmt: skip
            kept = None
        sink.feat = feat
        for band in bands:
            lo, nt, dvals, rstart, rend, _ = band
            if kept is not None:
                kept.append(band)
            args = (splats, ids, dvals, rstart, rend, cam, inv_var, alpha_max, bp, T, tiles_x)
            launch_walk(mode, sink, *args, lo, nt, states, dev, threads, "chunk")
            tm.lap("blend")
        if kept is not None:  # a fresh binning: keep its bands when there is one
            binning.bands = kept if len(kept) == 1 else None
            binning.stats = {"pairs": stats["pairs"], "bands": stats["bands"]}
        if s.profile:
            stats["visible"] = int(binning.n_visible)
    res = RasterOutput(out, W, H, stats)
    res.binning = binning if keep_binning else None
    return res


def _value_rows(v, n: int, dev) -> wp.array:
    """Per-surfel values ``[N]`` / ``[N, C]`` (NumPy or Warp) as a ``[N, C]`` float32
    Warp array on ``dev`` (a CPU NumPy float32 array is wrapped, not copied)."""
    if isinstance(v, wp.array):
        a = v if v.ndim == 2 else v.reshape((v.shape[0], 1))
    else:
        h = np.ascontiguousarray(v, dtype=np.float32)
        h = h.reshape(len(h), -1) if h.ndim > 1 else h.reshape(-1, 1)
        a = wp.array(h, dtype=float, device=dev, copy=not dev.is_cpu)
    if a.shape[0] != n or a.dtype != wp.float32:
        raise ValueError(f"rasterize_surfels: extra has {a.shape[0]} rows for {n} surfels")
    return a

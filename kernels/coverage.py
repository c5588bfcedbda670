"""Warp kernels of the 2DGS voxel-to-surfel mapping (paper Sec. 3.6, eq:pass1 …
eq:final-F; App. B "Voxel-to-Surfel Mapping: Implementation Details"; alg:vox2surfel).

* :data:`pass1_kernel` — ``f¹_i = B^seg[m_i]`` (the surfel's voxel is segmented);
* :data:`pass2_kernel` — ``f²_i = f¹_i ∧ (a_i ≤ τ_a)`` and the Pass-3 compaction flag;
* :data:`coverage_kernel` — Pass 3 (eq:cov-atomics, eq:kappa): per candidate and per view
  whose bit is set in its voxel's bitmask, the pixels of the 1σ box whose ray meets the
  surfel plane at ``u² + v² ≤ 9``; ``κ_s = mask_fp / max(total_fp, 1)``, ``κ = max_s κ_s``;
* :data:`select_kernel` — ``f_i = f²_i ∧ (κ_i ≥ τ_κ)`` (eq:final-F).

Pass 3 is surfel-parallel, not the paper's tile-sorted gather: the counts are order-free
integers, so the layout does not change the result. Exact early-outs (``early_out=1``) give
identical κ. Layout, early-outs and the visibility rule: docs/design-notes.md.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._launch import launch_split
from .splat import RasterCamera, Splat, make_raster_camera, plane_hit, splat_plane_rows

wp.set_module_options({"enable_backward": False})

__all__ = [
    "CoverageView",
    "make_coverage_view",
    "upload_coverage_views",
    "project_surfel",
    "splat_rho3",
    "footprint_counts",
    "pass1_kernel",
    "pass2_kernel",
    "compact_kernel",
    "coverage_kernel",
    "select_kernel",
    "run_pass1",
    "run_pass2",
    "compact",
    "run_coverage",
    "run_select",
]


@wp.struct
class CoverageView:
    """One view of Pass 3 on the device.

    ``cam``: projection (``cam.near`` = near plane); ``word``/``bit``: the view's slot
    in the ``[A, words]`` uint32 bitmask; ``mask_off``: offset of its binarised mask
    (``M̃ ≥ τ_M``, row-major ``H×W`` uint8) in the flat mask buffer; ``sat_off``:
    offset of its ``(H+1)×(W+1)`` int32 summed-area table of that mask.
    """

    cam: RasterCamera
    word: int
    bit: wp.uint32
    mask_off: int
    sat_off: int


def make_coverage_view(
    w2c: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: int,
    height: int,
    near: float,
    slot: int,
    mask_off: int,
    sat_off: int,
) -> CoverageView:
    v = CoverageView()
    v.cam = make_raster_camera(
        np.asarray(w2c, dtype=np.float64), fx, fy, cx, cy, width, height, near
    )
    v.word = int(slot) // 32
    v.bit = wp.uint32(1 << (int(slot) % 32))
    v.mask_off = int(mask_off)
    v.sat_off = int(sat_off)
    return v


def upload_coverage_views(views: list[CoverageView], device) -> wp.array:
    """The ``[V]`` device array of Pass-3 views :func:`run_coverage` takes."""
    return wp.array(views, dtype=CoverageView, device=device)


# --------------------------------------------------------------------------- funcs
@wp.func
def project_surfel(mu: wp.vec3, tu: wp.vec3, tv: wp.vec3, cam: RasterCamera) -> Splat:
    """Camera-space splat rows of a surfel (the rasterizer's preprocess, same formulas:
    ``divas_kernels.rasterize.preprocess_kernel``); bounds/opacity fields are unused here.
    Requires ``pc.z > 0`` (checked by the caller)."""
    pc = cam.R * mu + cam.t
    a = cam.R * tu
    b = cam.R * tv
    mx = wp.vec3(a[0], b[0], pc[0])
    my = wp.vec3(a[1], b[1], pc[1])
    mz = wp.vec3(a[2], b[2], pc[2])
    sp = splat_plane_rows(mx, my, mz)
    sp.pz0 = wp.dot(sp.qn, pc) / pc[2]
    sp.center = wp.vec2(cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy)
    sp.depth = pc[2]
    sp.r2 = 0.0
    sp.opacity = 0.0
    sp.rho_cut = 0.0
    sp.x0 = 1
    sp.x1 = 0
    sp.y0 = 1
    sp.y1 = 0
    return sp


@wp.func
def splat_rho3(sp: Splat, px: float, py: float, fx: float, fy: float) -> float:
    """``u² + v²`` of the pixel ray through ``(px, py)`` on the surfel plane, in units of
    the tangent scales (the ``ρ_3`` of ``divas_kernels.splat.splat_alpha``, same operations;
    no low-pass term). Edge-on (``p_z = 0``) → 1e30."""
    return plane_hit(sp, (px - sp.center[0]) / fx, (py - sp.center[1]) / fy)[0]


@wp.func
def _tip_dev(p: wp.vec3, c: wp.vec2, cam: RasterCamera, ex: float, ey: float) -> wp.vec2:
    """Running max of ``|π(p) − c|`` per image axis."""
    x = cam.fx * p[0] / p[2] + cam.cx
    y = cam.fy * p[1] / p[2] + cam.cy
    return wp.vec2(wp.max(ex, wp.abs(x - c[0])), wp.max(ey, wp.abs(y - c[1])))


@wp.func
def _sat_box(
    sats: wp.array(dtype=wp.int32), off: int, W: int, x0: int, y0: int, x1: int, y1: int
) -> int:
    """Inclusive box sum of a flat ``(H+1)×(W+1)`` summed-area table."""
    s = W + 1
    return (
        int(sats[off + (y1 + 1) * s + x1 + 1])
        - int(sats[off + y0 * s + x1 + 1])
        - int(sats[off + (y1 + 1) * s + x0])
        + int(sats[off + y0 * s + x0])
    )


@wp.func
def footprint_counts(
    mu: wp.vec3,
    tu: wp.vec3,
    tv: wp.vec3,
    vw: CoverageView,
    masks: wp.array(dtype=wp.uint8),
    sats: wp.array(dtype=wp.int32),
    box_sigma: float,
    rho_acc: float,
    early_out: int,
) -> wp.vec3i:
    """``(total_fp, mask_fp, swept)`` of one surfel in one view (eq:cov-atomics).

    ``swept = 0`` when an early-out decided κ_s without a full sweep: then only the
    ratio ``mask_fp / max(total_fp, 1)`` is meaningful (it equals the exact κ_s).
    ``(0, 0, 0)`` when the surfel is not visible (near-plane rule) or its box is empty.
    """
    cam = vw.cam
    pc = cam.R * mu + cam.t
    a = cam.R * tu
    b = cam.R * tv
    kmax = wp.max(rho_acc, box_sigma * box_sigma)
    zr = wp.sqrt(kmax * (a[2] * a[2] + b[2] * b[2]))
    if not (pc[2] - zr > cam.near):
        return wp.vec3i(0, 0, 0)
    sp = project_surfel(mu, tu, tv, cam)
    c = sp.center
    # 1σ box: the largest image-axis deviation of the four projected tangent tips
    e = wp.vec2(0.0, 0.0)
    da = a * box_sigma
    db = b * box_sigma
    e = _tip_dev(pc + da, c, cam, e[0], e[1])
    e = _tip_dev(pc - da, c, cam, e[0], e[1])
    e = _tip_dev(pc + db, c, cam, e[0], e[1])
    e = _tip_dev(pc - db, c, cam, e[0], e[1])
    W = cam.width
    H = cam.height
    Wf = float(W)
    Hf = float(H)
    # pixel centres at i + 0.5; clamp before the int conversion
    xlo = wp.clamp(c[0] - e[0], -2.0, Wf + 2.0)
    xhi = wp.clamp(c[0] + e[0], -2.0, Wf + 2.0)
    ylo = wp.clamp(c[1] - e[1], -2.0, Hf + 2.0)
    yhi = wp.clamp(c[1] + e[1], -2.0, Hf + 2.0)
    x0 = wp.max(int(wp.ceil(xlo - 0.5)), 0)
    x1 = wp.min(int(wp.floor(xhi - 0.5)), W - 1)
    y0 = wp.max(int(wp.ceil(ylo - 0.5)), 0)
    y1 = wp.min(int(wp.floor(yhi - 0.5)), H - 1)
    if x0 > x1 or y0 > y1:
        return wp.vec3i(0, 0, 0)
    all_pos = int(0)
    if early_out != 0:
        npos = _sat_box(sats, vw.sat_off, W, x0, y0, x1, y1)
        if npos == 0:
            return wp.vec3i(0, 0, 0)  # κ_s = 0 whatever total_fp is
        if npos == (x1 - x0 + 1) * (y1 - y0 + 1):
            all_pos = 1
    tot = int(0)
    pos = int(0)
    for y in range(y0, y1 + 1):
        py = float(y) + 0.5
        row = vw.mask_off + y * W
        for x in range(x0, x1 + 1):
            px = float(x) + 0.5
            if splat_rho3(sp, px, py, cam.fx, cam.fy) <= rho_acc:
                if all_pos != 0:
                    return wp.vec3i(1, 1, 0)  # every pixel is positive: κ_s = 1
                tot += 1
                if masks[row + x] != wp.uint8(0):
                    pos += 1
    return wp.vec3i(tot, pos, 1)


# --------------------------------------------------------------------------- kernels
@wp.kernel
def pass1_kernel(
    act: wp.array(dtype=wp.int32),
    seg: wp.array(dtype=wp.uint8),
    f1: wp.array(dtype=wp.uint8),
    base: int,
    stride: int,
):
    """eq:pass1: ``f¹_i = B^seg[m_i]`` (``act[i]`` = active index of the surfel's voxel,
    −1 when the NaN/AABB filter dropped it or the voxel is inactive)."""
    i = base + wp.tid() * stride
    a = act[i]
    r = wp.uint8(0)
    if a >= 0:
        if seg[a] != wp.uint8(0):
            r = wp.uint8(1)
    f1[i] = r


@wp.kernel
def pass2_kernel(
    f1: wp.array(dtype=wp.uint8),
    keep: wp.array(dtype=wp.uint8),
    f2: wp.array(dtype=wp.uint8),
    flag: wp.array(dtype=int),
    base: int,
    stride: int,
):
    """eq:pass-needle: ``f²_i = f¹_i ∧ (a_i ≤ τ_a)`` (``keep`` = a_i ≤ τ_a); ``flag`` is
    the compaction flag of the Pass-3 candidates."""
    i = base + wp.tid() * stride
    r = wp.uint8(0)
    if f1[i] != wp.uint8(0) and keep[i] != wp.uint8(0):
        r = wp.uint8(1)
    f2[i] = r
    flag[i] = int(r)


@wp.kernel
def compact_kernel(
    flag: wp.array(dtype=int), pos: wp.array(dtype=int), out: wp.array(dtype=wp.int32)
):
    i = wp.tid()
    if flag[i] != 0:
        out[pos[i]] = wp.int32(i)


@wp.kernel
def coverage_kernel(
    cand: wp.array(dtype=wp.int32),
    act: wp.array(dtype=wp.int32),
    vmask: wp.array2d(dtype=wp.uint32),
    means: wp.array(dtype=wp.vec3),
    tu: wp.array(dtype=wp.vec3),
    tv: wp.array(dtype=wp.vec3),
    views: wp.array(dtype=CoverageView),
    masks: wp.array(dtype=wp.uint8),
    sats: wp.array(dtype=wp.int32),
    box_sigma: float,
    rho_acc: float,
    early_out: int,
    kappa: wp.array(dtype=float),
    scored: wp.array(dtype=wp.int32),
    total_out: wp.array(dtype=wp.int32),
    mask_out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    """Pass 3 for candidate ``cand[j]`` over all views (eq:cov-atomics, eq:kappa).

    Writes ``kappa[i]`` and ``scored[i]`` (views admitted by the bitmask gate). When
    ``total_out`` is non-empty (one view, ``early_out = 0``) also the raw counts.
    """
    j = base + wp.tid() * stride
    i = int(cand[j])
    a = act[i]
    mu = means[i]
    t0 = tu[i]
    t1 = tv[i]
    k = float(0.0)
    ns = int(0)
    for s in range(views.shape[0]):
        vw = views[s]
        if (vmask[a, vw.word] & vw.bit) != wp.uint32(0):  # alg:vox2surfel (i): view gate
            ns += 1
            if early_out == 0 or k < 1.0:
                r = footprint_counts(mu, t0, t1, vw, masks, sats, box_sigma, rho_acc, early_out)
                ks = float(r[1]) / float(wp.max(r[0], 1))
                k = wp.max(k, ks)
                if total_out.shape[0] > 0:
                    total_out[i] = wp.int32(r[0])
                    mask_out[i] = wp.int32(r[1])
    kappa[i] = k
    scored[i] = wp.int32(ns)


@wp.kernel
def select_kernel(
    f2: wp.array(dtype=wp.uint8),
    kappa: wp.array(dtype=float),
    tau_k: float,
    apply: int,
    out: wp.array(dtype=wp.uint8),
    base: int,
    stride: int,
):
    """eq:final-F: ``f_i = f²_i ∧ (κ_i ≥ τ_κ)`` (``apply = 0``: ``f = f²``, ablation)."""
    i = base + wp.tid() * stride
    r = wp.uint8(0)
    if f2[i] != wp.uint8(0):
        if apply == 0 or kappa[i] >= tau_k:
            r = wp.uint8(1)
    out[i] = r


# --------------------------------------------------------------------------- wrappers
def run_pass1(act: wp.array, seg: wp.array, f1: wp.array, device, threads: int = 1) -> None:
    launch_split(pass1_kernel, act.shape[0], [act, seg, f1], device, threads)


def run_pass2(
    f1: wp.array, keep: wp.array, f2: wp.array, flag: wp.array, device, threads: int = 1
) -> None:
    launch_split(pass2_kernel, f1.shape[0], [f1, keep, f2, flag], device, threads)


def compact(flag: wp.array, device) -> wp.array:
    """Indices ``[K] int32`` of the non-zero flags, ascending."""
    n = flag.shape[0]
    if n == 0:
        return wp.empty(0, dtype=wp.int32, device=device)
    pos = wp.empty(n, dtype=int, device=device)
    wp.utils.array_scan(flag, pos, inclusive=False)
    k = int(pos[n - 1 : n].numpy()[0] + flag[n - 1 : n].numpy()[0])
    out = wp.empty(k, dtype=wp.int32, device=device)
    wp.launch(compact_kernel, dim=n, inputs=[flag, pos, out], device=device)
    return out


def run_coverage(
    cand: wp.array,
    act: wp.array,
    vmask: wp.array,
    means: wp.array,
    tu: wp.array,
    tv: wp.array,
    views: wp.array,
    masks: wp.array,
    sats: wp.array,
    box_sigma: float,
    accept_sigma: float,
    early_out: bool,
    kappa: wp.array,
    scored: wp.array,
    total_out: wp.array | None = None,
    mask_out: wp.array | None = None,
    device=None,
    threads: int = 1,
) -> None:
    """Launch Pass 3 over the candidates (``kappa``/``scored`` are ``[N]``, zeroed by the
    caller for non-candidates)."""
    device = device or means.device
    if total_out is None:
        total_out = wp.empty(0, dtype=wp.int32, device=device)
        mask_out = wp.empty(0, dtype=wp.int32, device=device)
    launch_split(
        coverage_kernel,
        cand.shape[0],
        [
            cand,
            act,
            vmask,
            means,
            tu,
            tv,
            views,
            masks,
            sats,
            float(box_sigma),
            float(accept_sigma) ** 2,
            1 if early_out else 0,
            kappa,
            scored,
            total_out,
            mask_out,
        ],
        device,
        threads,
        mode="interleave",
    )


def run_select(
    f2: wp.array,
    kappa: wp.array,
    tau_k: float,
    apply: bool,
    out: wp.array,
    device,
    threads: int = 1,
) -> None:
    launch_split(
        select_kernel,
        f2.shape[0],
        [f2, kappa, float(np.float32(tau_k)), 1 if apply else 0, out],
        device,
        threads,
    )

"""Warp kernels of the 2DGS occupancy grid (paper Sec. 3.5 "Occupancy by
Morton-scattered opacity", App. B "Occupancy grid construction").

Build pipeline (every step is a kernel or a Warp primitive; no dense g³ array):

1. :func:`surfel_codes` — AABB filter ``¬NaN(μ) ∧ ‖μ − c_scene‖_∞ < b`` and the
   Morton code of ``⌊((μ − c_scene) + b) / h_v⌋`` (alg:vox2surfel Pass 1 uses the
   *same* :func:`point_voxel_code`). Arithmetic in float64 so that a NumPy
   reference reproduces every voxel assignment bit for bit.
2. stable radix sort of (code, opacity) pairs (``wp.utils.radix_sort_pairs``).
3. segment heads + exclusive scan → one entry per occupied voxel; each voxel's
   opacity is summed in float64 by one thread, in sorted (= surfel-index, the sort
   is stable) order, so the sum equals ``np.bincount`` bit for bit and is
   deterministic on every device (no float atomics).
4. ``ρ ≥ τ_TF`` → compact, Morton-sorted active list (codes, density, surfel count).
5. an open-addressing hash table code → active index (see :func:`hash_build`).

Morton layout: bit ``3k`` of the code is bit ``k`` of ``ix``, ``3k+1`` of ``iy``,
``3k+2`` of ``iz``; up to 21 bits per axis (63-bit codes in int64).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._launch import cpu_threads, launch_split

__all__ = [
    "GridGeom",
    "point_voxel_code",
    "morton_encode3",
    "morton_decode3",
    "hash_lookup",
    "voxel_center",
    "voxel_center_d",
    "make_grid_geom",
    "surfel_codes",
    "build_active",
    "hash_build",
    "hash_query",
    "HASH_EMPTY",
]

_M21 = wp.constant(wp.uint64(0x1FFFFF))
_S1 = wp.constant(wp.uint64(0x1F00000000FFFF))
_S2 = wp.constant(wp.uint64(0x1F0000FF0000FF))
_S3 = wp.constant(wp.uint64(0x100F00F00F00F00F))
_S4 = wp.constant(wp.uint64(0x10C30C30C30C30C3))
_S5 = wp.constant(wp.uint64(0x1249249249249249))
_FIB = wp.constant(wp.uint64(0x9E3779B97F4A7C15))
HASH_EMPTY = -1


@wp.struct
class GridGeom:
    """Grid frame on the device. ``center`` = c_scene, ``half`` = b, ``h`` = h_v,
    ``g`` = resolution, ``origin`` = c_scene − b (float32, for voxel centres)."""

    center: wp.vec3d
    half: wp.float64
    h: wp.float64
    g: int
    origin: wp.vec3
    hf: float


# --- Morton helpers -----------------------------------------------------------
@wp.func
def _part1by2(x: wp.uint64) -> wp.uint64:
    x = x & _M21
    x = (x | (x << wp.uint64(32))) & _S1
    x = (x | (x << wp.uint64(16))) & _S2
    x = (x | (x << wp.uint64(8))) & _S3
    x = (x | (x << wp.uint64(4))) & _S4
    x = (x | (x << wp.uint64(2))) & _S5
    return x


@wp.func
def _compact1by2(x: wp.uint64) -> wp.uint64:
    x = x & _S5
    x = (x ^ (x >> wp.uint64(2))) & _S4
    x = (x ^ (x >> wp.uint64(4))) & _S3
    x = (x ^ (x >> wp.uint64(8))) & _S2
    x = (x ^ (x >> wp.uint64(16))) & _S1
    x = (x ^ (x >> wp.uint64(32))) & _M21
    return x


@wp.func
def morton_encode3(ix: int, iy: int, iz: int) -> wp.int64:
    """Interleave three ≤21-bit coordinates (x lowest)."""
    c = (
        _part1by2(wp.uint64(ix))
        | (_part1by2(wp.uint64(iy)) << wp.uint64(1))
        | (_part1by2(wp.uint64(iz)) << wp.uint64(2))
    )
    return wp.int64(c)


@wp.func
def morton_decode3(code: wp.int64) -> wp.vec3i:
    c = wp.uint64(code)
    return wp.vec3i(
        int(_compact1by2(c)),
        int(_compact1by2(c >> wp.uint64(1))),
        int(_compact1by2(c >> wp.uint64(2))),
    )


@wp.func
def point_voxel_code(p: wp.vec3, geom: GridGeom, filtered: wp.int64) -> wp.int64:
    """Morton code of the voxel holding ``p`` or ``filtered`` (NaN or outside the cube).

    alg:vox2surfel Pass 1: keep ``¬NaN(μ) ∧ ‖μ − c‖_∞ < b``, voxel ``⌊(μ − c + b)/h_v⌋``.
    """
    ijk = wp.vec3i(0, 0, 0)
    for k in range(3):
        x = wp.float64(p[k])
        if not wp.isfinite(x):
            return filtered
        r = x - geom.center[k]
        if wp.abs(r) >= geom.half:
            return filtered
        q = int(wp.floor((r + geom.half) / geom.h))
        ijk[k] = wp.clamp(q, 0, geom.g - 1)
    return morton_encode3(ijk[0], ijk[1], ijk[2])


@wp.func
def voxel_center(code: wp.int64, geom: GridGeom) -> wp.vec3:
    """World centre ``c − b + (i + ½) h_v`` of the voxel ``code`` (float32)."""
    ijk = morton_decode3(code)
    return (
        geom.origin
        + wp.vec3(float(ijk[0]) + 0.5, float(ijk[1]) + 0.5, float(ijk[2]) + 0.5) * geom.hf
    )


@wp.func
def voxel_center_d(code: wp.int64, geom: GridGeom) -> wp.vec3d:
    """float64 world centre ``(c − b) + (i + ½) h_v`` of the voxel ``code``."""
    ijk = morton_decode3(code)
    half = wp.float64(0.5)
    o = geom.center - wp.vec3d(geom.half, geom.half, geom.half)
    return (
        o
        + wp.vec3d(wp.float64(ijk[0]) + half, wp.float64(ijk[1]) + half, wp.float64(ijk[2]) + half)
        * geom.h
    )


@wp.func
def _hash_slot(code: wp.int64, shift: int) -> int:
    return int((wp.uint64(code) * _FIB) >> wp.uint64(shift))


@wp.func
def hash_lookup(
    keys: wp.array(dtype=wp.int64), vals: wp.array(dtype=wp.int32), shift: int, code: wp.int64
) -> int:
    """Active index of ``code`` or −1 (linear probing; expected O(1) at load ≤ ½)."""
    mask = keys.shape[0] - 1
    s = _hash_slot(code, shift)
    for _probe in range(keys.shape[0]):
        k = keys[s]
        if k == code:
            return int(vals[s])
        if k == wp.int64(HASH_EMPTY):
            return -1
        s = (s + 1) & mask
    return -1


# --- kernels --------------------------------------------------------------------
@wp.kernel
def _codes_kernel(
    means: wp.array(dtype=wp.vec3),
    geom: GridGeom,
    filtered: wp.int64,
    codes: wp.array(dtype=wp.int64),
    values: wp.array(dtype=float),
    opac: wp.array(dtype=float),
    n_valid: wp.array(dtype=int),
):
    i = wp.tid()
    c = point_voxel_code(means[i], geom, filtered)
    codes[i] = c
    if values.shape[0] > 0:
        values[i] = opac[i]
    if c != filtered and n_valid.shape[0] > 0:
        wp.atomic_add(n_valid, 0, 1)


@wp.kernel
def _heads_kernel(codes: wp.array(dtype=wp.int64), n: int, heads: wp.array(dtype=int)):
    i = wp.tid()
    h = 0
    if i < n:
        if i == 0:
            h = 1
        elif codes[i] != codes[i - 1]:
            h = 1
    heads[i] = h


@wp.kernel
def _seg_start_kernel(
    heads: wp.array(dtype=int), seg_id: wp.array(dtype=int), starts: wp.array(dtype=int)
):
    i = wp.tid()
    if heads[i] == 1:
        starts[seg_id[i]] = i


@wp.kernel
def _seg_sum_kernel(
    starts: wp.array(dtype=int),
    n: int,
    values: wp.array(dtype=float),
    tau: wp.float64,
    sums: wp.array(dtype=wp.float64),
    counts: wp.array(dtype=int),
    active: wp.array(dtype=int),
):
    s = wp.tid()
    b = starts[s]
    e = n
    if s + 1 < starts.shape[0]:
        e = starts[s + 1]
    acc = wp.float64(0.0)
    for j in range(b, e):  # fixed (stable-sorted) order → deterministic float64 sum
        acc = acc + wp.float64(values[j])
    sums[s] = acc
    counts[s] = e - b
    active[s] = wp.where(acc >= tau, 1, 0)


@wp.kernel
def _compact_kernel(
    starts: wp.array(dtype=int),
    keys: wp.array(dtype=wp.int64),
    sums: wp.array(dtype=wp.float64),
    counts: wp.array(dtype=int),
    active: wp.array(dtype=int),
    pos: wp.array(dtype=int),
    out_codes: wp.array(dtype=wp.int64),
    out_density: wp.array(dtype=float),
    out_count: wp.array(dtype=wp.int32),
):
    s = wp.tid()
    if active[s] == 1:
        j = pos[s]
        out_codes[j] = keys[starts[s]]
        out_density[j] = float(sums[s])
        out_count[j] = wp.int32(counts[s])


@wp.kernel
def _hash_insert_kernel(
    codes: wp.array(dtype=wp.int64),
    shift: int,
    keys: wp.array(dtype=wp.int64),
    vals: wp.array(dtype=wp.int32),
):
    a = wp.tid()
    code = codes[a]
    mask = keys.shape[0] - 1
    s = _hash_slot(code, shift)
    for _probe in range(keys.shape[0]):
        prev = wp.atomic_cas(keys, s, wp.int64(HASH_EMPTY), code)
        if prev == wp.int64(HASH_EMPTY) or prev == code:
            vals[s] = wp.int32(a)
            return
        s = (s + 1) & mask


@wp.kernel
def _hash_query_kernel(
    keys: wp.array(dtype=wp.int64),
    vals: wp.array(dtype=wp.int32),
    shift: int,
    codes: wp.array(dtype=wp.int64),
    out: wp.array(dtype=wp.int32),
    base: int,
    stride: int,
):
    i = base + wp.tid() * stride
    c = codes[i]
    r = -1
    if c >= wp.int64(0):
        r = hash_lookup(keys, vals, shift, c)
    out[i] = wp.int32(r)


# --- wrappers -------------------------------------------------------------------
def make_grid_geom(center: np.ndarray, half: float, h: float, g: int) -> GridGeom:
    geom = GridGeom()
    c = np.asarray(center, dtype=np.float64).reshape(3)
    geom.center = wp.vec3d(*c)
    geom.half = wp.float64(half)
    geom.h = wp.float64(h)
    geom.g = int(g)
    geom.origin = wp.vec3(*(c - half).astype(np.float32))
    geom.hf = float(h)
    return geom


def surfel_codes(
    means: wp.array,
    geom: GridGeom,
    *,
    filtered: int = -1,
    opacities: wp.array | None = None,
    capacity: int | None = None,
    device=None,
) -> tuple[wp.array, wp.array | None, int]:
    """Voxel Morton code of every surfel centre (``filtered`` where Pass 1 drops it).

    Args:
        means: ``[N] vec3`` surfel centres.
        opacities: optional ``[N] float32``; when given, copied into the returned
            value array (the sort payload of the build).
        capacity: length of the returned arrays (≥ N; the radix sort needs 2N).
    Returns:
        ``codes [capacity] int64``, ``values [capacity] float32`` or None, and the
        number of kept (non-filtered) surfels.
    """
    device = device or means.device
    n = means.shape[0]
    cap = n if capacity is None else int(capacity)
    if cap < n:
        raise ValueError("surfel_codes: capacity < N")
    codes = wp.empty(cap, dtype=wp.int64, device=device)
    values = wp.zeros(cap if opacities is not None else 0, dtype=float, device=device)
    opac = opacities if opacities is not None else wp.zeros(0, dtype=float, device=device)
    n_valid = wp.zeros(1, dtype=int, device=device)
    wp.launch(
        _codes_kernel,
        dim=n,
        inputs=[means, geom, wp.int64(filtered), codes, values, opac, n_valid],
        device=device,
    )
    return codes, (values if opacities is not None else None), int(n_valid.numpy()[0])


def build_active(
    means: wp.array,
    opacities: wp.array,
    geom: GridGeom,
    bits: int,
    tau: float,
    device=None,
    mem=None,
) -> dict:
    """Sort + segment-reduce the surfel opacities; return the active-voxel list.

    Returns a dict with ``codes [A] int64`` (ascending), ``density [A] float32``,
    ``count [A] int32`` (surfels per active voxel), ``n_kept``, ``n_occupied``.
    ``mem`` (optional) is a callable ``mem(nbytes_delta)`` for peak tracking.
    """
    device = device or means.device
    track = mem or (lambda _d: None)
    n = means.shape[0]
    sentinel = 1 << (3 * bits)
    keys, values, n_kept = surfel_codes(
        means, geom, filtered=sentinel, opacities=opacities, capacity=max(2 * n, 2), device=device
    )
    track(keys.capacity + values.capacity)
    if n > 0:
        wp.utils.radix_sort_pairs(keys, values, n, 0, 3 * bits + 1)
    heads = wp.empty(max(n, 1), dtype=int, device=device)
    seg_id = wp.empty(max(n, 1), dtype=int, device=device)
    track(heads.capacity + seg_id.capacity)
    wp.launch(_heads_kernel, dim=max(n, 1), inputs=[keys, n_kept, heads], device=device)
    wp.utils.array_scan(heads, seg_id, inclusive=False)
    m = heads.shape[0]
    n_occ = int(seg_id[m - 1 : m].numpy()[0] + heads[m - 1 : m].numpy()[0])
    out = {"n_kept": n_kept, "n_occupied": n_occ}
    if n_occ == 0:
        z = wp.zeros(0, dtype=wp.int64, device=device)
        out.update(
            codes=z,
            density=wp.zeros(0, dtype=float, device=device),
            count=wp.zeros(0, dtype=wp.int32, device=device),
        )
        return out
    starts = wp.empty(n_occ, dtype=int, device=device)
    wp.launch(_seg_start_kernel, dim=max(n, 1), inputs=[heads, seg_id, starts], device=device)
    del heads, seg_id
    sums = wp.empty(n_occ, dtype=wp.float64, device=device)
    counts = wp.empty(n_occ, dtype=int, device=device)
    active = wp.empty(n_occ, dtype=int, device=device)
    pos = wp.empty(n_occ, dtype=int, device=device)
    track(starts.capacity + sums.capacity + counts.capacity + active.capacity + pos.capacity)
    wp.launch(
        _seg_sum_kernel,
        dim=n_occ,
        inputs=[starts, n_kept, values, wp.float64(tau), sums, counts, active],
        device=device,
    )
    wp.utils.array_scan(active, pos, inclusive=False)
    n_act = int(pos[n_occ - 1 : n_occ].numpy()[0] + active[n_occ - 1 : n_occ].numpy()[0])
    codes = wp.empty(n_act, dtype=wp.int64, device=device)
    dens = wp.empty(n_act, dtype=float, device=device)
    cnt = wp.empty(n_act, dtype=wp.int32, device=device)
    track(codes.capacity + dens.capacity + cnt.capacity)
    wp.launch(
        _compact_kernel,
        dim=n_occ,
        inputs=[starts, keys, sums, counts, active, pos, codes, dens, cnt],
        device=device,
    )
    out.update(codes=codes, density=dens, count=cnt)
    return out


def hash_capacity(n: int) -> tuple[int, int]:
    """Power-of-two capacity ≥ 2n (load ≤ ½, min 16) and the Fibonacci-hash shift."""
    cap = 16
    while cap < 2 * n:
        cap *= 2
    return cap, 64 - (cap.bit_length() - 1)


def hash_build(codes: wp.array, device=None) -> tuple[wp.array, wp.array, int]:
    """Open-addressing hash table (Fibonacci hashing, linear probing) code → index.

    Returns ``keys [cap] int64`` (−1 empty), ``vals [cap] int32`` and the hash shift.
    Slot placement may differ between devices; lookups return the same index.
    """
    device = device or codes.device
    cap, shift = hash_capacity(codes.shape[0])
    keys = wp.full(cap, HASH_EMPTY, dtype=wp.int64, device=device)
    vals = wp.full(cap, -1, dtype=wp.int32, device=device)
    if codes.shape[0] > 0:
        wp.launch(
            _hash_insert_kernel,
            dim=codes.shape[0],
            inputs=[codes, shift, keys, vals],
            device=device,
        )
    return keys, vals, shift


def hash_query(
    keys: wp.array, vals: wp.array, shift: int, codes: wp.array, device=None, threads=None
) -> wp.array:
    """``[M] int32`` active index of each code (−1 when absent or code < 0); queries are
    independent: split over ``threads`` CPU sub-launches (default all cores)."""
    device = wp.get_device(device or keys.device)
    out = wp.empty(codes.shape[0], dtype=wp.int32, device=device)
    if codes.shape[0] > 0:
        launch_split(
            _hash_query_kernel,
            codes.shape[0],
            [keys, vals, shift, codes, out],
            device,
            cpu_threads(threads),
        )
    return out
